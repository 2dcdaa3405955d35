"""The coarse pass that gives every pixel its disparity band (eSGM / tSGM style).

The pair is averaged down by ``band.scale`` (2: half resolution), matched over the full range
with census, one CBCA pass and SGM, and checked left against right. Each full-resolution pixel
then gets a band of ``K = band.width`` disparities:

1. lo, hi = the min and max coarse disparity (times the scale) within ``band.radius`` coarse
   pixels, or ``band.unsure_radius`` where the coarse left-right check fails (around depth
   edges and in occlusions the range widens);
2. lo -= margin, hi += margin + scale - 1;
3. when hi - lo + 1 <= K the band holds [lo, hi], its slack split on both sides; otherwise K
   disparities centred on the pixel's own coarse disparity;
4. clipped to [0, D - K].

The right view's bands follow the same rule from the coarse right disparities (its own
left-right agreement deciding "unsure"). Returns ``i32[H, W]`` offsets for both views.

The pass itself is the sub-chain :data:`stereojax.chain.COARSE` of the chain's own stages
(:func:`stereojax.chain.bands` runs it); this module holds its config and the band rule.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


def downsample(grey: jax.Array, scale: int) -> jax.Array:
    """Mean over ``scale x scale`` blocks of ``f32[H, W]`` (edge-padded to a multiple)."""
    if scale == 1:
        return grey
    h, w = grey.shape
    hp, wp = -(-h // scale) * scale, -(-w // scale) * scale
    g = jnp.pad(grey, ((0, hp - h), (0, wp - w)), mode="edge")
    return g.reshape(hp // scale, scale, wp // scale, scale).mean(axis=(1, 3))


def _window(values: jax.Array, radius: int, op) -> jax.Array:
    if radius == 0:
        return values
    init = jnp.array(-jnp.inf if op is jax.lax.max else jnp.inf, values.dtype)
    size = 2 * radius + 1
    # separable (the same min / max): a column window, then a row window, 2 (2r + 1) reads per
    # pixel instead of (2r + 1)^2
    cols = jax.lax.reduce_window(values, init, op, (size, 1), (1, 1), [(radius, radius), (0, 0)])
    return jax.lax.reduce_window(cols, init, op, (1, size), (1, 1), [(0, 0), (radius, radius)])


def band_offsets(disp: jax.Array, sure: jax.Array, band, max_disp: int, shape) -> jax.Array:
    """``i32[H, W]`` band offsets at full resolution ``shape`` from the coarse disparities
    ``disp`` ``i32[h, w]`` (in coarse pixels) and the coarse ``sure`` map (module docstring)."""
    s, k = band.scale, band.width
    d = disp.astype(jnp.float32)
    lo = jnp.where(sure, _window(d, band.radius, jax.lax.min), _window(d, band.unsure_radius, jax.lax.min))
    hi = jnp.where(sure, _window(d, band.radius, jax.lax.max), _window(d, band.unsure_radius, jax.lax.max))
    lo = lo.astype(jnp.int32) * s - band.margin
    hi = hi.astype(jnp.int32) * s + s - 1 + band.margin
    need = hi - lo + 1
    own = disp * s + s // 2 - k // 2
    off = jnp.where(need <= k, lo - (k - need) // 2, own)
    off = jnp.clip(off, 0, max_disp - k)
    h, w = shape
    return jnp.repeat(jnp.repeat(off, s, axis=0), s, axis=1)[:h, :w]


def coarse_config(config):
    """The coarse pass's chain (:data:`stereojax.chain.COARSE`, run at 1/``band.scale``): census
    with the chain's census window over the full range ``ceil(D / scale)``, the chain's cross arms
    (arm length divided by the scale, at least 1), one CBCA pass, SGM with ``band.p1/p2``, and
    both views' WTA."""
    b = config.band
    return dataclasses.replace(
        config, max_disp=-(-config.max_disp // b.scale),
        cost=dataclasses.replace(config.cost, method="census", border="replicate", candidates=0),
        cbca=dataclasses.replace(config.cbca, arm_length=max(1, config.cbca.arm_length // b.scale),
                                 iterations_before=1, iterations_after=0),
        sgm=dataclasses.replace(config.sgm, p1=b.p1, p2=b.p2),
        band=dataclasses.replace(b, width=0),
        refine=dataclasses.replace(config.refine, lr_check=True, right_from_left=True))


def sure(dl: jax.Array, dr: jax.Array):
    """(left sure, right sure) ``bool[h, w]``: where the coarse WTA disparities of the two views
    (``i32[h, w]``, in coarse pixels) agree within 1 and the match lies inside the other image."""
    w = dl.shape[1]
    x = jnp.arange(w)[None, :]
    dr_at_l = jnp.take_along_axis(dr, jnp.clip(x - dl, 0, w - 1), axis=1)
    dl_at_r = jnp.take_along_axis(dl, jnp.clip(x + dr, 0, w - 1), axis=1)
    return (jnp.abs(dl - dr_at_l) <= 1) & (x - dl >= 0), (jnp.abs(dr - dl_at_r) <= 1) & (x + dr < w)


def offsets_from(dl: jax.Array, dr: jax.Array, config, shape):
    """(left offsets, right offsets), each ``i32[H, W]`` at full resolution ``shape``: the band of
    every pixel of each view (module docstring) from the coarse pass's WTA disparities."""
    sure_l, sure_r = sure(dl, dr)
    return (band_offsets(dl, sure_l, config.band, config.max_disp, shape),
            band_offsets(dr, sure_r, config.band, config.max_disp, shape))
