"""Winner-takes-all disparity: the best disparity of each pixel, full range or in its band.

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).

:func:`wta_volume` has two kernels: ``jnp.argmin`` (the reference, and the path on every
platform other than the CPU) and the native C++ kernel beside it (``winner_takes_all.cc``, an
XLA FFI call), picked by its ``kernels`` setting (:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod


def wta(cost: jax.Array) -> jax.Array:
    """``i32[H, W]`` winner-takes-all disparity of ``f32[H, W, D]`` cost (first minimum wins)."""
    return jnp.argmin(cost, axis=-1).astype(jnp.int32)


def wta_volume_xla(vol) -> jax.Array:
    """The JAX kernel of :func:`wta_volume`."""
    return wta(vol.cost) + (vol.offset if vol.banded else 0)


def wta_volume_native(vol) -> jax.Array:
    """The native kernel (``winner_takes_all.cc``) of :func:`wta_volume_xla`."""
    h, w, _ = vol.cost.shape
    call = jax.ffi.ffi_call("stereojax_wta", jax.ShapeDtypeStruct((h, w), jnp.int32), vmap_method="sequential")
    return call(vol.cost.astype(jnp.float32), vol.offset.astype(jnp.int32), banded=np.int32(bool(vol.banded)),
                threads=np.int32(kernels_mod.threads()))


def wta_volume(vol, kernels: str = "auto") -> jax.Array:
    """``i32[H, W]`` winner-takes-all absolute disparity of a CostVolume (first minimum wins),
    with the kernel of the ``kernels`` setting."""
    return kernels_mod.select(kernels, wta_volume_native, wta_volume_xla, vol)
