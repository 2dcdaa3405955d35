"""Exact median filter of a disparity map.

:func:`median_filter` has two kernels: forgetful selection in JAX (the reference, and the path on
every platform other than the CPU) and the native C++ kernel beside it (``median.cc``, an XLA FFI
call), picked by its ``kernels`` setting (:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod

from stereojax.filters.neighbourhood import edge_windows


def median_filter_xla(disp: jax.Array, size: int = 5) -> jax.Array:
    """The JAX kernel of :func:`median_filter`. Exact median over a size x size window (edge replicated); ``f32[H, W]``.

    Uses forgetful selection (Paeth): keep n // 2 + 2 candidates, repeatedly drop their
    minimum and maximum and take in the next window value. Only element-wise min/max, so
    XLA fuses it into one pass (about 100x faster on CPU than sorting the windows).
    """
    if size <= 1:
        return disp
    values = list(edge_windows(disp.astype(jnp.float32), size // 2))
    keep = len(values) // 2 + 2
    buf, rest = values[:keep], values[keep:]
    while True:
        for i in range(1, len(buf)):              # minimum to the front
            buf[0], buf[i] = jnp.minimum(buf[0], buf[i]), jnp.maximum(buf[0], buf[i])
        for i in range(1, len(buf) - 1):          # maximum to the back
            buf[i], buf[-1] = jnp.minimum(buf[i], buf[-1]), jnp.maximum(buf[i], buf[-1])
        buf = buf[1:-1]
        if not rest:
            return buf[0]
        buf.append(rest.pop(0))


def median_filter_native(disp: jax.Array, size: int = 5) -> jax.Array:
    """The native kernel (``median.cc``) of :func:`median_filter_xla`."""
    call = jax.ffi.ffi_call("stereojax_median", jax.ShapeDtypeStruct(disp.shape, jnp.float32), vmap_method="sequential")
    return call(disp.astype(jnp.float32), size=np.int32(size), threads=np.int32(kernels_mod.threads()))


def median_filter(disp: jax.Array, size: int = 5, kernels: str = "auto") -> jax.Array:
    """Exact median over a size x size window (edge replicated); ``f32[H, W]``
    (:func:`median_filter_xla`), with the kernel of the ``kernels`` setting."""
    if size <= 1:
        return disp
    return kernels_mod.select(kernels, functools.partial(median_filter_native, size=size),
                              functools.partial(median_filter_xla, size=size), disp)
