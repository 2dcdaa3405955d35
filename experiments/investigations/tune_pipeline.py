"""Grid search of pipeline settings on KITTI 2015 training frames (never the validation split).

Command:  .venv/bin/python experiments/investigations/tune_pipeline.py GRID.txt [--frames 1,3,5,...,19]
GRID.txt holds one JSON object of config overrides per line (e.g. {"sgm": {"p1": 0.45}}).
Running time here: ~35 s per line for 10 frames (2 CPU cores), plus ~12 s compilation.
Prints, per line, the mean > 3 px error (non-occluded GT; the chain's output is dense) and
the time taken. The record of the search behind the shipped presets is
experiments/results/tuning.md.
"""

import argparse
import json
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np


from stereojax.inference.prepare import prepare_pair
from stereojax.inference.programs import disparity_grey
from stereojax.config import StereoConfig
from stereojax.data import DEFAULT_DATA, load_kitti2015
from stereojax.metrics import evaluate



def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("grid")
    ap.add_argument("--frames", default=",".join(str(i) for i in range(1, 21, 2)))
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    samples = [load_kitti2015(Path(args.data) / "kitti2015" / "training", int(f)) for f in args.frames.split(",")]
    for line in Path(args.grid).read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cfg = StereoConfig.from_dict({**json.loads(line), "max_disp": 228})
        t0, errs = time.time(), []
        for s in samples:
            gl, gr = prepare_pair(s.left, s.right, cfg)
            disp = np.asarray(disparity_grey(jnp.asarray(gl), jnp.asarray(gr), cfg))
            errs.append(evaluate(disp, s.gt, s.gt_valid)["bad3"])
        print(f"{np.mean(errs):6.2f}  {time.time() - t0:5.1f}s  {line}", flush=True)


if __name__ == "__main__":
    main()
