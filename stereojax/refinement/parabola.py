"""Sub-pixel refinement: a parabola through the costs at d - 1, d, d + 1.

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stereojax.volume import BIG


def subpixel(cost: jax.Array, disp: jax.Array) -> jax.Array:
    """Parabola fit through the costs at d - 1, d, d + 1 around integer ``disp``; ``f32[H, W]``.

    d_sub = d - (C+ - C-) / (2 (C+ - 2 C + C-)), applied where 0 < d < D - 1, neither
    neighbour lies outside the pixel's limits (:data:`~stereojax.volume.BIG`) and the
    parabola opens upwards; the offset is clamped to [-0.5, 0.5].
    """
    max_disp = cost.shape[-1]
    d = jnp.clip(jnp.round(disp).astype(jnp.int32), 0, max_disp - 1)
    c0 = jnp.take_along_axis(cost, d[..., None], axis=-1)[..., 0]
    cm = jnp.take_along_axis(cost, jnp.clip(d - 1, 0, max_disp - 1)[..., None], axis=-1)[..., 0]
    cp = jnp.take_along_axis(cost, jnp.clip(d + 1, 0, max_disp - 1)[..., None], axis=-1)[..., 0]
    denom = cp - 2.0 * c0 + cm
    ok = (d > 0) & (d < max_disp - 1) & (denom > 1e-12) & (jnp.maximum(cm, cp) < 0.5 * BIG)
    offset = jnp.clip((cp - cm) / (2.0 * jnp.where(ok, denom, 1.0)), -0.5, 0.5)
    return d.astype(jnp.float32) - jnp.where(ok, offset, 0.0)


def subpixel_volume(vol, disp: jax.Array) -> jax.Array:
    """:func:`subpixel` on a CostVolume: the parabola through the costs at d - 1, d, d + 1 when
    all three lie in the pixel's band (so not at a band's edge, nor at 0 or D - 1); elsewhere
    the integer disparity."""
    if not vol.banded:
        return subpixel(vol.cost, disp)
    k = vol.k
    d = jnp.clip(jnp.round(disp).astype(jnp.int32), 0, vol.max_disp - 1)
    j = d - vol.offset
    take = lambda i: jnp.take_along_axis(vol.cost, jnp.clip(i, 0, k - 1)[..., None], axis=-1)[..., 0]
    c0, cm, cp = take(j), take(j - 1), take(j + 1)
    denom = cp - 2.0 * c0 + cm
    ok = (j > 0) & (j < k - 1) & (denom > 1e-12) & (jnp.maximum(cm, cp) < 0.5 * BIG)
    offset = jnp.clip((cp - cm) / (2.0 * jnp.where(ok, denom, 1.0)), -0.5, 0.5)
    return d.astype(jnp.float32) - jnp.where(ok, offset, 0.0)
