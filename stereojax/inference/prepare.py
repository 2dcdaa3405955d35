"""A pair checked and made ready for the chain: sizes, ranges, per-pixel limits, grey images.

Every check raises one line (:class:`~stereojax.errors.StereoInputError`) before anything is
compiled or allocated; :func:`prepare_pair` also estimates the chain's peak memory
(:mod:`stereojax.inference.memory`).
"""

from __future__ import annotations

import numbers
import warnings
from typing import Any

import numpy as np

from stereojax.config import StereoConfig
from stereojax.data.images import as_grey, pair_float_scale
from stereojax.errors import InputWarning, StereoInputError, wxh
from stereojax.inference.memory import check_memory


def min_image_size(config: StereoConfig) -> int:
    """Smallest height/width the chain accepts (the largest window it uses)."""
    c = config.cost
    windows = [2 * max(c.census_radius) + 1, 2 * c.sad_radius + 1, config.refine.median_size,
               2 * config.refine.bilateral_radius + 1, 2 * config.cbca.arm_length + 1]
    return max(windows)


def check_disp_range(disp_range, width: int | None = None) -> tuple[int, int] | None:
    """``(MIN, MAX)`` as ints (disparities MIN <= d < MAX), or None; a one-line
    :class:`StereoInputError` for anything else: not two integers, MIN >= MAX, or (given the
    image ``width``) a range at least as wide as the image."""
    if disp_range is None:
        return None

    try:
        lo, hi = disp_range
    except (TypeError, ValueError):
        raise StereoInputError(f"disp_range must be two integers (MIN, MAX), got {disp_range!r}") from None
    for v in (lo, hi):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise StereoInputError(f"disp_range must be two integers (MIN, MAX), got {disp_range!r}")
    lo, hi = int(lo), int(hi)
    if lo >= hi:
        raise StereoInputError(f"disp_range MIN must be below MAX (disparities MIN <= d < MAX), got {lo} {hi}")
    if width is not None and hi - lo >= width:
        raise StereoInputError(f"disp_range {lo}..{hi} spans {hi - lo} disparities, as many as the image is wide "
                               f"({width}); give a narrower range")
    if width is not None and hi >= width:
        raise StereoInputError(f"disp_range {lo}..{hi} reaches the image width {width}: a match x - d lies inside "
                               f"the right image only for d < {width}; give MAX <= {width - 1}")
    return lo, hi


def check_pixel_range(pixel_range, shape: tuple[int, int], lo: int, hi: int) -> np.ndarray:
    """``i32[2, H, W]``: per-pixel limits (MIN, MAX maps, MIN <= d < MAX) checked and intersected
    with the range ``lo <= d < hi``; a one-line :class:`StereoInputError` for maps that are not
    two ``shape`` arrays of integers, or that leave a pixel no disparity."""
    try:
        mn, mx = pixel_range
        maps = np.stack([np.asarray(mn), np.asarray(mx)])
    except (TypeError, ValueError):
        raise StereoInputError("pixel_range must be two [H, W] maps (MIN, MAX) of the image's size "
                               f"{wxh(shape)}") from None
    if maps.shape != (2,) + tuple(shape):
        got = wxh(maps.shape[1:]) if maps.ndim == 3 else f"shape {maps.shape[1:]}"
        raise StereoInputError(f"pixel_range maps are {got}, the image is {wxh(shape)}")
    if maps.dtype.kind not in "iu":
        if maps.dtype.kind != "f" or not np.all(np.isfinite(maps)) or np.any(maps != np.round(maps)):
            raise StereoInputError("pixel_range maps must hold integers (disparities MIN <= d < MAX)")
    maps = np.clip(maps.astype(np.int64), lo, hi).astype(np.int32)
    empty = maps[0] >= maps[1]
    if empty.any():
        y, x = (int(v[0]) for v in np.nonzero(empty))
        raise StereoInputError(f"pixel_range leaves {int(empty.sum())} pixels no disparity (e.g. at row {y}, "
                               f"column {x}: MIN {int(np.asarray(mn)[y, x])}, MAX {int(np.asarray(mx)[y, x])}, "
                               f"within the range {lo}..{hi}); each needs MIN < MAX inside it")
    return maps


def shift_right_image(grey: np.ndarray, lo: int) -> np.ndarray:
    """The right image moved by ``lo`` columns, edges repeated: out[:, u] = grey[:, u - lo], so that
    disparity d of the original pair is disparity d - lo of (left, out)."""
    if lo == 0:
        return grey
    w = grey.shape[1]
    cols = np.clip(np.arange(w) - lo, 0, w - 1)
    return np.ascontiguousarray(grey[:, cols])


def range_pair(gl: np.ndarray, gr: np.ndarray, lo: int, config: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """The grey pair the chain searches for a range starting at ``lo`` (disparities lo <= d < MAX are
    d - lo of the result), with the right image's real left edge where the chain puts it.

    ``lo > 0``: the left image without its first ``lo`` columns and the right image without its
    last ``lo`` (``left[:, lo:]``, ``right[:, :W - lo]``): pixel x of the result is x + lo of the
    pair, and its match x - (d - lo) is the pair's x + lo - d, so a match leaves the result's right
    image (x - d' < 0) exactly where it leaves the pair's, and the out-of-view strip (``cost.border``),
    the left-right check and the coarse pass see the image's edge. The left columns x < lo have no
    match inside the right image at any disparity of the range; the chain does not search them
    (:class:`~stereojax.inference.predictor.Predictor` gives them the disparity of column lo and
    confidence 0). Moving the right image by ``lo`` instead (:func:`shift_right_image`) invents
    ``lo`` repeated columns at its left edge, which the chain takes for real ones: on Middlebury
    scenes that cost up to 2.9 points > 3 px against [0, MAX) (docs/results.md, issue 55).
    ``lo < 0``: the right image moved by ``lo`` (:func:`shift_right_image`); ``lo == 0``: the pair.
    Raises a one-line :class:`StereoInputError` when fewer columns than the config's largest window
    are left."""
    if lo <= 0:
        return gl, shift_right_image(gr, lo)
    w = gl.shape[1]
    need = max(min_image_size(config), config.max_disp + 1)
    if w - lo < need:
        raise StereoInputError(f"disp_range MIN {lo} leaves {w - lo} of the image's {w} columns to search, fewer "
                               f"than the {need} the configuration needs; give a smaller MIN")
    return np.ascontiguousarray(gl[:, lo:]), np.ascontiguousarray(gr[:, :w - lo])


def _kind(arr: np.ndarray) -> str:
    return f"{'colour' if arr.ndim == 3 else 'grey'} {arr.dtype}"


def check_size(h: int, w: int, config: StereoConfig) -> None:
    """Refuse an ``h x w`` pair too small for ``config``'s windows or disparity range."""
    need = min_image_size(config)
    if h < need or w < need:
        raise StereoInputError(f"image is {w}x{h}, smaller than the {need}x{need} window the "
                               "configuration needs")
    if config.max_disp >= w:
        raise StereoInputError(f"max_disp must be smaller than the image width {w}, got {config.max_disp}")


def prepare_pair(left: Any, right: Any, config: StereoConfig, memory_limit_gb=None,
                 keep: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Check a pair against a config; return grey ``f32[H, W]`` left and right images.

    A colour image paired with a grey one (or 8-bit with 16-bit/float) is accepted: both are
    converted to grey 0..255, with an :class:`~stereojax.errors.InputWarning` saying so.
    Before returning, the chain's peak memory is estimated (:mod:`stereojax.inference.memory`) and a
    frame that would not fit in ``memory_limit_gb`` (default: ``STEREOJAX_MEMORY_LIMIT_GB``,
    else 70 % of the available memory) raises :class:`MemoryBudgetError`.
    """
    config.validate()
    la, ra = np.asarray(left), np.asarray(right)
    scale = pair_float_scale(la, ra)
    gl, gr = as_grey(la, "left", scale), as_grey(ra, "right", scale)
    if gl.shape != gr.shape:
        raise StereoInputError(f"left is {wxh(gl.shape)} but right is {wxh(gr.shape)}; a rectified pair has equal "
                               "sizes")
    if (la.ndim == 3) != (ra.ndim == 3) or la.dtype != ra.dtype:
        warnings.warn(f"left is {_kind(la)} but right is {_kind(ra)}; both converted to grey "
                      "0..255 before matching", InputWarning, stacklevel=3)
    h, w = gl.shape
    check_size(h, w, config)
    check_memory(h, w, config, memory_limit_gb, keep=keep)
    return gl, gr
