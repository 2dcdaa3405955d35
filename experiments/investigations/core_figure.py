"""Figure of the classical pipeline on KITTI 2015 validation frames: left image, disparity,
KITTI-style error map, one row block per frame, next to OpenCV SGBM (left-padded).

Command:  .venv/bin/python experiments/investigations/core_figure.py [--frames 000025,000021]
Running time here: ~20 s. Writes experiments/results/figures/core_kitti2015.png and prints
the > 3 px error of both methods on each frame.
"""

import argparse
from pathlib import Path

import cv2
import numpy as np


import stereojax
from stereojax.app.baselines import sgbm_disparity
from stereojax.data import DEFAULT_DATA, io, load_kitti2015
from stereojax.metrics import evaluate, interpolate_background

OUT = Path(__file__).resolve().parents[1] / "results" / "figures" / "core_kitti2015.png"


def label(img, text):
    img = img.copy()
    cv2.putText(img, text, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    return img


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", default="000025,000021")
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    rows = []
    for frame in args.frames.split(","):
        s = load_kitti2015(Path(args.data) / "kitti2015" / "training", frame)
        scale = float(s.gt[s.gt_valid].max())
        ours = stereojax.disparity(s.left, s.right, stereojax.preset("census", 228))
        cv_d, cv_v = sgbm_disparity(s.left, s.right, 228, pad=True)
        cv_d = interpolate_background(cv_d, cv_v)   # as scored: KITTI's background fill
        m_ours = evaluate(ours, s.gt, s.gt_valid)
        m_cv = evaluate(cv_d, s.gt, s.gt_valid)
        print(f"{frame}: census pipeline {m_ours['bad3']:.2f} %  SGBM {m_cv['bad3']:.2f} % > 3 px")
        rows.append(np.hstack([label(s.left, f"{frame} left"),
                               label(io.colorize_disparity(ours, scale), "census + CBCA + SGM")]))
        rows.append(np.hstack([
            label(io.error_map(ours, s.gt, s.gt_valid), f"errors, stereojax ({m_ours['bad3']:.1f} % > 3 px)"),
            label(io.error_map(cv_d, s.gt, s.gt_valid), f"errors, OpenCV SGBM ({m_cv['bad3']:.1f} % > 3 px)")]))
    fig = np.vstack(rows)
    fig = cv2.resize(fig, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    io.write_png(OUT, fig)
    print(f"-> {OUT}")


if __name__ == "__main__":
    main()
