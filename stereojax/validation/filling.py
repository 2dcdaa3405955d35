"""Filling the pixels the left-right check rejected (MC-CNN's interpolation).

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).

:func:`fill_disparity` has two kernels: the JAX kernel (the reference, and the path on every
platform other than the CPU) and the native C++ kernel beside it (``filling.cc``, an XLA FFI
call), picked by its ``kernels`` setting (:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod

from stereojax.validation.left_right import CORRECT, MISMATCH, OCCLUSION
from stereojax.volume import BIG


def _propagate(values: jax.Array, valid: jax.Array, axis: int, reverse: bool):
    """Nearest valid value along ``axis`` seen so far (scan order), and whether one exists."""
    def body(carry, xs):
        last, have = carry
        v, ok = xs
        last = jnp.where(ok, v, last)
        have = have | ok
        return (last, have), (last, have)

    v = jnp.moveaxis(values, axis, 0)
    ok = jnp.moveaxis(valid, axis, 0)
    init = (jnp.zeros_like(v[0]), jnp.zeros_like(ok[0]))
    _, (last, have) = jax.lax.scan(body, init, (v, ok), reverse=reverse)
    return jnp.moveaxis(last, 0, axis), jnp.moveaxis(have, 0, axis)


def _propagate_diagonal(values, valid, dy: int, dx: int):
    """Nearest valid value met walking from p in direction (-dy, -dx) (scan along y, shifting x)."""
    def shift(a, fill):
        if dx == 1:
            return jnp.concatenate([jnp.full_like(a[:1], fill), a[:-1]], axis=0)
        return jnp.concatenate([a[1:], jnp.full_like(a[:1], fill)], axis=0)

    def body(carry, xs):
        last, have = carry
        last, have = shift(last, 0), shift(have, False)
        v, ok = xs
        last = jnp.where(ok, v, last)
        have = have | ok
        return (last, have), (last, have)

    init = (jnp.zeros_like(values[0]), jnp.zeros_like(valid[0]))
    _, (last, have) = jax.lax.scan(body, init, (values, valid), reverse=(dy == -1))
    return last, have


#: Batcher's odd-even merge sort of 8 values: 19 compare-exchanges (tests/validation/test_filling.py checks
#: it on every 0/1 input, which proves it sorts everything)
SORT8 = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (1, 2), (5, 6),
         (0, 4), (1, 5), (2, 6), (3, 7), (2, 4), (3, 5), (1, 2), (3, 4), (5, 6))


def sort8(values: list) -> list:
    """8 arrays of one shape sorted elementwise (ascending) by :data:`SORT8`: elementwise min and
    max, about 8x faster on the CPU than ``jnp.sort`` over a stacked axis of 8."""
    v = list(values)
    for i, j in SORT8:
        v[i], v[j] = jnp.minimum(v[i], v[j]), jnp.maximum(v[i], v[j])
    return v


def fill_disparity_xla(disp: jax.Array, labels: jax.Array) -> jax.Array:
    """The JAX kernel of :func:`fill_disparity`. Fill non-CORRECT pixels of ``f32[H, W]`` disparity (MC-CNN's interpolation).

    Occluded pixels take the nearest correct disparity to their left (the background; to
    their right where the row has none on the left). Mismatched pixels take the median of the
    nearest correct disparities found along 8 directions. Pixels with no correct pixel in any
    direction keep their value.
    """
    disp = disp.astype(jnp.float32)
    good = labels == CORRECT
    left_v, left_ok = _propagate(disp, good, axis=1, reverse=False)
    right_v, right_ok = _propagate(disp, good, axis=1, reverse=True)
    up_v, up_ok = _propagate(disp, good, axis=0, reverse=False)
    down_v, down_ok = _propagate(disp, good, axis=0, reverse=True)
    diag = [_propagate_diagonal(disp, good, dy, dx) for dy, dx in ((1, 1), (1, -1), (-1, 1), (-1, -1))]

    occl_fill = jnp.where(left_ok, left_v, jnp.where(right_ok, right_v, disp))

    cands = jnp.stack([left_v, right_v, up_v, down_v] + [v for v, _ in diag])
    oks = jnp.stack([left_ok, right_ok, up_ok, down_ok] + [o for _, o in diag])
    # median over the available candidates: sort with missing ones pushed to +inf
    srt = jnp.stack(sort8(list(jnp.where(oks, cands, jnp.float32(BIG)))))
    n = oks.sum(0)
    lo = jnp.take_along_axis(srt, jnp.clip((n - 1) // 2, 0, 7)[None], axis=0)[0]
    hi = jnp.take_along_axis(srt, jnp.clip(n // 2, 0, 7)[None], axis=0)[0]
    mism_fill = jnp.where(n > 0, 0.5 * (lo + hi), disp)

    return jnp.where(labels == OCCLUSION, occl_fill, jnp.where(labels == MISMATCH, mism_fill, disp))


def fill_disparity_native(disp: jax.Array, labels: jax.Array) -> jax.Array:
    """The native kernel (``filling.cc``) of :func:`fill_disparity_xla`."""
    call = jax.ffi.ffi_call("stereojax_fill", jax.ShapeDtypeStruct(disp.shape, jnp.float32), vmap_method="sequential")
    return call(disp.astype(jnp.float32), labels.astype(jnp.int32), threads=np.int32(kernels_mod.threads()))


def fill_disparity(disp: jax.Array, labels: jax.Array, kernels: str = "auto") -> jax.Array:
    """Fill non-CORRECT pixels of ``f32[H, W]`` disparity (MC-CNN's interpolation; see
    :func:`fill_disparity_xla`), with the kernel of the ``kernels`` setting."""
    return kernels_mod.select(kernels, fill_disparity_native, fill_disparity_xla, disp, labels)
