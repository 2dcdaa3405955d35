"""Disparity error metrics with the KITTI devkit's conventions (numpy only).

* ``bad<t>``: percent of ground-truth pixels whose absolute error exceeds ``t`` px.
* ``d1``: KITTI's outlier rate, percent of ground-truth pixels whose error exceeds 3 px
  *and* 5 % of the true disparity.
* ``epe``: mean absolute error (end-point error) in px.
* ``density``: percent of all image pixels that have an estimate.

Sparse estimates are handled like the devkit does: missing pixels are filled by
:func:`interpolate_background` before scoring (``fill="interpolate"``), or, with
``fill="error"``, counted as errors.
"""

from __future__ import annotations

from typing import Iterable, Mapping, Sequence

import numpy as np

from stereojax.errors import StereoInputError, wxh

__all__ = ["interpolate_background", "evaluate", "mean_metrics"]

#: KITTI outlier criterion: error > 3 px and > 5 % of the true disparity.
KITTI_TAU = (3.0, 0.05)


def _fill_lines(values: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill invalid runs along axis 1 with the smaller of the two bounding valid values;
    runs touching an end take the nearest valid value. Lines without any valid entry are
    left as they are. Returns (filled f32[N, M], bool[N] line has a valid entry)."""
    n, m = values.shape
    idx = np.arange(m)
    # index of the nearest valid entry at or before / at or after each position (-1 / m: none)
    before = np.maximum.accumulate(np.where(valid, idx, -1), axis=1)
    after = np.minimum.accumulate(np.where(valid, idx, m)[:, ::-1], axis=1)[:, ::-1]
    has_before, has_after = before >= 0, after < m
    v_before = np.take_along_axis(values, np.clip(before, 0, m - 1), axis=1)
    v_after = np.take_along_axis(values, np.clip(after, 0, m - 1), axis=1)
    filled = np.where(has_before & has_after, np.minimum(v_before, v_after),
                      np.where(has_before, v_before, v_after))
    line_ok = valid.any(axis=1)
    filled = np.where(line_ok[:, None], filled, values)
    return filled.astype(np.float32), line_ok


def interpolate_background(disp: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Fill pixels without an estimate the way the KITTI devkit does (``interpolateBackground``).

    Along each row, every run of invalid pixels between two valid ones takes the smaller
    (background) of the two bounding values; invalid pixels before the first / after the
    last valid pixel of a row take that pixel's value. Rows without any valid pixel are then
    filled column-wise by the same rule from the rows that have one: rows above the first /
    below the last such row copy it (the devkit's vertical extrapolation) and an empty row
    between two such rows takes the smaller of the two values above and below (the devkit
    leaves those undefined). If no pixel is valid the result is all zeros.

    Args:
        disp: ``f32[H, W]`` disparity; values at invalid pixels are ignored (may be NaN).
        valid: ``bool[H, W]`` pixels that have an estimate.
    Returns:
        ``f32[H, W]`` dense disparity, equal to ``disp`` at valid pixels.
    """
    d = np.asarray(disp, dtype=np.float32)
    v = np.asarray(valid, dtype=bool)
    if d.ndim != 2 or v.shape != d.shape:
        raise StereoInputError(f"interpolate_background expects disp [H, W] and a mask of the same "
                               f"shape, found {d.shape} and {v.shape}")
    v = v & np.isfinite(d)
    if not v.any():
        return np.zeros(d.shape, np.float32)
    rows, row_ok = _fill_lines(np.where(v, d, 0).astype(np.float32), v)
    if row_ok.all():
        return rows
    col_valid = np.broadcast_to(row_ok[None, :], (d.shape[1], d.shape[0]))
    cols, _ = _fill_lines(np.ascontiguousarray(rows.T), col_valid)
    return np.ascontiguousarray(cols.T)


def _threshold_key(t: float) -> str:
    return f"bad{t:g}"


def evaluate(disp: np.ndarray, gt: np.ndarray, gt_valid: np.ndarray | None,
             est_valid: np.ndarray | None = None, thresholds: Sequence[float] = (2, 3, 4, 5),
             fill: str = "interpolate") -> dict:
    """Score ``f32[H, W]`` disparity against ``f32[H, W]`` ground truth.

    Args:
        disp: estimated disparity. Pixels that are NaN, infinite, negative or exactly 0, or
            False in ``est_valid``, have no estimate: 0 is "no value" in KITTI's 16-bit PNGs
            (the devkit reads it as invalid), and stereojax writes 0 there too.
        gt: ground-truth disparity.
        gt_valid: ``bool[H, W]`` pixels with ground truth (None: finite and > 0). Non-finite
            ground truth is never scored.
        est_valid: optional ``bool[H, W]`` mask of pixels with an estimate.
        thresholds: pixel thresholds of the ``bad<t>`` keys.
        fill: ``"interpolate"``: pixels without estimate are filled with
            :func:`interpolate_background` and scored like the others (KITTI's rule; ``epe``
            covers every ground-truth pixel). ``"error"``: they count as errors in every
            ``bad<t>`` and in ``d1``, and ``epe`` is the mean over the ground-truth pixels
            that have an estimate only (NaN if there are none).
    Returns:
        ``{"bad2", "bad3", "bad4", "bad5", "d1", "epe", "density", "n_gt"}``: percentages in
        [0, 100], ``epe`` in px, ``density`` = percent of all pixels with an estimate,
        ``n_gt`` = number of ground-truth pixels scored (int).
    Raises:
        StereoInputError: shapes differ, unknown ``fill``, or no ground-truth pixel.
    """
    d = np.asarray(disp)
    g = np.asarray(gt)
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2:
        raise StereoInputError(f"disparity must be a 2-D [H, W] array, found shape {d.shape}")
    if g.shape != d.shape:
        raise StereoInputError(f"ground truth is {wxh(g.shape)} but the disparity is {wxh(d.shape)}")
    if fill not in ("interpolate", "error"):
        raise StereoInputError(f"fill must be 'interpolate' or 'error', got {fill!r}")
    d = d.astype(np.float32, copy=False)
    g = g.astype(np.float32, copy=False)
    with np.errstate(invalid="ignore"):
        gv = np.isfinite(g) & (g > 0) if gt_valid is None else _mask(gt_valid, d.shape, "gt_valid") & np.isfinite(g)
        est = np.isfinite(d) & (d > 0)
    if est_valid is not None:
        est &= _mask(est_valid, d.shape, "est_valid")
    n_gt = int(gv.sum())
    if n_gt == 0:
        raise StereoInputError("no ground-truth pixels to score: gt_valid is empty "
                               "(or the ground truth is not finite)")
    g_s = g[gv].astype(np.float64)
    if fill == "interpolate":
        dense = d if est.all() else interpolate_background(d, est)
        err = np.abs(dense[gv].astype(np.float64) - g_s)
        have = np.ones(n_gt, bool)
    else:
        have = est[gv]
        err = np.where(have, np.abs(np.where(est, d, 0)[gv].astype(np.float64) - g_s), np.inf)
    out = {}
    for t in thresholds:
        out[_threshold_key(float(t))] = 100.0 * float(np.count_nonzero(err > t)) / n_gt
    outlier = (err > KITTI_TAU[0]) & (err > KITTI_TAU[1] * np.abs(g_s))
    out["d1"] = 100.0 * float(np.count_nonzero(outlier)) / n_gt
    out["epe"] = float(err[have].mean()) if have.any() else float("nan")
    out["density"] = 100.0 * float(np.count_nonzero(est)) / est.size
    out["n_gt"] = n_gt
    return out


def mean_metrics(rows: Iterable[Mapping]) -> dict:
    """Average per-frame metric dicts (e.g. from :func:`evaluate`) over frames.

    Every numeric key present in all rows is the plain mean over frames (each frame weighs the
    same, as in KITTI's per-frame tables; *not* weighted by pixel count), ignoring NaN values
    (``epe`` of a frame without estimates in ``fill="error"`` mode). ``n_gt`` is summed
    instead, and ``n_frames`` is added.

    Raises:
        StereoInputError: no rows.
    """
    rows = list(rows)
    if not rows:
        raise StereoInputError("mean_metrics needs at least one frame, got none")
    keys = [k for k in rows[0] if all(k in r for r in rows)]
    out = {}
    for k in keys:
        vals = [r[k] for r in rows]
        if not all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                   for v in vals):
            continue
        if k == "n_gt":
            out[k] = int(sum(int(v) for v in vals))
            continue
        arr = np.asarray(vals, np.float64)
        finite = arr[~np.isnan(arr)]
        out[k] = float(finite.mean()) if finite.size else float("nan")
    out["n_frames"] = len(rows)
    return out


def _mask(m, shape, name) -> np.ndarray:
    arr = np.asarray(m)
    if arr.shape != tuple(shape):
        raise StereoInputError(f"{name} must have the disparity's shape {tuple(shape)}, found {arr.shape}")
    return arr.astype(bool)
