"""Writing a prediction: disparity (KITTI 16-bit PNG, PFM, colour map) and, with a
calibration, depth (PNG, npy) and a coloured point cloud; every file atomically."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import OutputError


def output_folder(path) -> Path:
    """Create the output folder and check that it is writable, before any long computation."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output folder {path}: {exc.strerror}") from None
    if not path.is_dir() or not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {path} is not writable")
    return path


def color_scale(disp, gt=None, gt_valid=None) -> float:
    """Disparity shown as the top colour: the largest true disparity when GT is known, else
    the 99.5th percentile of the estimate (so a few outliers do not wash out the picture)."""
    if gt is not None and gt_valid is not None and gt_valid.any():
        return float(gt[gt_valid].max())
    return max(float(np.percentile(disp, 99.5)), 1.0)


def write_prediction(out: Path, stem: str, disp, calib=None, image=None, ply=False, color_max=None):
    """Write disparity (KITTI png + colour png) and depth files; returns the written names."""
    from .data import io
    from . import depth as depth_mod

    written = []
    io.write_kitti_disparity(out / f"{stem}disparity.png", disp)
    io.write_pfm(out / f"{stem}disparity.pfm", disp)
    io.write_color_disparity(out / f"{stem}disparity_color.png", disp,
                             max_disp=color_max or color_scale(disp))
    written += [f"{stem}disparity.png", f"{stem}disparity.pfm", f"{stem}disparity_color.png"]
    if calib is not None:
        z = depth_mod.disparity_to_depth(disp, calib.baseline, calib.focal, calib.doffs)
        depth_mod.write_depth(out / f"{stem}depth.png", z)
        depth_mod.write_depth(out / f"{stem}depth.npy", z)
        written += [f"{stem}depth.png", f"{stem}depth.npy"]
        if ply and image is not None:
            xyz, rgb = depth_mod.point_cloud(disp, image, calib)
            depth_mod.write_ply(out / f"{stem}points.ply", xyz, rgb)
            written.append(f"{stem}points.ply")
    return written
