"""Per-pixel disparity limits (``pixel_range=``) on real KITTI frames: what a sparse prior, as
from a lidar, does to the error and the time of each chain, beside OpenCV SGBM in the same run.

The prior: 5 % of the ground-truth pixels of each frame (KITTI's ground truth *is* accumulated
lidar), each giving MIN = d - 3, MAX = d + 4 to the pixels within 3 px of it; every other pixel
keeps the whole range. The error is scored on all ground-truth pixels, the prior's own included,
so it flatters the prior: read it as what a lidar of that density could give, not as a
benchmark result. Frames 000021-000025 (validation frames; nothing is chosen here).

Command:  .venv/bin/python experiments/investigations/pixel_range.py   (about 3 min here)
-> experiments/results/pixel_range.{json,md}
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

import stereojax
from stereojax.data.datasets import DEFAULT_DATA, load_kitti2015
from stereojax.app.evaluation import evaluate_frames, sgbm_method
from stereojax.metrics import evaluate
from stereojax.models.registry import learned_config, load_model, shipped_weights

OUT = Path(__file__).resolve().parents[1] / "results"
FRAMES = [f"{i:06d}" for i in range(21, 26)]
SHARE, RADIUS, MARGIN = 0.05, 3, 3
MAX_DISP = 228


def prior_limits(gt: np.ndarray, valid: np.ndarray, seed: int):
    """(MIN, MAX) maps from a random SHARE of the GT pixels, spread over RADIUS px."""
    rng = np.random.default_rng(seed)
    picked = valid & (rng.random(gt.shape) < SHARE)
    d = np.where(picked, np.round(gt), -1).astype(np.float32)
    k = np.ones((2 * RADIUS + 1, 2 * RADIUS + 1), np.uint8)
    hi_d = cv2.dilate(d, k)                                     # the largest prior disparity nearby
    lo_d = -cv2.dilate(np.where(picked, -d, -1e6).astype(np.float32), k)   # the smallest
    near = hi_d >= 0
    lo = np.where(near, lo_d - MARGIN, 0).astype(np.int32)
    hi = np.where(near, hi_d + MARGIN + 1, MAX_DISP).astype(np.int32)
    return lo, hi, float(near.mean() * 100)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    args = ap.parse_args()
    root = Path(args.data) / "kitti2015" / "training"
    samples = [load_kitti2015(root, f) for f in FRAMES]
    chains = {"census": (stereojax.preset("census", MAX_DISP), None),
              "kitti2015_compact": (learned_config("kitti2015_compact", MAX_DISP),
                                    load_model(shipped_weights("kitti2015_compact")))}
    r_sgbm = evaluate_frames(samples, {"sgbm": sgbm_method(pad=True)}, MAX_DISP)    # missing: interpolated
    sg = {"bad3": float(r_sgbm["mean"]["sgbm"]["bad3"]),
          "seconds": float(np.median([r["sgbm"]["seconds"] for r in r_sgbm["frames"]]))}
    rows = []
    for name, (cfg, model) in chains.items():
        predict = stereojax.Predictor(cfg, model)
        first = samples[0]
        lo, hi, _ = prior_limits(first.gt, first.gt_valid, 0)
        predict(first.left, first.right)                                     # compile both programs
        predict(first.left, first.right, pixel_range=(lo, hi))
        for use in (False, True):
            secs, errs, cover = [], [], []
            for i, s in enumerate(samples):
                lo, hi, near = prior_limits(s.gt, s.gt_valid, i)
                t0 = time.perf_counter()
                d = predict(s.left, s.right, pixel_range=(lo, hi) if use else None)
                secs.append(time.perf_counter() - t0)
                errs.append(evaluate(d, s.gt, s.gt_valid)["bad3"])
                cover.append(near)
            rows.append({"chain": name, "prior": use, "bad3": float(np.mean(errs)), "seconds": float(np.median(secs)),
                         "limited_pixels_pct": float(np.mean(cover)) if use else 0.0})
            print(f"{name:>18} {'with' if use else 'without'} prior: > 3 px {rows[-1]['bad3']:.2f} %, "
                  f"{rows[-1]['seconds']:.2f} s", flush=True)
    OUT.joinpath("pixel_range.json").write_text(json.dumps(
        {"frames": FRAMES, "share": SHARE, "radius": RADIUS, "margin": MARGIN, "rows": rows, "sgbm": sg}, indent=2) + "\n")
    lines = ["# Per-pixel limits from a sparse prior (KITTI 2015 000021-000025, non-occluded GT)", "",
             f"Prior: {SHARE * 100:g} % of the GT pixels (lidar-like), each limiting the pixels within {RADIUS} px to "
             f"its disparity ± {MARGIN}; scored on all GT pixels, the prior's own included, so the error flatters "
             "the prior. Warm seconds per frame (median), 2 CPU cores, one run with OpenCV SGBM. "
             "`python experiments/investigations/pixel_range.py`.", "",
             "| chain | prior | pixels with limits % | > 3 px % | warm s | × SGBM |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['chain']} | {'yes' if r['prior'] else 'no'} | {r['limited_pixels_pct']:.1f} | "
                     f"{r['bad3']:.2f} | {r['seconds']:.2f} | {r['seconds'] / sg['seconds']:.0f}× |")
    lines.append(f"| OpenCV StereoSGBM (left-padded) | no | 0 | {sg['bad3']:.2f} | {sg['seconds']:.3f} | 1× |")
    OUT.joinpath("pixel_range.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT / 'pixel_range.md'}")


if __name__ == "__main__":
    main()
