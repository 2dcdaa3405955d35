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

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .errors import ConfigError, StereoInputError


@dataclass(frozen=True)
class SamplerConfig:
    """Offsets of positives and negatives (pixels); defaults are the paper's."""

    v_pos: float = 4.0
    z_low: float = 4.0
    z_high: float = 18.0

    def validate(self) -> "SamplerConfig":
        if self.v_pos < 0:
            raise ConfigError(f"sampler.v_pos must be >= 0, got {self.v_pos}")
        if self.z_low < 0 or self.z_high <= self.z_low:
            raise ConfigError(f"sampler needs 0 <= z_low < z_high, got z_low={self.z_low}, z_high={self.z_high}")
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
    from .pipeline import _as_grey

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
        gl, gr = normalise(_as_grey(s.left, "left")), normalise(_as_grey(s.right, "right"))
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


def sample_batch(key, data: PatchData, batch: int, patch_size: int, cfg: SamplerConfig):
    """One balanced batch: (ref, pos, neg) patches, each ``f32[batch, P, P, 1]``.

    Pure in ``key`` (same key, same batch); jit it with ``batch``, ``patch_size`` and ``cfg``
    static.
    """
    k_idx, k_pos, k_neg, k_sign = jax.random.split(key, 4)
    i = jax.random.randint(k_idx, (batch,), 0, data.index.shape[0])
    img, y, x, d = data.index[i], data.y[i], data.x[i], data.d[i]
    o_pos = jax.random.uniform(k_pos, (batch,), minval=-cfg.v_pos, maxval=cfg.v_pos)
    mag = jax.random.uniform(k_neg, (batch,), minval=cfg.z_low, maxval=cfg.z_high)
    sign = jnp.where(jax.random.bernoulli(k_sign, 0.5, (batch,)), 1.0, -1.0)
    xr = x.astype(jnp.float32) - d
    ref = _cut(data.left, img, y, x.astype(jnp.float32), patch_size)
    pos = _cut(data.right, img, y, xr + o_pos, patch_size)
    neg = _cut(data.right, img, y, xr + sign * mag, patch_size)
    return ref, pos, neg
