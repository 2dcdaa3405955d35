"""Cross construction and cross-based cost aggregation (CBCA) with integral images.

Each pixel p of the reference (left) grey image gets four arms (left, right, up, down):
an arm extends from p while the next pixel q satisfies |I(q) - I(p)| < tau and the arm is
at most ``arm_length`` long. One CBCA pass sums the cost over the support region
"horizontal arms of every pixel on p's vertical arm" (horizontal pass, then vertical
pass) and divides by the number of pixels in that region. Sums over arms are two reads of
an integral image (cumulative sum), so a pass costs O(H W D) whatever the arm length.

The arms come from the reference image only (Zhang et al.'s cross), which keeps them
independent of d; MC-CNN additionally intersects them with the arms of the right image at
(x - d), which needs a per-disparity arm volume.

Two kernels: the JAX kernel below (the reference, and the path on every platform other than
the CPU) and the native C++ kernel beside it (``cross_based.cc``, an XLA FFI call); the public
functions :func:`cbca` and :func:`cbca_volume` pick one by their ``kernels`` setting
(:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod
from stereojax.volume import BIG


class Arms(NamedTuple):
    """Arm lengths in pixels (0 .. arm_length), each ``i32[H, W]``."""

    left: jax.Array
    right: jax.Array
    up: jax.Array
    down: jax.Array


def cross_arms(grey: jax.Array, tau: float, arm_length: int, mask=None) -> Arms:
    """Arm lengths of every pixel of ``f32[H, W]`` grey image (see module docstring).

    mask: ``bool[H, W]`` real pixels of a pair padded to its size bucket (None: all real); no
    arm reaches into the padding, as none reaches out of an unpadded image.
    """
    h, w = grey.shape
    big = jnp.float32(BIG)   # padding and out-of-image pixels never join an arm
    if mask is not None:
        grey = jnp.where(mask, grey, big)
    padded = jnp.pad(grey, arm_length, constant_values=big)
    arms = []
    for dy, dx in ((0, -1), (0, 1), (-1, 0), (1, 0)):
        alive = jnp.ones((h, w), jnp.bool_)
        length = jnp.zeros((h, w), jnp.int32)
        for k in range(1, arm_length + 1):
            y0, x0 = arm_length + dy * k, arm_length + dx * k
            q = padded[y0:y0 + h, x0:x0 + w]
            alive = alive & (jnp.abs(q - grey) < tau)
            length = length + alive.astype(jnp.int32)
        arms.append(length)
    return Arms(*arms)


# Up to this arm length a sum over an arm is a masked sum of shifted copies (one fused,
# vectorised pass, about 5x faster on CPU than gathering from an integral image); above it
# the integral image wins because its cost does not grow with the arm length.
SHIFT_SUM_MAX_ARM = 8


def _shift_sum(volume: jax.Array, before: jax.Array, after: jax.Array, axis: int, max_arm: int):
    """out[p] = sum of volume[p + k e_axis] for -before[p] <= k <= after[p] (|k| <= max_arm)."""
    pad = [(0, 0)] * volume.ndim
    pad[axis] = (max_arm, max_arm)
    padded = jnp.pad(volume, pad)
    n = volume.shape[axis]
    total = jnp.zeros_like(volume)
    extra = (None,) * (volume.ndim - 2)
    for k in range(-max_arm, max_arm + 1):
        shifted = jax.lax.slice_in_dim(padded, max_arm + k, max_arm + k + n, axis=axis)
        take = (k >= -before) & (k <= after)
        total = total + jnp.where(take[(...,) + extra], shifted, 0.0)
    return total


def _horizontal_sum(volume: jax.Array, left: jax.Array, right: jax.Array, max_arm: int = 0) -> jax.Array:
    """out[y, x] = sum of volume[y, x - left : x + right + 1] (over axis 1), any trailing axes.

    ``max_arm``: an upper bound of the arms; when <= SHIFT_SUM_MAX_ARM the shifted-sum path is used.
    """
    if 0 < max_arm <= SHIFT_SUM_MAX_ARM:
        return _shift_sum(volume, left, right, 1, max_arm)
    h, w = left.shape
    s = jnp.cumsum(volume, axis=1)
    s = jnp.concatenate([jnp.zeros_like(s[:, :1]), s], axis=1)            # [H, W + 1, ...]
    x = jnp.arange(w)[None, :]
    y = jnp.arange(h)[:, None]
    return s[y, x + right + 1] - s[y, x - left]


def _vertical_sum(volume: jax.Array, up: jax.Array, down: jax.Array, max_arm: int = 0) -> jax.Array:
    """out[y, x] = sum of volume[y - up : y + down + 1, x] (over axis 0), any trailing axes."""
    if 0 < max_arm <= SHIFT_SUM_MAX_ARM:
        return _shift_sum(volume, up, down, 0, max_arm)
    h, w = up.shape
    s = jnp.cumsum(volume, axis=0)
    s = jnp.concatenate([jnp.zeros_like(s[:1]), s], axis=0)                # [H + 1, W, ...]
    x = jnp.arange(w)[None, :]
    y = jnp.arange(h)[:, None]
    return s[y + down + 1, x] - s[y - up, x]


def support_sizes(arms: Arms) -> jax.Array:
    """``f32[H, W]``: number of pixels in each pixel's cross-based support region."""
    left, right, up, down = arms
    ones = jnp.ones(left.shape, jnp.float32)
    return _vertical_sum(_horizontal_sum(ones, left, right), up, down)


def cbca_xla(cost: jax.Array, arms: Arms, iterations: int, max_arm: int = 0) -> jax.Array:
    """The JAX kernel of :func:`cbca`. Cross-based aggregation of ``f32[H, W, D]`` cost, ``iterations`` passes; returns f32[H, W, D].

    max_arm: the ``arm_length`` the arms were built with (selects the summation kernel; 0 =
    unknown, use integral images).
    """
    if iterations == 0:
        return cost
    left, right, up, down = arms
    norm = (1.0 / support_sizes(arms))[:, :, None]

    def one_pass(c, _):
        c = _vertical_sum(_horizontal_sum(c, left, right, max_arm), up, down, max_arm) * norm
        return c, None

    cost, _ = jax.lax.scan(one_pass, cost, None, length=iterations)
    return cost


# ---- per-pixel disparity bands ---------------------------------------------------------------

def _band_shift_sum(values, offset, before, after, axis: int, max_arm: int, neutral, weight=None):
    """Banded arm sum: out[p, j] = sum over q = p + k e_axis (-before[p] <= k <= after[p]) of
    ``values[q, j + offset[p] - offset[q]]`` (the neighbour at the same *absolute* disparity),
    or of ``neutral[p, j] * weight[q]`` where that disparity lies outside q's band (weight
    ``f32[H, W]``, None: 1).

    A ``fori_loop`` over the shifts: unrolled, XLA fused each pass into the next one's gathers
    and recomputed it (measured on a KITTI frame at K = 32: 2.3 s for two passes against 0.3 s).
    """
    k_band = values.shape[-1]
    pad = [(0, 0)] * 3
    pad[axis] = (max_arm, max_arm)
    vals = jnp.pad(values, pad)
    offs = jnp.pad(offset, pad[:2])
    wgts = None if weight is None else jnp.pad(weight, pad[:2])
    n = values.shape[axis]
    j = jnp.arange(k_band, dtype=jnp.int32)

    def body(i, total):
        v = jax.lax.dynamic_slice_in_dim(vals, i, n, axis=axis)
        o = jax.lax.dynamic_slice_in_dim(offs, i, n, axis=axis)
        nu = neutral
        if wgts is not None:
            nu = neutral * jax.lax.dynamic_slice_in_dim(wgts, i, n, axis=axis)[..., None]
        shift = offset - o
        idx = j + shift[..., None]
        inside = (idx >= 0) & (idx < k_band)
        got = jnp.take_along_axis(v, jnp.clip(idx, 0, k_band - 1), axis=-1)
        k = i - max_arm
        take = ((k >= -before) & (k <= after))[..., None]
        return total + jnp.where(take, jnp.where(inside, got, nu), 0.0)

    return jax.lax.fori_loop(0, 2 * max_arm + 1, body, jnp.zeros_like(values))


def cbca_volume_xla(vol, arms: Arms, iterations: int, max_arm: int):
    """The JAX kernel of :func:`cbca_volume`. CBCA of a :class:`~stereojax.volume.CostVolume`; returns one with the same bands.

    Full range: :func:`cbca`. Bands: a neighbour q is read at the same absolute disparity as p;
    where that disparity lies outside q's band, q counts with p's own value (p's cost in the
    horizontal pass; p's horizontal mean times q's horizontal arm count in the vertical pass),
    so it neither pulls p's cost up nor down. A band covering the whole range gives :func:`cbca`.
    """
    if iterations == 0:
        return vol
    if not vol.banded:
        return vol.with_cost(cbca_xla(vol.cost, arms, iterations, max_arm))
    left, right, up, down = arms
    norm = (1.0 / support_sizes(arms))[:, :, None]
    h_len = (left + right + 1).astype(jnp.float32)
    off = vol.offset

    def one_pass(c, _):
        hs = _band_shift_sum(c, off, left, right, 1, max_arm, c)
        vs = _band_shift_sum(hs, off, up, down, 0, max_arm, hs / h_len[..., None], h_len)
        return vs * norm, None

    cost, _ = jax.lax.scan(one_pass, vol.cost, None, length=iterations)
    return vol.with_cost(cost)


# ---- the native kernel (cross_based.cc) and the switch ---------------------------------------

def cbca_native(cost: jax.Array, offset: jax.Array, arms: Arms, iterations: int, banded: bool = True) -> jax.Array:
    """The native kernel (``cross_based.cc``): ``iterations`` CBCA passes of the band
    ``[offset, offset + K)`` costs ``f32[H, W, K]`` (the full range: offset 0, ``banded=False``);
    the result of :func:`cbca_volume_xla` / :func:`cbca_xla`."""
    call = jax.ffi.ffi_call("stereojax_cbca", jax.ShapeDtypeStruct(cost.shape, jnp.float32),
                            vmap_method="sequential")
    return call(cost.astype(jnp.float32), offset.astype(jnp.int32), *(a.astype(jnp.int32) for a in arms),
                iterations=np.int32(iterations), banded=np.int32(bool(banded)),
                threads=np.int32(kernels_mod.threads()))


def cbca(cost: jax.Array, arms: Arms, iterations: int, max_arm: int = 0, kernels: str = "auto") -> jax.Array:
    """Cross-based aggregation of ``f32[H, W, D]`` cost, ``iterations`` passes; returns f32[H, W, D].

    max_arm: the ``arm_length`` the arms were built with (selects the summation kernel of the
    JAX kernel; 0 = unknown, use integral images). kernels: see :mod:`stereojax.kernels`.
    """
    if iterations == 0:
        return cost

    def native(c, a):
        return cbca_native(c, jnp.zeros(c.shape[:2], jnp.int32), a, iterations, banded=False)

    return kernels_mod.select(kernels, native, functools.partial(cbca_xla, iterations=iterations, max_arm=max_arm),
                              cost, arms)


def cbca_volume(vol, arms: Arms, iterations: int, max_arm: int, kernels: str = "auto"):
    """CBCA of a :class:`~stereojax.volume.CostVolume` (see :func:`cbca_volume_xla`) with the
    kernel of the ``kernels`` setting; returns one with the same bands."""
    if iterations == 0:
        return vol

    def native(v, a):
        return v.with_cost(cbca_native(v.cost, v.offset, a, iterations, v.banded))

    return kernels_mod.select(kernels, native, functools.partial(cbca_volume_xla, iterations=iterations,
                                                                 max_arm=max_arm), vol, arms)
