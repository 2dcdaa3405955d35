"""``--disp-range auto`` on the Middlebury scenes (issue 40): error, time and ground-truth
coverage of the automatic range against the true range and the default one, in one run.

Ranges, per scene:
- true: the ground truth's minimum (floored) up to its maximum, the span rounded up to 16;
- auto: :func:`stereojax.data.disp_range.auto_disp_range` (the dense probe over the feature window);
- window: the feature window alone, the rule ``auto`` used before the probe (without the probe's
  third-of-the-width floor, exactly as it was);
- default: 0 <= d < 228, what `stereojax predict` searches without a range.
Methods: `best` as `predict` resolves it for these scenes (the shipped Middlebury model), and the
census chain. Error: > 3 px on every ground-truth pixel (occluded included, missing estimates
interpolated as KITTI does). Time: the warm run (the chain compiled before; compile time apart)
plus, for auto, its check and probe. The probe's constants (its percentiles, 10 % and 8 px) were
chosen among four candidates by the ground truth they cover (not by any error) on KITTI 2015
000001-000030, KITTI 2012 000000 and these scenes. The first run (2026-12-05, the far end
widened like the near one, 10 % + 8 px) found census on Aloe 0.67 points worse than the true
range, all of it from the far end (census over 43..207: 7.09 %, over 31..207: 7.81 %); the far
end now keeps 4 px only (chosen by coverage again: >= 99.9 % on every scene). So these
scenes are not held out.

Command:  .venv/bin/python experiments/investigations/auto_range.py   (about 15 min here)
-> experiments/results/auto_range.{json,md}
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from stereojax.data.datasets import DEFAULT_DATA, load_kitti2015, load_middlebury
from stereojax.data.disp_range import ROUND_TO, auto_disp_range
from stereojax.data.rectification import check_rectified
from stereojax.devices import current_device
from stereojax.inference.predictor import Predictor
from stereojax.metrics import evaluate
from stereojax.models.registry import resolve

OUT = Path(__file__).resolve().parents[1] / "results"
DEFAULT = (0, 228)
KITTI_FRAMES = [f"{i:06d}" for i in range(1, 21)]


def true_range(gt: np.ndarray) -> tuple[int, int]:
    lo = math.floor(float(gt.min()))
    return lo, lo + ROUND_TO * math.ceil((math.floor(float(gt.max())) + 1 - lo) / ROUND_TO)


def old_window(check, width: int) -> tuple[int, int]:
    """The feature rule before the probe (no third-of-the-width floor)."""
    p1, p99 = check.disparity_p1, check.disparity_p99
    lo = math.floor(p1 - max(16, 0.25 * (p99 - p1)))
    hi = math.ceil(max(2 * p99, p99 + 48)) + 1
    lo = max(lo, 0) if p1 >= 0 else lo
    return max(lo, -(width - 2)), min(hi, width - 1)


def coverage(gt: np.ndarray, rng) -> float:
    return float(100 * np.mean((gt >= rng[0]) & (gt < rng[1])))


def run(method, sample, rng) -> dict:
    h, w = sample.left.shape[:2]
    res = resolve(method, width=w, height=h, dataset="middlebury")
    pred = Predictor(res.config, res.model(), current_device(), confidence=True, disp_range=tuple(rng))
    (_, _), first = pred.timed(sample.left, sample.right)
    (disp, _), warm = pred.timed(sample.left, sample.right)
    m = evaluate(disp, sample.gt, sample.gt_valid)
    return {"bad2": float(m["bad2"]), "bad3": float(m["bad3"]), "seconds": warm["seconds"],
            "compile_s": first["compile_s"], "model": res.label}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--methods", default="best,census")
    ap.add_argument("--scenes", default="")
    args = ap.parse_args()
    data = Path(args.data)
    tuned = []
    for f in KITTI_FRAMES[:1] if args.scenes else KITTI_FRAMES:     # coverage on KITTI frames (one: a quick try)
        s = load_kitti2015(data / "kitti2015" / "training", f, gt="noc")
        gt = s.gt[s.gt_valid]
        found = auto_disp_range(s.left, s.right, check_rectified(s.left, s.right))
        tuned.append({"frame": f, "auto": list(found.range), "cover": coverage(gt, found.range),
                      "gt_p99": float(np.percentile(gt, 99)), "gt_max": float(gt.max())})
        print(tuned[-1], flush=True)
    scenes = sorted(p for p in (data / "middlebury").iterdir() if (p / "disp0GT.pfm").is_file())
    if args.scenes:
        scenes = [p for p in scenes if p.name in args.scenes.split(",")]
    rows = []
    for scene in scenes:
        s = load_middlebury(scene)
        gt = s.gt[s.gt_valid]
        t0 = time.perf_counter()
        check = check_rectified(s.left, s.right)
        found = auto_disp_range(s.left, s.right, check)
        auto_s = time.perf_counter() - t0
        ranges = {"true": true_range(gt), "auto": found.range, "window": old_window(check, s.left.shape[1]),
                  "default": DEFAULT}
        row = {"scene": scene.name, "size": [int(s.left.shape[1]), int(s.left.shape[0])], "auto_s": auto_s,
               "auto_describe": found.describe(),
               "gt": [float(gt.min()), float(np.percentile(gt, 1)), float(np.percentile(gt, 99)), float(gt.max())],
               "ranges": {k: list(v) for k, v in ranges.items()},
               "cover": {k: coverage(gt, v) for k, v in ranges.items()}, "methods": {}}
        for method in args.methods.split(","):
            row["methods"][method] = {k: run(method, s, v) for k, v in ranges.items()}
            print(scene.name, method, {k: (round(v["bad3"], 2), round(v["seconds"], 2))
                                       for k, v in row["methods"][method].items()}, flush=True)
        rows.append(row)
        write(rows, tuned, args.methods.split(","))


def write(rows, tuned, methods):
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "auto_range.json").write_text(json.dumps({"scenes": rows, "tuned_on": tuned}, indent=1))
    lines = ["# `--disp-range auto` on the Middlebury scenes", "",
             "`experiments/investigations/auto_range.py`, one run on this machine (2 cores). "
             "> 3 px on all ground-truth pixels; time: the warm run (auto adds its check and probe, column *auto s*).",
             "", "| scene | GT min..max | true | auto | old window | default | GT in auto |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        rg = r["ranges"]
        lines.append(f"| {r['scene']} | {r['gt'][0]:.0f}..{r['gt'][3]:.0f} | {rg['true'][0]}..{rg['true'][1]} | "
                     f"{rg['auto'][0]}..{rg['auto'][1]} | {rg['window'][0]}..{rg['window'][1]} | "
                     f"{rg['default'][0]}..{rg['default'][1]} | {r['cover']['auto']:.2f} % |")
    for m in methods:
        lines += ["", f"**{m}**: > 3 px (%) / warm seconds", "",
                  "| scene | true | auto | old window | default | auto − true | auto s |", "|---|---|---|---|---|---|---|"]
        for r in rows:
            v = r["methods"][m]
            cells = " | ".join(f"{v[k]['bad3']:.2f} / {v[k]['seconds']:.2f}" for k in ("true", "auto", "window", "default"))
            lines.append(f"| {r['scene']} | {cells} | {v['auto']['bad3'] - v['true']['bad3']:+.2f} | {r['auto_s']:.2f} |")
        mean = {k: np.mean([r["methods"][m][k]["bad3"] for r in rows]) for k in ("true", "auto", "window", "default")}
        secs = {k: np.sum([r["methods"][m][k]["seconds"] for r in rows]) for k in ("true", "auto", "window", "default")}
        lines.append("| **mean / total** | " + " | ".join(f"{mean[k]:.2f} / {secs[k]:.2f}" for k in mean)
                     + f" | {mean['auto'] - mean['true']:+.2f} | {sum(r['auto_s'] for r in rows):.2f} |")
    lines += ["", "KITTI 2015 000001–000020 (GT pixels inside the auto range):",
              "", "| frame | auto | GT p99 | GT max | GT in auto |", "|---|---|---|---|---|"]
    lines += [f"| {t['frame']} | {t['auto'][0]}..{t['auto'][1]} | {t['gt_p99']:.1f} | {t['gt_max']:.1f} | "
              f"{t['cover']:.2f} % |" for t in tuned]
    (OUT / "auto_range.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
