"""Is the learned chain weak in dark image regions? Measured on KITTI 2015 TRAINING frames
(000001-000019, odd; non-occluded GT): > 3 px error of `best` (the shipped kitti2015 model and
card), the census chain and OpenCV SGBM (left-padded; pixels it leaves without an estimate count
as wrong), per bin of local brightness (9x9 mean of the left grey image).

Asked because on KITTI 2012 000000 most of `best`'s wrong pixels lie in a dark shadowed verge.

Command:  .venv/bin/python experiments/investigations/error_by_brightness.py [--data ../shared/data]
(about 4 min here) -> experiments/results/error_by_brightness.{json,md}
"""

import argparse
from pathlib import Path

import cv2
import numpy as np

import stereojax
from stereojax.app.baselines import sgbm_disparity
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, search_range
from stereojax.data.io import write_json
from stereojax.models.registry import resolve
from stereojax.data.images import as_grey

FRAMES = [f"{i:06d}" for i in range(1, 20, 2)]
BINS = (0, 20, 40, 70, 110, 256)
METHODS = ("best", "census", "sgbm")
OUT = Path(__file__).resolve().parents[1] / "results"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    counts = {m: np.zeros((len(BINS) - 1, 2), np.int64) for m in METHODS}     # [bin, (wrong, GT pixels)]
    predictors = {}
    for frame in FRAMES:
        s = load_dataset(args.data, "kitti2015", [frame], gt="noc")[0][1]()
        md = search_range("kitti2015", s, None)
        lum = cv2.blur(as_grey(s.left, "left"), (9, 9))
        out = {}
        for m in ("best", "census"):
            if m not in predictors:
                run = resolve(m, None, None, s.left.shape[1], s.left.shape[0], "kitti2015", md)
                predictors[m] = stereojax.Predictor(run.config, run.model())
            out[m] = predictors[m](s.left, s.right)
        d, valid = sgbm_disparity(s.left, s.right, num_disp=md, pad=True)
        out["sgbm"] = np.where(valid, d, -1e3)
        for m, disp in out.items():
            wrong = np.abs(disp - s.gt) > 3
            for i in range(len(BINS) - 1):
                sel = s.gt_valid & (lum >= BINS[i]) & (lum < BINS[i + 1])
                counts[m][i] += (int(wrong[sel].sum()), int(sel.sum()))
        print(frame, flush=True)
    names = [f"[{BINS[i]}, {BINS[i + 1]})" for i in range(len(BINS) - 1)]
    err = {m: [100.0 * w / max(n, 1) for w, n in counts[m]] for m in METHODS}
    lines = ["# > 3 px error by local brightness (KITTI 2015 training frames 000001-000019 odd, noc GT)", "",
             "| method | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    lines += [f"| {m} | " + " | ".join(f"{e:.2f}" for e in err[m]) + " |" for m in METHODS]
    lines.append("| GT pixels | " + " | ".join(str(int(n)) for _, n in counts["best"]) + " |")
    OUT.mkdir(parents=True, exist_ok=True)
    write_json(OUT / "error_by_brightness.json", {"frames": FRAMES, "bins": list(BINS), "error": err,
                                                  "gt_pixels": [int(n) for _, n in counts["best"]]})
    (OUT / "error_by_brightness.md").write_text(
        "\n".join(lines) + "\n\nBrightness: 9x9 mean of the left grey image (0-255). SGBM pixels without "
        "an estimate count as wrong.\n\nCommand: `python experiments/investigations/error_by_brightness.py`\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
