"""Does a share of the census cost beside the learned one help the learned chain? Measured on
KITTI 2015 TRAINING frames only (000001-000019, odd; non-occluded GT, and 000001 with all-pixel
GT), with the shipped `kitti2015` model and its card's chain settings.

Each frame's learned volume is computed once (`Predictor.volume`); the chain then runs on
``learned + w * census`` (census: the fraction of differing bits of the chain's census window,
in [0, 1]) for every weight w. Lower > 3 px is better.

Command:  .venv/bin/python experiments/investigations/census_blend.py [--data ../shared/data]
(about 6 min here) -> experiments/results/census_blend.{json,md}
"""

import argparse
from pathlib import Path

import jax
import numpy as np

import stereojax
from stereojax.matching_cost.classical import census_cost
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, search_range
from stereojax.data.io import write_json
from stereojax.metrics import evaluate
from stereojax.models.registry import resolve
from stereojax.inference.programs import Volume

FRAMES = [f"{i:06d}" for i in range(1, 20, 2)]
WEIGHTS = (0.0, 0.1, 0.2, 0.4, 0.8)
OUT = Path(__file__).resolve().parents[1] / "results"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    census = jax.jit(census_cost, static_argnames=("max_disp", "radius"))
    rows = []
    for gt in ("noc", "occ"):
        frames = FRAMES if gt == "noc" else ["000001"]
        for frame in frames:
            s = load_dataset(args.data, "kitti2015", [frame], gt=gt)[0][1]()
            md = search_range("kitti2015", s, None)
            run = resolve("best", None, None, s.left.shape[1], s.left.shape[0], "kitti2015", md)
            predictor = stereojax.Predictor(run.config, run.model())
            vol = predictor.volume(s.left, s.right)
            cen = np.asarray(census(vol.left, vol.right, max_disp=md, radius=tuple(run.config.cost.census_radius)))
            row = {"frame": frame, "gt": gt}
            for w in WEIGHTS:
                disp = predictor.from_volume(Volume(vol.cost + w * cen, vol.left, vol.right, vol.valid))
                row[f"w={w:g}"] = evaluate(disp, s.gt, s.gt_valid)["bad3"]
            rows.append(row)
            print(row, flush=True)
    names = [f"w={w:g}" for w in WEIGHTS]
    noc = [r for r in rows if r["gt"] == "noc"]
    mean = {n: float(np.mean([r[n] for r in noc])) for n in names}
    lines = ["# Census share beside the learned cost (> 3 px %, KITTI 2015 training frames)", "",
             "Chain: the shipped `kitti2015` model and card; cost = learned + w x census.", "",
             "| frame | GT | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    lines += [f"| {r['frame']} | {r['gt']} | " + " | ".join(f"{r[n]:.2f}" for n in names) + " |" for r in rows]
    lines.append("| **mean, noc** | | " + " | ".join(f"**{mean[n]:.2f}**" for n in names) + " |")
    OUT.mkdir(parents=True, exist_ok=True)
    write_json(OUT / "census_blend.json", {"frames": rows, "mean_noc": mean, "weights": list(WEIGHTS)})
    (OUT / "census_blend.md").write_text("\n".join(lines) + "\n\nCommand: `python experiments/investigations/census_blend.py`\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
