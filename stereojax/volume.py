"""The cost-volume type every stage of the chain takes and returns.

A :class:`CostVolume` holds, for every pixel of the left (reference) view, the costs of a
*band* of ``K`` consecutive disparities:

* ``cost`` ``f32[H, W, K]``: entry ``k`` of pixel (y, x) is the cost of the absolute disparity
  ``offset[y, x] + k`` (lower is better);
* ``offset`` ``i32[H, W]``: the first disparity of each pixel's band, ``0 <= offset <= D - K``;
* ``valid`` ``i32[2]`` or None: the real (rows, columns) of a pair padded on the right and
  bottom to its size bucket (:mod:`stereojax.inference.compile_cache`); None when nothing is padded;
* ``max_disp`` (static): the full range ``D``; absolute disparities are ``0 .. D - 1``;
* ``banded`` (static): False for the full range (``K == D``, offset 0 everywhere), which
  every stage runs with its full-volume kernel; True for per-pixel bands.

The full range is the special case ``offset == 0, K == D``: a stage given a banded volume whose
band covers the whole range returns what its full-volume kernel returns (tests/system/test_bands.py).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp

#: the one sentinel of the chain: the cost of an entry outside a band or a pixel's limits where a
#: stage must read one (SGM's predecessor, the right view, WTA), and the grey value that keeps the
#: padding out of every cross arm; larger than any real cost or grey value, finite so that sums
#: stay finite (never NaN or inf)
BIG = 1e9


def real_pixels(shape, valid):
    """``bool[H, W]``: the real pixels (rows < valid[0], columns < valid[1]) of a pair padded on
    the right and bottom to its size bucket, ``valid`` a traced ``i32[2]``; None when ``valid``
    is None (nothing padded). With :func:`real_bounds`, the one spelling of the padding."""
    if valid is None:
        return None
    h, w = shape
    return (jnp.arange(h)[:, None] < valid[0]) & (jnp.arange(w)[None, :] < valid[1])


def real_bounds(valid):
    """(first row, end row, first column, end column) of the real pixels (see
    :func:`real_pixels`), or None when nothing is padded: the form the path loops of SGM take."""
    return None if valid is None else (0, valid[0], 0, valid[1])


@dataclass(frozen=True)
class CostVolume:
    cost: jax.Array
    offset: jax.Array
    valid: jax.Array | None
    max_disp: int
    banded: bool = True

    @property
    def k(self) -> int:
        return self.cost.shape[-1]

    @property
    def shape(self) -> tuple[int, int]:
        return self.cost.shape[:2]

    @classmethod
    def full(cls, cost: jax.Array, valid=None) -> "CostVolume":
        """The full-range volume of ``f32[H, W, D]`` costs (offset 0 everywhere)."""
        h, w, d = cost.shape
        return cls(cost, jnp.zeros((h, w), jnp.int32), valid, d, banded=False)

    @classmethod
    def band(cls, cost: jax.Array, offset: jax.Array, max_disp: int, valid=None) -> "CostVolume":
        return cls(cost, offset.astype(jnp.int32), valid, int(max_disp), banded=True)

    def with_cost(self, cost: jax.Array) -> "CostVolume":
        """The same bands with other costs (the output of a stage)."""
        return dataclasses.replace(self, cost=cost)

    def disparities(self) -> jax.Array:
        """``i32[H, W, K]``: the absolute disparity of every entry."""
        return self.offset[..., None] + jnp.arange(self.k, dtype=jnp.int32)

    def real_mask(self):
        """``bool[H, W]`` real pixels, or None when nothing is padded."""
        return real_pixels(self.shape, self.valid)

    def at(self, disp: jax.Array, fill: float = BIG) -> jax.Array:
        """The cost at absolute disparities ``disp`` ``i32[H, W]`` (``fill`` outside the band)."""
        j = disp.astype(jnp.int32) - self.offset
        inside = (j >= 0) & (j < self.k)
        c = jnp.take_along_axis(self.cost, jnp.clip(j, 0, self.k - 1)[..., None], axis=-1)[..., 0]
        return jnp.where(inside, c, fill)

    def to_full(self, fill: float = 1.0) -> jax.Array:
        """``f32[H, W, D]`` with every entry outside the band set to ``fill`` (for inspection
        and tests; the chain never builds it)."""
        h, w = self.shape
        if not self.banded:
            return self.cost
        yy, xx = jnp.mgrid[:h, :w]
        full = jnp.full((h, w, self.max_disp), fill, self.cost.dtype)
        return full.at[yy[..., None], xx[..., None], self.disparities()].set(self.cost)


jax.tree_util.register_dataclass(CostVolume, data_fields=["cost", "offset", "valid"],
                                 meta_fields=["max_disp", "banded"])


def band_from_full(full: jax.Array, offset: jax.Array, k: int, valid=None) -> CostVolume:
    """The band ``[offset, offset + k)`` of every pixel of a full ``f32[H, W, D]`` volume."""
    d = full.shape[-1]
    idx = offset[..., None] + jnp.arange(k)
    return CostVolume.band(jnp.take_along_axis(full, idx, axis=-1), offset, d, valid)


def windows(values: jax.Array, start: jax.Array, size: int) -> jax.Array:
    """``values[..., start : start + size]`` for every element of the batch: values
    ``[*B, L]``, start ``i32[*B]`` (0 <= start <= L - size; clip it first), result ``[*B, size]``.

    A gather of contiguous slices (``vmap`` of ``dynamic_slice``): on the CPU about 3x faster
    than gathering the same entries one by one with ``take_along_axis`` for the census band
    (:func:`stereojax.matching_cost.classical.census_band`), and faster for SGM's predecessor and its right-image
    gradients (:mod:`stereojax.optimization.semi_global`); for CBCA it was slower, so CBCA gathers entries
    (docs/results.md).
    """
    def one(v, s):
        return jax.lax.dynamic_slice_in_dim(v, s, size, axis=0)

    fn = one
    for _ in range(start.ndim):
        fn = jax.vmap(fn)
    return fn(values, start)
