"""Raw pairs in, the same 3-D scene out (issue 54's target): KITTI pairs un-rectified on purpose.

Command:  .venv/bin/python experiments/rectify_roundtrip.py [--frames 000021-000023] [--method best|census]

Each KITTI 2015 pair (rectified, with its non-occluded GT) is turned into a raw pair of a made-up rig
(stereojax.data.stereo_rig.simulate_raw_pair: each camera rotated by about a degree, its own
intrinsics and radial/tangential distortion), with the rig's exact stereo calibration. stereojax
then rectifies the raw pair itself (stereoRectify, alpha 0) and matches it; its depth is compared
with the GT's 3-D points (GT disparity and the original calibration, rotated into the raw left
camera and then into stereojax's rectified camera), by depth at the pixels where the GT points
project: the share within 5 % of their depth. The same measure on the original rectified pair is
the reference; the target: within 3 points of it.

KITTI's calibration is not in the shared data: the usual KITTI 2015 values (f 721.5377 px,
principal point 609.5593, 172.854, baseline 0.5372 m) stand in; the GT points and both runs use
the same values, so the comparison does not depend on them.
-> experiments/results/rectify_roundtrip.{json,md}
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from common import DEFAULT_DATA, ROOT, md_table  # noqa: E402

import stereojax  # noqa: E402
from stereojax.data.datasets import Calibration, load_kitti2015, parse_frames  # noqa: E402
from stereojax.data.depth import disparity_to_depth  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.data.stereo_rig import RawCamera, Rectifier, simulate_raw_pair  # noqa: E402
from stereojax.models.registry import learned_config, load_model, shipped_weights  # noqa: E402

KITTI_CALIB = Calibration(baseline=0.5372, focal=721.5377, cx=609.5593, cy=172.854)
CAM_LEFT = RawCamera(710.0, 712.0, 615.0, 180.0, (-0.12, 0.05, 0.0008, -0.0005, 0.0), (0.6, -0.8, 0.3))
CAM_RIGHT = RawCamera(730.0, 728.0, 600.0, 168.0, (-0.09, 0.02, -0.0006, 0.0004, 0.0), (-0.4, 0.5, -0.2))
TOLERANCE = 0.05
TARGET_POINTS = 3.0


def gt_points(sample, calib: Calibration) -> np.ndarray:
    """The GT's 3-D points ``[N, 3]`` in the original rectified left camera's frame (metres)."""
    ys, xs = np.nonzero(sample.gt_valid)
    d = sample.gt[ys, xs]
    z = calib.baseline * calib.focal / (d + calib.doffs)
    return np.stack([(xs - calib.cx) * z / calib.focal, (ys - calib.cy) * z / calib.focal, z], -1)


def share_within(depth: np.ndarray, points: np.ndarray, p1: np.ndarray, tol: float = TOLERANCE):
    """(share of the points whose depth at the pixel they project to is within ``tol`` of theirs,
    share of the points that project inside the image). ``points`` in the camera's frame, ``p1``
    its 3x3 projection."""
    h, w = depth.shape
    uvw = points @ p1.T
    u = np.rint(uvw[:, 0] / uvw[:, 2]).astype(int)
    v = np.rint(uvw[:, 1] / uvw[:, 2]).astype(int)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (points[:, 2] > 0)
    z = depth[v[inside], u[inside]]
    ok = (z > 0) & (np.abs(z - points[inside, 2]) <= tol * points[inside, 2])
    return float(ok.mean()) if ok.size else float("nan"), float(inside.mean())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", default="000021-000023")
    ap.add_argument("--method", default="best", choices=["best", "census"])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    args = ap.parse_args()
    if args.method == "best":
        cfg, model = learned_config("kitti2015"), load_model(shipped_weights("kitti2015"))
    else:
        cfg, model = stereojax.preset("census"), None
    root = Path(args.data) / "kitti2015" / "training"
    rows = []
    for frame in parse_frames(args.frames):
        s = load_kitti2015(root, frame, "noc")
        pts = gt_points(s, KITTI_CALIB)
        t0 = time.perf_counter()
        disp = stereojax.Predictor(cfg, model)(s.left, s.right)
        z_ref = disparity_to_depth(disp, KITTI_CALIB.baseline, KITTI_CALIB.focal, KITTI_CALIB.doffs)
        p_ref = np.array([[KITTI_CALIB.focal, 0, KITTI_CALIB.cx], [0, KITTI_CALIB.focal, KITTI_CALIB.cy], [0, 0, 1]])
        ref, ref_in = share_within(z_ref, pts, p_ref)
        raw_l, raw_r, rig, r_l = simulate_raw_pair(s.left, s.right, KITTI_CALIB, CAM_LEFT, CAM_RIGHT)
        rect = Rectifier(rig)
        disp_raw = stereojax.Predictor(cfg, model, rectifier=rect)(raw_l, raw_r)
        c = rect.calibration
        z_raw = disparity_to_depth(disp_raw, c.baseline, c.focal, c.doffs)
        pts_ours = (pts @ r_l) @ rect.R1.T        # original rectified -> raw left -> stereojax's rectified
        got, got_in = share_within(z_raw, pts_ours, rect.P1[:, :3])
        rows.append({"frame": s.name, "reference": ref, "reference_inside": ref_in, "rectified_by_stereojax": got,
                     "inside": got_in, "gap_points": 100 * (ref - got), "focal_rectified": c.focal,
                     "baseline_rectified": c.baseline, "seconds": time.perf_counter() - t0})
        print(f"{s.name}: original pair {100 * ref:.2f} %, raw pair rectified by stereojax {100 * got:.2f} % of the "
              f"GT points within 5 % of their depth ({100 * got_in:.1f} % of them inside its rectified view)",
              flush=True)
    mean_ref = float(np.mean([r["reference"] for r in rows]))
    mean_got = float(np.mean([r["rectified_by_stereojax"] for r in rows]))
    gap = 100 * (mean_ref - mean_got)
    met = abs(gap) <= TARGET_POINTS
    table = md_table(["frame", "original rectified pair %", "raw pair, --rectify %", "GT points inside %"],
                     [[r["frame"], f"{100 * r['reference']:.2f}", f"{100 * r['rectified_by_stereojax']:.2f}",
                       f"{100 * r['inside']:.1f}"] for r in rows]
                     + [["**mean**", f"**{100 * mean_ref:.2f}**", f"**{100 * mean_got:.2f}**", ""]])
    md = ("# Raw pairs in: KITTI pairs un-rectified on purpose, rectified by stereojax\n\n"
          f"Share of the GT's 3-D points whose depth, read where they project, is within {100 * TOLERANCE:g} % "
          f"(method `{args.method}`). Raw rig: {CAM_LEFT} / {CAM_RIGHT}.\n\n" + table + "\n\n"
          f"Gap {gap:+.2f} points; target within {TARGET_POINTS:g}: **{'met' if met else 'missed'}**.\n\n"
          f"Command: `python experiments/rectify_roundtrip.py {' '.join(sys.argv[1:])}`\n")
    out = Path(args.out)
    stem = "rectify_roundtrip" + ("" if args.method == "best" else f"_{args.method}")
    write_json(out / f"{stem}.json", {"method": args.method, "frames": rows, "mean_reference": mean_ref,
                                      "mean_rectified": mean_got, "gap_points": gap, "target_met": met})
    (out / f"{stem}.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
