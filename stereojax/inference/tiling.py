"""Large pairs in horizontal strips: a frame whose volumes exceed the memory limit is computed
strip by strip and stitched.

A strip keeps the full width (so the disparity range, the horizontal SGM paths and the
left-right check are those of the whole frame) and adds ``overlap`` rows of context above and
below the rows it keeps; the vertical SGM paths, the cross arms, the census window and the
network's patch see no further than the strip, which is why the overlap is there. All strips have
the same height, so they share one compiled program. Peak memory is that of one strip.
"""

from __future__ import annotations

import numpy as np

from stereojax.errors import MemoryBudgetError
from stereojax.inference.compile_cache import bucket_shape
from stereojax.inference.memory import OVERHEAD, chain_peak_bytes, memory_limit

#: rows of context above and below the rows a strip keeps. Chosen by measurement
#: (experiments/tiling.py -> experiments/results/tiling.md): with this many, the stitched
#: disparity equals the whole-frame one except on a few pixels near the seams.
SEAM_OVERLAP = 48
#: strip heights are multiples of this (the size buckets of the compile cache)
ROW_STEP = 32
#: a strip may use this share of the memory limit above the fixed overhead (the available
#: memory, and so the limit, changes a little between choosing the strips and checking each one)
BAND_SHARE = 0.9


def fits(height: int, width: int, config, limit_gb=None) -> bool:
    """Whether the whole frame fits the memory limit (:func:`stereojax.inference.memory.check_memory`)."""

    return chain_peak_bytes(height, width, config) <= memory_limit(limit_gb)[0]


def strip_rows(height: int, width: int, config, limit_gb=None, overlap: int = SEAM_OVERLAP) -> int:
    """The height of the largest strip (a multiple of 32 rows, at most the frame's height) whose
    chain, padded to its size bucket, fits in ``BAND_SHARE`` of the memory limit above the fixed
    overhead (the limit is read again for every strip, from the memory available then). Raises
    :class:`MemoryBudgetError` when not even a strip with ``2 * overlap + 32`` rows fits."""

    limit, source = memory_limit(limit_gb)
    budget = OVERHEAD + BAND_SHARE * (limit - OVERHEAD)
    need = min(2 * overlap + ROW_STEP, height)
    candidates = [height] + list(range((height - 1) // ROW_STEP * ROW_STEP, need - 1, -ROW_STEP))
    rows = next((r for r in candidates if r >= need and chain_peak_bytes(*bucket_shape(r, width), config) <= budget), 0)
    if rows < need:
        raise MemoryBudgetError(
            f"a {height}x{width} frame with {config.max_disp} disparities does not fit the memory limit of "
            f"{limit / 2 ** 30:.1f} GiB ({source}) even in strips of {need} rows (about "
            f"{chain_peak_bytes(need, width, config) / 2 ** 30:.1f} GiB each); use a smaller --max-disp or "
            "downscale the pair")
    return rows


def strips(height: int, rows: int, overlap: int = SEAM_OVERLAP) -> list[tuple[int, int, int, int]]:
    """``(start, stop, keep_from, keep_to)`` per strip: the strip covers rows start..stop (all strips
    ``rows`` high), and rows keep_from..keep_to of the frame are taken from it. The kept rows tile
    the frame; each has ``overlap`` rows of context on both sides wherever the frame has them."""
    if rows >= height:
        return [(0, height, 0, height)]
    if rows - 2 * overlap < 1:
        raise ValueError(f"a strip of {rows} rows leaves nothing to keep with an overlap of {overlap}")
    out, k0 = [], 0
    while k0 < height:
        start = min(max(k0 - overlap, 0), height - rows)
        stop = start + rows
        k1 = height if stop == height else stop - overlap
        out.append((start, stop, k0, k1))
        k0 = k1
    return out


def run_in_strips(predict, left, right, rows: int, overlap: int = SEAM_OVERLAP, on_strip=None, limits=None):
    """``predict(left_strip, right_strip)`` on every strip and the results stitched: a disparity
    ``f32[H, W]``, or a tuple of such maps when ``predict`` returns one (e.g. with confidence).
    ``on_strip()`` is called after each strip (a progress bar's update). ``limits``: per-pixel
    limits ``[2, H, W]``, cut into the same strips and passed as ``predict``'s third argument."""
    la, ra = np.asarray(left), np.asarray(right)
    height = la.shape[0]
    stitched = None
    for start, stop, k0, k1 in strips(height, rows, overlap):
        if limits is None:
            out = predict(la[start:stop], ra[start:stop])
        else:
            out = predict(la[start:stop], ra[start:stop], limits[:, start:stop])
        parts = out if isinstance(out, tuple) else (out,)
        if stitched is None:
            stitched = [np.empty((height,) + p.shape[1:], p.dtype) for p in parts]
        for whole, part in zip(stitched, parts):
            whole[k0:k1] = part[k0 - start:k1 - start]
        if on_strip is not None:
            on_strip()
    return tuple(stitched) if len(stitched) > 1 else stitched[0]
