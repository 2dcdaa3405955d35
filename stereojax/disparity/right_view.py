"""The right view's disparity from the left cost volume: C_R(x, d) = C_L(x + d, d).

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stereojax.disparity.winner_takes_all import wta
from stereojax.volume import BIG


def right_cost_from_left(cost: jax.Array, invalid: float = 1.0, valid_width=None) -> jax.Array:
    """Right-view volume from the left one: C_R[y, x, d] = C_L[y, x + d, d].

    Entries with x + d >= W (or >= ``valid_width``, the real width of a pair padded on the
    right) get ``invalid``. Returns ``f32[H, W, D]``.
    """
    h, w, max_disp = cost.shape
    # per-disparity [H, W] slices (padding a slice, not the volume, keeps memory at one volume
    # and lets XLA fuse the skew into a consumer such as argmin)
    cols = [jnp.pad(cost[:, d:, d], ((0, 0), (0, d)), constant_values=invalid) for d in range(max_disp)]
    vol = jnp.stack(cols, axis=-1)
    if valid_width is None:
        return vol
    inside = jnp.arange(w)[:, None] + jnp.arange(max_disp)[None, :] < valid_width      # [W, D]
    return jnp.where(inside[None], vol, invalid)


def right_wta(vol, right_offset, invalid: float = 1.0) -> jax.Array:
    """``i32[H, W]`` WTA disparity of the right view, from the left volume:
    C_R(x, d) = C_L(x + d, d), for d in the right view's band ``[right_offset, right_offset + K)``
    (full range: :func:`right_cost_from_left`). Entries with x + d beyond the real width get
    ``invalid``, as in the full range; entries where d lies outside the left pixel's band get
    :data:`~stereojax.volume.BIG`."""
    vw = None if vol.valid is None else vol.valid[1]
    if not vol.banded:
        return wta(right_cost_from_left(vol.cost, invalid, vw))
    h, w, k = vol.cost.shape
    width = w if vw is None else vw
    d = right_offset[..., None] + jnp.arange(k, dtype=jnp.int32)               # [H, W, K]
    xl = jnp.arange(w)[None, :, None] + d
    in_image = xl < width
    xl = jnp.clip(xl, 0, w - 1)
    off_l = jnp.take_along_axis(vol.offset, xl.reshape(h, -1), axis=1).reshape(h, w, k)
    j = d - off_l
    in_band = (j >= 0) & (j < k)
    flat = (xl * k + jnp.clip(j, 0, k - 1)).reshape(h, -1)
    c = jnp.take_along_axis(vol.cost.reshape(h, w * k), flat, axis=1).reshape(h, w, k)
    c = jnp.where(in_image, jnp.where(in_band, c, BIG), invalid)
    return wta(c) + right_offset
