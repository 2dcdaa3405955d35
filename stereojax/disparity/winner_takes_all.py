"""Winner-takes-all disparity: the best disparity of each pixel, full range or in its band.

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def wta(cost: jax.Array) -> jax.Array:
    """``i32[H, W]`` winner-takes-all disparity of ``f32[H, W, D]`` cost (first minimum wins)."""
    return jnp.argmin(cost, axis=-1).astype(jnp.int32)


def wta_volume(vol) -> jax.Array:
    """``i32[H, W]`` winner-takes-all absolute disparity of a CostVolume (first minimum wins)."""
    return wta(vol.cost) + (vol.offset if vol.banded else 0)
