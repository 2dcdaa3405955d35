"""Joint bilateral filter of a disparity map guided by the grey left image."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stereojax.filters.neighbourhood import edge_windows


def bilateral_filter(disp: jax.Array, guide: jax.Array, radius: int, sigma_space: float,
                     sigma_range: float) -> jax.Array:
    """Joint bilateral filter of disparity ``f32[H, W]`` guided by grey image ``f32[H, W]``.

    Weight of neighbour q for p: exp(-|p - q|^2 / 2 s_s^2) * exp(-(I(p) - I(q))^2 / 2 s_r^2).
    """
    if radius == 0:
        return disp
    k = 2 * radius + 1
    dy, dx = jnp.meshgrid(jnp.arange(k) - radius, jnp.arange(k) - radius, indexing="ij")
    spatial = jnp.exp(-(dy ** 2 + dx ** 2) / (2.0 * sigma_space ** 2)).reshape(-1, 1, 1)
    g = edge_windows(guide.astype(jnp.float32), radius)
    wgt = spatial * jnp.exp(-((g - guide[None]) ** 2) / (2.0 * sigma_range ** 2))
    disp = disp.astype(jnp.float32)
    # written as a correction of the centre value, so that constant regions stay exact
    d = edge_windows(disp, radius) - disp[None]
    return disp + (wgt * d).sum(0) / wgt.sum(0)
