"""Left-right consistency check: each left pixel labelled correct, mismatch or occlusion.

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# labels of the left-right check
CORRECT, MISMATCH, OCCLUSION = 0, 1, 2


def lr_check(disp_left: jax.Array, disp_right: jax.Array, max_disp: int,
             tolerance: float = 1.0) -> jax.Array:
    """Label every left pixel CORRECT, MISMATCH or OCCLUSION (MC-CNN's rule); ``i32[H, W]``.

    correct: |d - D_R(x - d)| <= tolerance. Otherwise mismatch if some disparity d' < max_disp
    has D_R(x - d') == d' (the pixel would be visible at another disparity), else occlusion.
    """
    h, w = disp_left.shape
    x = jnp.arange(w)[None, :]
    d = jnp.round(disp_left).astype(jnp.int32)
    xr = x - d
    dr = jnp.take_along_axis(disp_right, jnp.clip(xr, 0, w - 1), axis=1)
    correct = (xr >= 0) & (jnp.abs(disp_left - dr) <= tolerance)

    # "some d' has D_R(x - d') == d'" is "some right pixel x' = x - d' lands on x = x' + D_R(x')":
    # one scatter of the right pixels onto their left matches instead of a loop over the range
    r = jnp.round(disp_right).astype(jnp.int32)
    target = jnp.where((r >= 0) & (r < max_disp), x + r, w)                   # w: dropped
    rows = jnp.broadcast_to(jnp.arange(h)[:, None], (h, w))
    seen = jnp.zeros((h, w), jnp.bool_).at[rows, target].set(True, mode="drop")
    return jnp.where(correct, CORRECT, jnp.where(seen, MISMATCH, OCCLUSION)).astype(jnp.int32)
