"""Classical matching costs: census (Hamming distance) and SAD (paper Eq. 3.1).

Every cost volume is ``f32[H, W, D]`` with values in [0, 1], lower is better, for
disparities d = 0 .. D-1. The left-view volume compares left (y, x) with right
(y, x - d); the right-view volume compares right (y, x) with left (y, x + d).
Entries whose match leaves the image (x - d < 0) are handled by ``border``:
"replicate" compares with the right image's first column repeated (the left-padding trick
of the KITTI SGBM baseline, so that SGM can carry disparities into the left band), "worst"
gives them the finite sentinel ``INVALID_COST``. :func:`valid_mask` tells which they are.

The census cost has two kernels after the census transform: the JAX kernel (the reference, and
the path on every platform other than the CPU) and the native C++ kernel beside it
(``census.cc``, an XLA FFI call); :func:`census_cost` and :func:`census_band` pick one by their
``kernels`` setting (:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod
from stereojax.volume import CostVolume, band_from_full, windows

INVALID_COST = 1.0


def valid_mask(width: int, max_disp: int, view: str = "left") -> jax.Array:
    """``bool[W, D]``: True where the match of (x, d) lies inside the other image."""
    x = jnp.arange(width)[:, None]
    d = jnp.arange(max_disp)[None, :]
    return (x - d >= 0) if view == "left" else (x + d < width)


def _shifted_slices(other: jax.Array, max_disp: int, view: str) -> list[jax.Array]:
    """The other image at the matching column of every x, one slice per disparity d.

    For view "left": slice d is other[:, x - d]; for "right": other[:, x + d]. Columns outside
    the image repeat the border. Each slice is shaped like ``other``.
    """
    w = other.shape[1]
    pad = [(0, 0)] * other.ndim
    if view == "left":
        pad[1] = (max_disp, 0)
        padded = jnp.pad(other, pad, mode="edge")
        return [padded[:, max_disp - d: max_disp - d + w] for d in range(max_disp)]
    pad[1] = (0, max_disp)
    padded = jnp.pad(other, pad, mode="edge")
    return [padded[:, d: d + w] for d in range(max_disp)]


# ---- census --------------------------------------------------------------------------------

def census_transform(grey: jax.Array, radius: tuple[int, int]) -> jax.Array:
    """``u32[H, W, K]`` census bit strings (neighbour < centre), K = ceil(bits / 32) words.

    The window is (2 ry + 1) x (2 rx + 1) minus the centre; borders replicate the edge.
    """
    ry, rx = radius
    h, w = grey.shape
    padded = jnp.pad(grey, ((ry, ry), (rx, rx)), mode="edge")
    offsets = [(dy, dx) for dy in range(-ry, ry + 1) for dx in range(-rx, rx + 1) if (dy, dx) != (0, 0)]
    n_words = (len(offsets) + 31) // 32
    words = []
    for k in range(n_words):
        word = jnp.zeros((h, w), jnp.uint32)
        for bit, (dy, dx) in enumerate(offsets[32 * k: 32 * (k + 1)]):
            neighbour = padded[ry + dy: ry + dy + h, rx + dx: rx + dx + w]
            word = word | ((neighbour < grey).astype(jnp.uint32) << bit)
        words.append(word)
    return jnp.stack(words, axis=-1)


def census_bits(radius: tuple[int, int]) -> int:
    ry, rx = radius
    return (2 * ry + 1) * (2 * rx + 1) - 1


#: "neutral" border: the out-of-view cost of a pixel is its best in-view cost plus this share of
#: the gap to its mean in-view cost. Chosen on training frames only (KITTI 2015 000001 with
#: all-pixel GT and the Middlebury scenes Cones, Teddy, Reindeer, Venus, Tsukuba with the shipped
#: models' chains): shares 0, 0.25, 0.5, 0.75 gave a mean > 3 px of 6.18, 3.65, 3.44, 3.53 %,
#: replicate 3.77 % (experiments/results/border.md).
NEUTRAL_SHARE = 0.5


def _in_strip(fn, cost: jax.Array, max_disp: int) -> jax.Array:
    """``fn`` applied to the columns x < D - 1 of a left-view volume only: from x = D - 1 on,
    every match x - d (d <= D - 1) lies inside the right image, so the rest is unchanged."""
    strip = min(cost.shape[1], max(max_disp - 1, 0))
    if strip == 0:
        return cost
    return jnp.concatenate([fn(cost[:, :strip]), cost[:, strip:]], axis=1)


def neutral_border(cost: jax.Array, share: float = NEUTRAL_SHARE) -> jax.Array:
    """The left-view volume ``f32[H, W, D]`` with every entry whose match leaves the right image
    (x - d < 0) set to ``min + share * (mean - min)`` of that pixel's in-view costs: neither a
    good nor a bad match, so that the disparity of the border strip comes from the paths that
    enter it from the image (SGM) rather than from a comparison with padding. Only the strip
    x < D - 1 is read and written."""
    def strip(c):
        inside = valid_mask(c.shape[1], c.shape[2], "left")[None]
        count = jnp.maximum(inside.sum(-1, keepdims=True), 1)
        mean = jnp.where(inside, c, 0.0).sum(-1, keepdims=True) / count
        best = jnp.where(inside, c, jnp.inf).min(-1, keepdims=True)
        return jnp.where(inside, c, best + share * (mean - best))

    return _in_strip(strip, cost, cost.shape[2])


def _apply_border(cost, max_disp, view, border):
    if border in ("replicate", "neutral"):      # neutral: applied to the chain's volume (pipeline)
        return cost
    return jnp.where(valid_mask(cost.shape[1], max_disp, view)[None], cost, INVALID_COST)


def census_cost_xla(left: jax.Array, right: jax.Array, max_disp: int, radius=(3, 4), view: str = "left",
                    border: str = "replicate"):
    """The JAX kernel of :func:`census_cost`. Census cost volume ``f32[H, W, D]`` in [0, 1] (fraction of differing bits) for one view.

    left, right: ``f32[H, W]`` grey images. Returns the volume with invalid entries set to
    ``INVALID_COST``.
    """
    cl = census_transform(left, radius)
    cr = census_transform(right, radius)
    ref, other = (cl, cr) if view == "left" else (cr, cl)
    scale = 1.0 / census_bits(radius)

    def hamming(shifted):                                               # u32[H, W, K] -> f32[H, W]
        return jax.lax.population_count(ref ^ shifted).astype(jnp.float32).sum(-1) * scale

    # one fused [H, W] computation per disparity, written straight into the volume (building
    # the shifted u32[H, W, D, K] stack first would cost twice the volume's memory)
    cost = jnp.stack([hamming(s) for s in _shifted_slices(other, max_disp, view)], axis=-1)
    return _apply_border(cost, max_disp, view, border)


def census_native(cl: jax.Array, cr: jax.Array, offset: jax.Array, k: int, radius, border: str) -> jax.Array:
    """The native kernel (``census.cc``): the left view's census cost ``f32[H, W, K]`` of the
    census words ``u32[H, W, words]`` of both images in the bands ``[offset, offset + k)`` (the
    full range: offset 0, k = D)."""
    h, w = offset.shape
    call = jax.ffi.ffi_call("stereojax_census", jax.ShapeDtypeStruct((h, w, k), jnp.float32),
                            vmap_method="sequential")
    return call(cl, cr, offset.astype(jnp.int32), worst=np.int32(border == "worst"),
                scale=np.float32(1.0 / census_bits(radius)), threads=np.int32(kernels_mod.threads()))


def _census_cost_native(left, right, max_disp, radius, view, border):
    cl, cr = census_transform(left, radius), census_transform(right, radius)
    zeros = jnp.zeros(left.shape, jnp.int32)
    if view == "left":
        return census_native(cl, cr, zeros, max_disp, radius, border)
    # the right view is the left view of the mirrored pair (Hamming distances do not depend on
    # the order of the bits, and the mirrored border repeats column W - 1 as the JAX kernel does)
    return census_native(cr[:, ::-1], cl[:, ::-1], zeros, max_disp, radius, border)[:, ::-1]


def census_cost(left: jax.Array, right: jax.Array, max_disp: int, radius=(3, 4), view: str = "left",
                border: str = "replicate", kernels: str = "auto"):
    """Census cost volume ``f32[H, W, D]`` in [0, 1] (fraction of differing bits) for one view
    (:func:`census_cost_xla`), with the kernel of the ``kernels`` setting."""
    native = functools.partial(_census_cost_native, max_disp=max_disp, radius=radius, view=view, border=border)
    xla = functools.partial(census_cost_xla, max_disp=max_disp, radius=radius, view=view, border=border)
    return kernels_mod.select(kernels, native, xla, left, right)


def census_band(left: jax.Array, right: jax.Array, offset: jax.Array, k: int, max_disp: int,
                radius=(3, 4), border: str = "replicate", valid=None, kernels: str = "auto"):
    """Census cost of the left view at each pixel's band ``[offset, offset + k)`` (see
    :func:`census_band_xla`), with the kernel of the ``kernels`` setting."""
    def native(l, r, off):
        cost = census_native(census_transform(l, radius), census_transform(r, radius), off, k, radius, border)
        return CostVolume.band(cost, off, max_disp, valid)

    xla = functools.partial(census_band_xla, k=k, max_disp=max_disp, radius=radius, border=border, valid=valid)
    return kernels_mod.select(kernels, native, xla, left, right, offset)


# ---- SAD ------------------------------------------------------------------------------------

def box_mean(volume: jax.Array, radius: int) -> jax.Array:
    """Mean over a (2r+1) x (2r+1) window on the first two axes (edge-replicated), any trailing axes."""
    if radius == 0:
        return volume
    pad = [(radius, radius), (radius, radius)] + [(0, 0)] * (volume.ndim - 2)
    v = jnp.pad(volume, pad, mode="edge")
    s = jnp.cumsum(jnp.cumsum(v, axis=0), axis=1)
    s = jnp.pad(s, [(1, 0), (1, 0)] + [(0, 0)] * (volume.ndim - 2))
    k = 2 * radius + 1
    h, w = volume.shape[:2]
    total = s[k:k + h, k:k + w] - s[:h, k:k + w] - s[k:k + h, :w] + s[:h, :w]
    return total / (k * k)


def sad_cost(left: jax.Array, right: jax.Array, max_disp: int, radius: int = 2, view: str = "left",
             border: str = "replicate"):
    """SAD cost volume ``f32[H, W, D]`` (paper Eq. 3.1): window mean of |I_L - I_R| / 255."""
    ref, other = (left, right) if view == "left" else (right, left)
    # box mean of each disparity's [H, W] absolute difference (integral image per slice)
    slices = [box_mean(jnp.abs(ref - s) / 255.0, radius) for s in _shifted_slices(other, max_disp, view)]
    return _apply_border(jnp.stack(slices, axis=-1), max_disp, view, border)


def matching_cost(left: jax.Array, right: jax.Array, max_disp: int, cfg, view: str = "left",
                  kernels: str = "auto") -> jax.Array:
    """Dispatch on ``cfg.method`` (a :class:`stereojax.config.CostConfig`)."""
    if cfg.method == "census":
        return census_cost(left, right, max_disp, cfg.census_radius, view, cfg.border, kernels)
    if cfg.method == "sad":
        return sad_cost(left, right, max_disp, cfg.sad_radius, view, cfg.border)
    raise ValueError(f"unknown cost method {cfg.method!r}")


# ---- per-pixel disparity bands (stereojax.volume.CostVolume) ---------------------------------

def census_band_xla(left: jax.Array, right: jax.Array, offset: jax.Array, k: int, max_disp: int,
                    radius=(3, 4), border: str = "replicate", valid=None):
    """The JAX kernel of :func:`census_band`. Census cost of the left view at each pixel's band ``[offset, offset + k)``: a
    :class:`~stereojax.volume.CostVolume` whose entries equal those of :func:`census_cost`
    there (right columns left of the image repeat column 0; ``border="worst"``: INVALID_COST)."""

    cl = census_transform(left, radius)
    cr = census_transform(right, radius)
    h, w = left.shape
    scale = 1.0 / census_bits(radius)
    # the right columns x - offset - K + 1 .. x - offset of every pixel are one contiguous window
    # (read reversed): a slice gather, 3x faster on the CPU than gathering each column
    col = jnp.arange(w, dtype=jnp.int32)[None, :, None] - (offset[..., None] + jnp.arange(k, dtype=jnp.int32))
    pad = max_disp + k
    crp = jnp.pad(cr, ((0, 0), (pad, 0), (0, 0)), mode="edge")            # column u at u + pad
    first = jnp.clip(jnp.arange(w)[None, :] - offset - (k - 1) + pad, 0, w + pad - k)
    # every pixel of a row reads its window from that row: broadcast the row over the pixels
    words = jax.vmap(lambda row, st: windows(jnp.broadcast_to(row, (w,) + row.shape), st, k))(crp, first)
    words = words[:, :, ::-1]                                                 # [H, W, K, words]
    bits = jax.lax.population_count(cl[:, :, None, :] ^ words).astype(jnp.float32).sum(-1)
    c = bits * scale
    if border == "worst":
        c = jnp.where(col >= 0, c, INVALID_COST)
    return CostVolume.band(c, offset, max_disp, valid)


def band_cost(left: jax.Array, right: jax.Array, offset: jax.Array, k: int, max_disp: int, cfg,
              valid=None, kernels: str = "auto"):
    """The classical cost of ``cfg`` (a CostConfig) in the bands: census directly
    (:func:`census_band`); SAD from its full volume (its window would need every pixel's own
    disparities), then cut to the bands."""
    if cfg.method == "census":
        return census_band(left, right, offset, k, max_disp, cfg.census_radius, cfg.border, valid, kernels)

    return band_from_full(matching_cost(left, right, max_disp, cfg, "left", kernels), offset, k, valid)


def neutral_border_volume(vol, share: float = NEUTRAL_SHARE):
    """:func:`neutral_border` of a CostVolume: entries whose match leaves the right image
    (x - d < 0) get ``min + share * (mean - min)`` of the pixel's in-view entries of its band;
    a pixel whose whole band is out of view keeps its costs."""
    if not vol.banded:
        return vol.with_cost(neutral_border(vol.cost, share))
    strip = min(vol.shape[1], max(vol.max_disp - 1, 0))
    off = vol.offset[:, :strip]

    def in_strip(c):
        inside = jnp.arange(c.shape[1])[None, :, None] - (off[..., None] + jnp.arange(vol.k)) >= 0
        count = inside.sum(-1, keepdims=True)
        mean = jnp.where(inside, c, 0.0).sum(-1, keepdims=True) / jnp.maximum(count, 1)
        best = jnp.where(inside, c, jnp.inf).min(-1, keepdims=True)
        neutral = jnp.where(count > 0, best + share * (mean - best), c)
        return jnp.where(inside, c, neutral)

    return vol.with_cost(_in_strip(in_strip, vol.cost, vol.max_disp))
