"""Depth maps and point clouds from disparity (numpy only).

For a rectified pair with baseline ``B`` (metres), focal length ``f`` (pixels) and principal
point offset ``doffs = cx_right - cx_left`` (pixels; Middlebury's ``doffs``, 0 for KITTI),
a left-image pixel with disparity ``d`` lies at depth ``Z = B * f / (d + doffs)`` metres.
Depth 0 means "unknown" everywhere in this module, as in KITTI's depth maps.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from stereojax.data.io import atomic_output
from stereojax.errors import OutputError, StereoInputError, wxh

__all__ = ["disparity_to_depth", "write_depth", "point_cloud", "write_ply", "measurable_depth", "MEASURABLE_DISP"]

PathLike = str | os.PathLike


def _positive(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise StereoInputError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise StereoInputError(f"{name} must be a positive number, got {value!r}")
    return v


def _disp2d(disp) -> np.ndarray:
    d = np.asarray(disp)
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2 or not (np.issubdtype(d.dtype, np.floating) or np.issubdtype(d.dtype, np.integer)):
        raise StereoInputError(f"disparity must be a numeric 2-D [H, W] array, found {d.dtype} {d.shape}")
    return d.astype(np.float32, copy=False)


def disparity_to_depth(disp: np.ndarray, baseline: float, focal: float, doffs: float = 0.0,
                       min_disp: float = 0.5) -> np.ndarray:
    """Depth ``f32[H, W]`` in metres from disparity ``f32[H, W]`` in pixels.

    ``Z = baseline * focal / (disp + doffs)``. Pixels whose disparity is NaN, infinite or
    below ``min_disp`` (too far to be meaningful, or invalid such as -1 or 0), or whose
    ``disp + doffs`` is not positive, get depth 0 (= unknown).

    Raises:
        StereoInputError: ``disp`` not 2-D, or ``baseline``/``focal`` not positive.
    """
    d = _disp2d(disp)
    b, f = _positive(baseline, "baseline"), _positive(focal, "focal")
    doffs = float(doffs)
    if not math.isfinite(doffs):
        raise StereoInputError(f"doffs must be finite, got {doffs!r}")
    with np.errstate(invalid="ignore", divide="ignore"):
        denom = d.astype(np.float64) + doffs
        ok = np.isfinite(d) & (d >= min_disp) & (denom > 0)
        z = np.where(ok, b * f / np.where(ok, denom, 1.0), 0.0)
    return z.astype(np.float32)


#: a depth is measurable where ``d + doffs`` (the denominator of ``Z = B f / (d + doffs)``) is at
#: least this many pixels: one pixel of disparity error then at most doubles the depth (at 1 px the
#: same error makes it infinite). On KITTI (B f = 380-390 m px) that is about 190 m; sub-pixel
#: disparities of the sky reach about 770 m (d = 0.5 px, :func:`disparity_to_depth`'s smallest)
MEASURABLE_DISP = 2.0


def measurable_depth(calib, min_disp: float = MEASURABLE_DISP) -> float:
    """The farthest depth (metres) a calibration measures: ``baseline * focal / min_disp``, the
    depth where ``d + doffs = min_disp`` px (:data:`MEASURABLE_DISP`); farther, one pixel of
    disparity error moves the depth by more than its own size."""
    return _positive(calib.baseline, "baseline") * _positive(calib.focal, "focal") / _positive(min_disp, "min_disp")


def write_depth(path: PathLike, depth: np.ndarray) -> None:
    """Write ``f32[H, W]`` depth in metres, atomically.

    * ``.png``: uint16 ``round(depth * 256)`` (KITTI depth convention; 0 = unknown; depths are
      clipped to 255.99 m). NaN, infinite and non-positive depths are written as 0.
    * ``.npy``: float32 array as it is.

    Raises:
        StereoInputError: ``depth`` is not 2-D.
        OutputError: another extension, or the file cannot be written.
    """

    p = Path(path)
    z = _disp2d(depth)
    ext = p.suffix.lower()
    if ext == ".png":
        with np.errstate(invalid="ignore", over="ignore"):
            ok = np.isfinite(z) & (z > 0)
            v = np.clip(np.rint(np.where(ok, z, 0).astype(np.float64) * 256.0), 1, 65535)
        img = np.where(ok, v, 0).astype(np.uint16)
        good, buf = cv2.imencode(".png", img)
        if not good:
            raise OutputError(f"cannot write {p}: PNG encoding failed")
        with atomic_output(p) as tmp:
            tmp.write_bytes(buf.tobytes())
    elif ext == ".npy":
        with atomic_output(p) as tmp:
            with open(tmp, "wb") as fh:
                np.save(fh, np.ascontiguousarray(z, dtype=np.float32))
    else:
        raise OutputError(f"cannot write {p}: depth is written as .png (uint16, 1/256 m) or .npy "
                          f"(float32), found extension {p.suffix or '(none)'!r}")


def point_cloud(disp: np.ndarray, image: np.ndarray, calib, min_disp: float = 0.5,
                max_depth: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Coloured 3-D points of the left camera from ``f32[H, W]`` disparity.

    For each pixel (u, v) with a valid depth (see :func:`disparity_to_depth`):
    ``X = (u - cx) * Z / f``, ``Y = (v - cy) * Z / f`` (x right, y down, z forward, metres),
    with ``cx, cy`` from ``calib`` or the image centre ``((W - 1) / 2, (H - 1) / 2)`` when
    the calibration does not give them.

    Args:
        disp: ``f32[H, W]`` disparity.
        image: ``u8[H, W, 3]`` RGB or ``u8[H, W]`` grey left image (uint16 is scaled to 8 bits).
        calib: a :class:`~stereojax.data.datasets.Calibration` (baseline, focal, doffs, cx, cy).
        min_disp: smaller disparities are dropped.
        max_depth: if given, points farther than this (metres) are dropped.
    Returns:
        ``(f32[N, 3] xyz, u8[N, 3] rgb)`` in row-major pixel order.
    Raises:
        StereoInputError: missing calibration, or image and disparity sizes differ.
    """
    if calib is None:
        raise StereoInputError("a point cloud needs a calibration (baseline and focal length), got None")
    d = _disp2d(disp)
    img = np.asarray(image)
    if img.shape[:2] != d.shape or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3, 4))):
        raise StereoInputError(f"image is {wxh(img.shape)} but the disparity is "
                               f"{wxh(d.shape)}; expected [H, W] or [H, W, 3] of that size")
    z = disparity_to_depth(d, calib.baseline, calib.focal, getattr(calib, "doffs", 0.0), min_disp)
    h, w = d.shape
    cx = getattr(calib, "cx", None)
    cy = getattr(calib, "cy", None)
    cx = (w - 1) / 2.0 if cx is None else float(cx)
    cy = (h - 1) / 2.0 if cy is None else float(cy)
    keep = z > 0
    if max_depth is not None:
        keep &= z <= float(max_depth)
    vs, us = np.nonzero(keep)
    zk = z[keep].astype(np.float64)
    f = float(calib.focal)
    xyz = np.stack([(us - cx) * zk / f, (vs - cy) * zk / f, zk], axis=1).astype(np.float32)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.clip(np.rint(img.astype(np.float64)), 0, 255).astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        rgb = np.repeat(img[keep][:, None], 3, axis=1)
    else:
        rgb = img[keep][:, :3]
    return xyz.reshape(-1, 3), np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1, 3)


def write_ply(path: PathLike, xyz: np.ndarray, rgb: np.ndarray | None = None, binary: bool = True) -> None:
    """Write points ``f32[N, 3]`` (and colours ``u8[N, 3]``) as a PLY file, atomically.

    ``binary=True`` writes ``binary_little_endian 1.0``, otherwise ASCII. Vertex properties:
    ``float x, y, z`` and, with colours, ``uchar red, green, blue``.

    Raises:
        StereoInputError: shapes are not [N, 3] or differ in N.
        OutputError: the file cannot be written.
    """
    pts = np.asarray(xyz)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise StereoInputError(f"points must be an [N, 3] array, found shape {pts.shape}")
    cols = None
    if rgb is not None:
        cols = np.asarray(rgb)
        if cols.shape != pts.shape:
            raise StereoInputError(f"colours must be [N, 3] like the points {pts.shape}, found {cols.shape}")
        cols = np.clip(cols, 0, 255).astype(np.uint8)
    n = pts.shape[0]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if cols is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
              "comment written by stereojax", f"element vertex {n}",
              "property float x", "property float y", "property float z"]
    if cols is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header.append("end_header")
    head = ("\n".join(header) + "\n").encode("ascii")
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(head)
            if binary:
                rec = np.empty(n, dtype=fields)
                rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
                if cols is not None:
                    rec["red"], rec["green"], rec["blue"] = cols[:, 0], cols[:, 1], cols[:, 2]
                fh.write(rec.tobytes())
            else:
                p32 = pts.astype(np.float32)
                if cols is None:
                    lines = (f"{a:.7g} {b:.7g} {c:.7g}\n" for a, b, c in p32.tolist())
                else:
                    lines = (f"{a:.7g} {b:.7g} {c:.7g} {r} {g} {bl}\n"
                             for (a, b, c), (r, g, bl) in zip(p32.tolist(), cols.tolist()))
                fh.write("".join(lines).encode("ascii"))
