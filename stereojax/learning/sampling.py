"""Patch-pair sampling for training the matching network (pure, jitted, ``jax.random``).

For a ground-truth pixel (x, y) with disparity d of a left image, one training triple is
the reference patch around (x, y) in the left image, a *positive* right patch around
(x - d + o_pos, y) with o_pos ~ U[-v_pos, v_pos], and a *negative* right patch around
(x - d + o_neg, y) with |o_neg| ~ U[z_low, z_high] and a random sign; so every batch is
balanced (one positive and one negative per reference). Sub-pixel positions are read by
linear interpolation along x. GT pixels whose patches could leave the image for some draw
of the offsets are dropped before sampling, so no patch ever leaves its image.

Images are normalised per image (zero mean, unit variance) before patches are cut.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from stereojax.data.images import as_grey
from stereojax.errors import ConfigError, StereoInputError


@dataclass(frozen=True)
class AugmentConfig:
    """Patch augmentation in the manner of MC-CNN (Zbontar & LeCun 2016): every training triple
    is warped by a random affine map and a brightness/contrast change shared by its three
    patches, and the two right patches (positive and negative) by a further small random
    difference, so that the network learns to match across the photometric and geometric
    differences between the two cameras. All zero (the default): off.

    rotate: degrees, U[-rotate, rotate]. scale: zoom s ~ U[1 - scale, 1]. hscale: extra
    horizontal zoom U[1 - hscale, 1]. hshear: horizontal shear U[-hshear, hshear].
    brightness: added U[-b, b] (the images are normalised to unit variance). contrast: factor
    exp(U[-ln c, ln c]) (1 = off). d_*: the same, drawn again for the right patches only.
    Patches are read with bilinear interpolation; samples that leave the image read its border.
    Validation patches are never augmented.
    """

    rotate: float = 0.0
    scale: float = 0.0
    hscale: float = 0.0
    hshear: float = 0.0
    brightness: float = 0.0
    contrast: float = 1.0
    d_rotate: float = 0.0
    d_hscale: float = 0.0
    d_hshear: float = 0.0
    d_brightness: float = 0.0
    d_contrast: float = 1.0

    @property
    def enabled(self) -> bool:
        return self != AugmentConfig()

    def validate(self) -> "AugmentConfig":
        if min(self.rotate, self.hshear, self.brightness, self.d_rotate, self.d_hshear, self.d_brightness) < 0:
            raise ConfigError("sampler.augment rotations, shears and brightness ranges must be >= 0")
        if not (0 <= self.scale < 1 and 0 <= self.hscale < 1 and 0 <= self.d_hscale < 1):
            raise ConfigError("sampler.augment scale, hscale and d_hscale must be in [0, 1)")
        if self.contrast < 1 or self.d_contrast < 1:
            raise ConfigError("sampler.augment contrast and d_contrast must be >= 1 (1 = off)")
        return self


#: the augmentation of ``stereojax train --augment`` (values of the order MC-CNN used on KITTI)
AUGMENT_MCCNN = AugmentConfig(rotate=7.0, scale=0.2, hscale=0.2, hshear=0.1, brightness=0.7,
                              contrast=1.3, d_hscale=0.1, d_hshear=0.1, d_brightness=0.3, d_contrast=1.1)


@dataclass(frozen=True)
class SamplerConfig:
    """Offsets of positives and negatives (pixels); defaults are the paper's. augment: see
    :class:`AugmentConfig` (off by default)."""

    v_pos: float = 4.0
    z_low: float = 4.0
    z_high: float = 18.0
    augment: AugmentConfig = field(default_factory=AugmentConfig)

    def validate(self) -> "SamplerConfig":
        if self.v_pos < 0:
            raise ConfigError(f"sampler.v_pos must be >= 0, got {self.v_pos}")
        if self.z_low < 0 or self.z_high <= self.z_low:
            raise ConfigError(f"sampler needs 0 <= z_low < z_high, got z_low={self.z_low}, z_high={self.z_high}")
        self.augment.validate()
        return self


def normalise(grey: np.ndarray) -> np.ndarray:
    """Zero mean, unit variance ``f32[H, W]`` (numpy)."""
    g = np.asarray(grey, np.float32)
    return ((g - g.mean()) / max(float(g.std()), 1e-6)).astype(np.float32)


class PatchData(NamedTuple):
    """Training images and their usable GT pixels, as device arrays (a pytree).

    left, right: ``f32[N, Hmax, Wmax]`` normalised grey images (zero padded to a common size).
    index: ``i32[M]`` image of each GT pixel; y, x: ``i32[M]``; d: ``f32[M]`` disparity.
    """

    left: jax.Array
    right: jax.Array
    index: jax.Array
    y: jax.Array
    x: jax.Array
    d: jax.Array

    @property
    def size(self) -> int:
        return int(self.index.shape[0])


def build_patch_data(samples: Sequence, patch_size: int, cfg: SamplerConfig) -> PatchData:
    """Collect the GT pixels of ``samples`` (StereoSample with gt) usable with ``cfg``'s offsets."""

    if not samples:
        raise StereoInputError("no training images given")
    r = patch_size // 2
    reach = max(cfg.v_pos, cfg.z_high) + 1.0       # + 1: the right neighbour of linear interpolation
    hmax = max(s.left.shape[0] for s in samples)
    wmax = max(s.left.shape[1] for s in samples)
    lefts, rights, cols = [], [], {k: [] for k in ("index", "y", "x", "d")}
    for i, s in enumerate(samples):
        if s.gt is None or s.gt_valid is None:
            raise StereoInputError(f"training image {s.name} has no ground truth")
        h, w = s.left.shape[:2]
        gl, gr = normalise(as_grey(s.left, "left")), normalise(as_grey(s.right, "right"))
        lefts.append(np.pad(gl, ((0, hmax - h), (0, wmax - w))))
        rights.append(np.pad(gr, ((0, hmax - h), (0, wmax - w))))
        ys, xs = np.nonzero(s.gt_valid)
        ds = s.gt[ys, xs].astype(np.float32)
        ok = ((ys >= r) & (ys < h - r) & (xs >= r) & (xs < w - r)
              & (xs - ds - reach >= r) & (xs - ds + reach <= w - 1 - r))
        cols["index"].append(np.full(ok.sum(), i, np.int32))
        cols["y"].append(ys[ok].astype(np.int32))
        cols["x"].append(xs[ok].astype(np.int32))
        cols["d"].append(ds[ok])
    data = {k: np.concatenate(v) for k, v in cols.items()}
    if data["index"].size == 0:
        sizes = ", ".join(f"{s.left.shape[1]}x{s.left.shape[0]}" for s in samples[:3])
        raise StereoInputError(f"no ground-truth pixel leaves room for a {patch_size}x{patch_size} patch and "
                               f"offsets up to {reach:g} px (images {sizes}{', ...' if len(samples) > 3 else ''}); "
                               "use larger images or smaller z_high / v_pos")
    return PatchData(left=jnp.asarray(np.stack(lefts)), right=jnp.asarray(np.stack(rights)),
                     index=jnp.asarray(data["index"]), y=jnp.asarray(data["y"]),
                     x=jnp.asarray(data["x"]), d=jnp.asarray(data["d"]))


def _cut(images, index, y, x, size):
    """Patches ``f32[B, size, size, 1]`` centred on (y, x) (x may be fractional: linear in x)."""
    r = size // 2
    off = jnp.arange(size) - r
    x0 = jnp.floor(x)
    frac = (x - x0)[:, None, None]
    x0 = x0.astype(jnp.int32)
    yy = (y[:, None] + off[None, :])[:, :, None]                 # [B, P, 1]
    xx = (x0[:, None] + off[None, :])[:, None, :]                # [B, 1, P]
    img = index[:, None, None]
    a = images[img, yy, xx]
    b = images[img, yy, xx + 1]
    return (a * (1.0 - frac) + b * frac)[..., None]


def _cut_warped(images, index, y, x, size, a, bright, gain):
    """Patches ``f32[B, size, size, 1]`` read at (x, y) + a @ (u, v) for the patch offsets
    (u, v) (``a``: ``f32[B, 2, 2]`` acting on (x, y)), bilinear, border-clamped, then
    ``gain * value + bright``."""
    r = size // 2
    off = (jnp.arange(size) - r).astype(jnp.float32)
    v, u = jnp.meshgrid(off, off, indexing="ij")                          # [P, P]: row, column offsets
    xs = x[:, None, None] + a[:, 0, 0, None, None] * u + a[:, 0, 1, None, None] * v
    ys = y[:, None, None] + a[:, 1, 0, None, None] * u + a[:, 1, 1, None, None] * v
    _, hh, ww = images.shape
    xs, ys = jnp.clip(xs, 0.0, ww - 1.0), jnp.clip(ys, 0.0, hh - 1.0)
    x0, y0 = jnp.floor(xs), jnp.floor(ys)
    fx, fy = xs - x0, ys - y0
    x0, y0 = x0.astype(jnp.int32), y0.astype(jnp.int32)
    x1, y1 = jnp.minimum(x0 + 1, ww - 1), jnp.minimum(y0 + 1, hh - 1)
    img = index[:, None, None]
    top = images[img, y0, x0] * (1 - fx) + images[img, y0, x1] * fx
    bottom = images[img, y1, x0] * (1 - fx) + images[img, y1, x1] * fx
    val = top * (1 - fy) + bottom * fy
    return (gain[:, None, None] * val + bright[:, None, None])[..., None]


def _affine(key, n: int, rotate: float, scale: float, hscale: float, hshear: float):
    """Random maps ``f32[n, 2, 2]``: rotation @ diag(zoom * hzoom, zoom) @ shear."""
    k = jax.random.split(key, 4)
    th = jnp.deg2rad(jax.random.uniform(k[0], (n,), minval=-rotate, maxval=rotate))
    s = jax.random.uniform(k[1], (n,), minval=1.0 - scale, maxval=1.0)
    hs = jax.random.uniform(k[2], (n,), minval=1.0 - hscale, maxval=1.0)
    sh = jax.random.uniform(k[3], (n,), minval=-hshear, maxval=hshear)
    c, si = jnp.cos(th), jnp.sin(th)
    rot = jnp.stack([jnp.stack([c, -si], -1), jnp.stack([si, c], -1)], -2)
    zoom_shear = jnp.stack([jnp.stack([s * hs, s * hs * sh], -1),
                            jnp.stack([jnp.zeros_like(s), s], -1)], -2)
    return rot @ zoom_shear


def _photometric(key, n: int, brightness: float, contrast: float):
    kb, kc = jax.random.split(key)
    lc = float(np.log(contrast))
    return (jax.random.uniform(kb, (n,), minval=-brightness, maxval=brightness),
            jnp.exp(jax.random.uniform(kc, (n,), minval=-lc, maxval=lc)))


def sample_batch(key, data: PatchData, batch: int, patch_size: int, cfg: SamplerConfig,
                 augment: bool = True):
    """One balanced batch: (ref, pos, neg) patches, each ``f32[batch, P, P, 1]``.

    Pure in ``key`` (same key, same batch); jit it with ``batch``, ``patch_size``, ``cfg`` and
    ``augment`` static. augment: apply ``cfg.augment`` (when enabled; validation passes False).
    """
    if augment and cfg.augment.enabled:
        return _sample_augmented(key, data, batch, patch_size, cfg)
    img, y, x, d, o_pos, o_neg = _draw(key, data, batch, cfg)
    xr = x.astype(jnp.float32) - d
    ref = _cut(data.left, img, y, x.astype(jnp.float32), patch_size)
    pos = _cut(data.right, img, y, xr + o_pos, patch_size)
    neg = _cut(data.right, img, y, xr + o_neg, patch_size)
    return ref, pos, neg


def _draw(key, data: PatchData, batch: int, cfg: SamplerConfig):
    """The random part of a batch: (image, y, x, d) of each reference pixel, the positive
    offset o_pos and the signed negative offset o_neg (the same split of ``key`` for every
    sampler, so a batch does not depend on which patches are cut from it)."""
    k_idx, k_pos, k_neg, k_sign = jax.random.split(key, 4)
    i = jax.random.randint(k_idx, (batch,), 0, data.index.shape[0])
    o_pos = jax.random.uniform(k_pos, (batch,), minval=-cfg.v_pos, maxval=cfg.v_pos)
    mag = jax.random.uniform(k_neg, (batch,), minval=cfg.z_low, maxval=cfg.z_high)
    sign = jnp.where(jax.random.bernoulli(k_sign, 0.5, (batch,)), 1.0, -1.0)
    return data.index[i], data.y[i], data.x[i], data.d[i], o_pos, sign * mag


def sample_distill_batch(key, data: PatchData, batch: int, patch_size: int, cfg: SamplerConfig,
                         soft_range: float):
    """:func:`sample_batch` (not augmented) plus a fourth right patch per reference, ``soft``,
    at x - d + o with o ~ U[-soft_range, soft_range]: the near-miss offsets among which a
    disparity search chooses, where a distilled network learns the teacher's scores (there is
    no label there). Returns (ref, pos, neg, soft), each ``f32[batch, P, P, 1]``; the first
    three equal :func:`sample_batch`'s for the same key."""
    ref, pos, neg = sample_batch(key, data, batch, patch_size, cfg, augment=False)
    img, y, x, d, _, _ = _draw(key, data, batch, cfg)
    o = jax.random.uniform(jax.random.fold_in(key, 2), (batch,), minval=-soft_range, maxval=soft_range)
    soft = _cut(data.right, img, y, x.astype(jnp.float32) - d + o, patch_size)
    return ref, pos, neg, soft


def _sample_augmented(key, data: PatchData, batch: int, patch_size: int, cfg: SamplerConfig):
    """:func:`sample_batch` with :class:`AugmentConfig`: the offsets are drawn as without it
    (same key split), then the patches are read through the random maps."""
    img, y, x, d, o_pos, o_neg = _draw(key, data, batch, cfg)
    k_a, k_p, k_da, k_dp = jax.random.split(jax.random.fold_in(key, 1), 4)
    a = cfg.augment
    common = _affine(k_a, batch, a.rotate, a.scale, a.hscale, a.hshear)
    bright, gain = _photometric(k_p, batch, a.brightness, a.contrast)
    right = common @ _affine(k_da, batch, a.d_rotate, 0.0, a.d_hscale, a.d_hshear)
    d_bright, d_gain = _photometric(k_dp, batch, a.d_brightness, a.d_contrast)
    yf, xf = y.astype(jnp.float32), x.astype(jnp.float32)
    xr = xf - d
    ref = _cut_warped(data.left, img, yf, xf, patch_size, common, bright, gain)
    rb, rg = bright + d_bright, gain * d_gain
    pos = _cut_warped(data.right, img, yf, xr + o_pos, patch_size, right, rb, rg)
    neg = _cut_warped(data.right, img, yf, xr + o_neg, patch_size, right, rb, rg)
    return ref, pos, neg
