"""The right view's disparity from the left cost volume: C_R(x, d) = C_L(x + d, d).

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).

:func:`right_wta` has two kernels: the JAX kernel (the reference, and the path on every
platform other than the CPU) and the native C++ kernel beside it (``right_view.cc``, an XLA FFI
call), picked by its ``kernels`` setting (:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod
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


def right_wta_xla(vol, right_offset, invalid: float = 1.0) -> jax.Array:
    """The JAX kernel of :func:`right_wta`. ``i32[H, W]`` WTA disparity of the right view, from the left volume:
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


def right_wta_native(vol, right_offset, invalid: float = 1.0) -> jax.Array:
    """The native kernel (``right_view.cc``) of :func:`right_wta_xla`."""
    h, w, _ = vol.cost.shape
    width = jnp.full((1,), w, jnp.int32) if vol.valid is None else vol.valid[1:2].astype(jnp.int32)
    roff = right_offset if vol.banded else jnp.zeros((h, w), jnp.int32)
    call = jax.ffi.ffi_call("stereojax_right_wta", jax.ShapeDtypeStruct((h, w), jnp.int32), vmap_method="sequential")
    return call(vol.cost.astype(jnp.float32), vol.offset.astype(jnp.int32), roff.astype(jnp.int32), width,
                banded=np.int32(bool(vol.banded)), invalid=np.float32(invalid),
                threads=np.int32(kernels_mod.threads()))


def right_wta(vol, right_offset, invalid: float = 1.0, kernels: str = "auto") -> jax.Array:
    """``i32[H, W]`` WTA disparity of the right view from the left volume (see
    :func:`right_wta_xla`), with the kernel of the ``kernels`` setting."""
    return kernels_mod.select(kernels, functools.partial(right_wta_native, invalid=invalid),
                              functools.partial(right_wta_xla, invalid=invalid), vol, right_offset)
