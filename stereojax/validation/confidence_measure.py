"""Per-pixel confidence of the winner-takes-all disparity: cost margin times left-right agreement.

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).

:func:`confidence_volume` has two kernels: the JAX kernel (the reference, and the path on every
platform other than the CPU) and the native C++ kernel beside it (``confidence_measure.cc``, an
XLA FFI call), picked by its ``kernels`` setting (:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod


def confidence(cost: jax.Array, disp_wta: jax.Array, disp_right: jax.Array | None,
               lr_tolerance: float = 1.0, absolute=None) -> jax.Array:
    """Per-pixel confidence in [0, 1] of the winner-takes-all disparity, ``f32[H, W]``.

    The product of two terms: the *margin* of the aggregated cost ``f32[H, W, D]`` between its
    best disparity d1 and the best one at least 2 away, as ``(c2 - c1) / c2`` (0 when a rival
    is as good; 1 when the winner costs nothing), and the *left-right agreement*
    ``exp(-max(|d1 - D_R(x - d1)| - lr_tolerance, 0))`` (1 where the two views agree, smaller
    the more they differ; 0.5 where the match x - d1 leaves the right image and cannot be
    checked). Without a right view (``disp_right`` None) the margin alone. ``absolute``: the
    absolute disparity of ``disp_wta`` when ``cost`` is a band (``disp_wta`` its index)."""
    h, w, max_disp = cost.shape
    d1 = disp_wta.astype(jnp.int32)
    c1 = jnp.take_along_axis(cost, d1[..., None], axis=-1)[..., 0]
    near = jnp.abs(jnp.arange(max_disp)[None, None, :] - d1[..., None]) <= 1
    c2 = jnp.min(jnp.where(near, jnp.inf, cost), axis=-1)
    c2 = jnp.where(jnp.isfinite(c2), c2, c1)               # D <= 3: no rival
    margin = jnp.where(c2 > 0, jnp.clip((c2 - c1) / jnp.maximum(c2, 1e-12), 0.0, 1.0), 0.0)
    if disp_right is None:
        return margin
    if absolute is not None:
        d1 = absolute.astype(jnp.int32)
    xr = jnp.arange(w)[None, :] - d1
    dr = jnp.take_along_axis(disp_right.astype(jnp.float32), jnp.clip(xr, 0, w - 1), axis=1)
    agree = jnp.exp(-jnp.maximum(jnp.abs(d1.astype(jnp.float32) - dr) - lr_tolerance, 0.0))
    return margin * jnp.where(xr >= 0, agree, 0.5)


def confidence_volume_native(vol, disp_wta: jax.Array, disp_right, lr_tolerance: float = 1.0) -> jax.Array:
    """The native kernel (``confidence_measure.cc``) of :func:`confidence_volume_xla`."""
    h, w, _ = vol.cost.shape
    dr = jnp.zeros((h, w), jnp.int32) if disp_right is None else disp_right.astype(jnp.int32)
    call = jax.ffi.ffi_call("stereojax_confidence", jax.ShapeDtypeStruct((h, w), jnp.float32),
                            vmap_method="sequential")
    return call(vol.cost.astype(jnp.float32), vol.offset.astype(jnp.int32), disp_wta.astype(jnp.int32), dr,
                banded=np.int32(bool(vol.banded)), has_right=np.int32(disp_right is not None),
                tolerance=np.float32(lr_tolerance), threads=np.int32(kernels_mod.threads()))


def confidence_volume(vol, disp_wta: jax.Array, disp_right, lr_tolerance: float = 1.0,
                      kernels: str = "auto") -> jax.Array:
    """:func:`confidence` on a CostVolume (:func:`confidence_volume_xla`), with the kernel of the
    ``kernels`` setting."""
    native = functools.partial(confidence_volume_native, lr_tolerance=lr_tolerance)
    xla = functools.partial(confidence_volume_xla, lr_tolerance=lr_tolerance)
    return kernels_mod.select(kernels, native, xla, vol, disp_wta, disp_right)


def confidence_volume_xla(vol, disp_wta: jax.Array, disp_right, lr_tolerance: float = 1.0) -> jax.Array:
    """:func:`confidence` on a CostVolume: the margin between the best entry of the band and the
    best one at least 2 away within the band, times the left-right agreement."""
    if not vol.banded:
        return confidence(vol.cost, disp_wta, disp_right, lr_tolerance)
    return confidence(vol.cost, disp_wta - vol.offset, None if disp_right is None else disp_right,
                      lr_tolerance, absolute=disp_wta)


def texture_share(left: jax.Array, radius: tuple[int, int], noise: float) -> jax.Array:
    """``f32[H, W]``: the share of the pixels of the ``(2 ry + 1) x (2 rx + 1)`` window around each
    pixel (``radius`` = (ry, rx), the census window) whose grey level differs from the centre's by
    more than ``noise``: what a window-based cost has to work on (0 in saturated sky)."""
    ry, rx = int(radius[0]), int(radius[1])
    h, w = left.shape
    pad = jnp.pad(left.astype(jnp.float32), ((ry, ry), (rx, rx)), mode="edge")
    count = jnp.zeros((h, w), jnp.float32)
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dy or dx:
                count = count + (jnp.abs(pad[ry + dy:ry + dy + h, rx + dx:rx + dx + w] - left) > noise)
    return count / float((2 * ry + 1) * (2 * rx + 1) - 1)


def texture_factor(left: jax.Array, radius: tuple[int, int], noise: float, full: float) -> jax.Array:
    """The confidence's texture term: :func:`texture_share` / ``full``, capped at 1 (1 everywhere
    when ``full`` is 0)."""
    if full <= 0:
        return jnp.ones(left.shape, jnp.float32)
    return jnp.minimum(texture_share(left, radius, noise) / full, 1.0)
