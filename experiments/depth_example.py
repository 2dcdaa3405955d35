"""Depth — from a KITTI-like rectified pair to a metric depth map and a coloured point cloud with
Z = B·f/d, using KITTI's calibration file format.

Command:  make depth-example   (= .venv/bin/python experiments/depth_example.py [--frame 000021])
          .venv/bin/python experiments/depth_example.py --quick     (census chain, seconds)
Running time here (2 cores): about 2 min (shipped KITTI model, pruned mode K = 32, with
compilation); --quick about 15 s.

The shared data has no calibration files, so the script writes one in KITTI's
``calib_cam_to_cam`` format with a representative KITTI rectification (P_rect_02 / P_rect_03 of
the 2011_09_26 recordings: f = 721.54 px, baseline 0.532 m) into a small KITTI tree under
``out/depth_example/training`` beside links to the frame's images, and loads the frame from there
like any KITTI frame with calibration. The steps are the ones a user follows with their own data:

    s = stereojax.data.load_kitti2015(".../training", "000021")      # reads calib_cam_to_cam/000021.txt
    disp = stereojax.disparity(s.left, s.right, preset("learned", 228), params=load_model(...))
    z = disparity_to_depth(disp, s.calib.baseline, s.calib.focal)        # metres, Z = B f / d
    xyz, rgb = point_cloud(disp, s.left, s.calib); write_ply("points.ply", xyz, rgb)

Prints and writes experiments/results/depth_example.{json,md} (calibration, depth statistics, the
depth error against depth from the ground-truth disparity) and figures/depth_example.png; the
point cloud goes to out/depth_example/points.ply (not committed).
"""

import argparse
import shutil
from pathlib import Path

import numpy as np

from common import QUICK_CROP, ROOT, Setup, add_common_args, md_table, shrink, write_outputs

import stereojax
from stereojax.data import load_kitti2015
from stereojax.data.io import colorize_disparity, write_png
from stereojax.data.depth import disparity_to_depth, point_cloud, write_ply
from stereojax.models.registry import load_model, shipped_weights

CALIB = """calib_time: 09-Jan-2012 13:57:47
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
"""


def main():
    ap = add_common_args(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    ap.add_argument("--frame", default="000021")
    ap.add_argument("--work", default=str(ROOT / "out" / "depth_example"))
    args = ap.parse_args()
    setup = Setup.from_args(args)
    tree = _kitti_tree(Path(args.work) / "training", setup.data / "kitti2015" / "training", args.frame)
    s = load_kitti2015(tree, args.frame)
    calib = s.calib
    if setup.quick:
        s = s.crop(*QUICK_CROP)
        disp = stereojax.disparity(s.left, s.right, stereojax.preset("census", 48))
        method = "census chain (quick mode, bottom-centre crop)"
    else:
        model = load_model(shipped_weights("kitti2015"))
        disp = stereojax.disparity(s.left, s.right, stereojax.preset("learned", 228), params=model)
        method = "shipped KITTI 2015 model, preset(\"learned\")"
    z = disparity_to_depth(disp, calib.baseline, calib.focal)               # Z = B f / d
    z_gt = disparity_to_depth(np.where(s.gt_valid, s.gt, 0), calib.baseline, calib.focal)
    both = s.gt_valid & np.isfinite(z) & (z_gt < 80)
    rel = np.abs(z[both] - z_gt[both]) / z_gt[both]
    xyz, rgb = point_cloud(disp, s.left, calib)
    write_ply(Path(args.work) / "points.ply", xyz, rgb)
    stats = {"frame": args.frame, "method": method, "baseline_m": calib.baseline, "focal_px": calib.focal,
             "depth_median_m": float(np.nanmedian(z[np.isfinite(z)])),
             "depth_rel_error_median_percent": 100 * float(np.median(rel)),
             "depth_rel_error_over_5_percent": 100 * float((rel > 0.05).mean()),
             "gt_pixels_compared": int(both.sum()), "points": int(len(xyz))}
    figs = setup.out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    name = "depth_example" + ("_quick" if setup.quick else "") + ".png"
    zc = np.nan_to_num(np.clip(z, 0, 80), nan=80.0, posinf=80.0)
    panel = np.concatenate([np.asarray(s.left, np.uint8), colorize_disparity(80 - zc, 80)], 0)
    write_png(figs / name, shrink(panel, 0.5))
    md = (f"# Depth from a KITTI pair (frame {args.frame}, {method})\n\n"
          f"Calibration read from `calib_cam_to_cam/{args.frame}.txt` (KITTI format, representative "
          f"values): f = {calib.focal:.2f} px, B = {calib.baseline:.4f} m, so Z = {calib.baseline * calib.focal:.1f} / d m.\n\n"
          + md_table(["quantity", "value"], [
              ["median depth of the frame", f"{stats['depth_median_m']:.1f} m"],
              ["median relative depth error vs depth of the GT disparity (GT pixels < 80 m)",
               f"{stats['depth_rel_error_median_percent']:.2f} %"],
              ["GT pixels with depth error > 5 %", f"{stats['depth_rel_error_over_5_percent']:.2f} %"],
              ["GT pixels compared", stats["gt_pixels_compared"]],
              ["points in the point cloud", stats["points"]]])
          + f"\n\n![depth](figures/{name})\n\n(top: left image; bottom: depth, red = near, blue = 80 m "
          "or more.) The point cloud (`out/depth_example/points.ply`, binary PLY with colours) opens in "
          "MeshLab or CloudCompare.")
    write_outputs(setup, "depth_example" , stats, md)


def _kitti_tree(root: Path, source: Path, frame: str) -> Path:
    """A one-frame KITTI 2015 tree (links to the shared images and GT) with a calibration file."""
    for sub in ("image_2", "image_3", "disp_noc_0"):
        (root / sub).mkdir(parents=True, exist_ok=True)
        target = root / sub / f"{frame}_10.png"
        if not target.exists():
            src = source / sub / f"{frame}_10.png"
            try:
                target.symlink_to(src.resolve())
            except OSError:
                shutil.copyfile(src, target)
    (root / "calib_cam_to_cam").mkdir(exist_ok=True)
    (root / "calib_cam_to_cam" / f"{frame}.txt").write_text(CALIB)
    return root


if __name__ == "__main__":
    main()
