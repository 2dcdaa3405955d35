"""Dense distillation on the band chain (issue "`best` in two seconds"): a student learns the
teacher's matching cost at *every* disparity of a pixel's band, the disparities the chain
actually uses, instead of at a few patches near the true match.

Targets (:func:`teacher_targets`): on a frame, the band chain's coarse pass gives every pixel
its band of K disparities (:func:`stereojax.chain.bands`); at a sample of pixels, the teacher's
similarity is computed at all K (``s = 1 - cost``, :func:`stereojax.matching_cost.learned.head_at_pixels`).
Pixels are drawn with more weight at depth edges (a step of the coarse band offsets) and on weak
texture (low local contrast), where students and teacher disagree most. No ground truth is
needed, so the unlabeled pairs serve as well as the labelled frames.

Targets are cached on disk, one ``.npz`` per frame written atomically (:func:`cache_targets`): a
killed run keeps every finished frame and computes only the rest.

Training (:func:`dense_loss`, used by :func:`stereojax.learning.train.train_step` when
``TrainConfig.dense > 0``): for a batch of target pixels, the student's tower runs on the 9x9
left patch and on the right strip ``9 x (K + 8)`` that covers the band (valid convolutions: one
feature vector per band disparity), its head scores each disparity, and the loss is the
cross-entropy to the teacher's similarity, averaged over the band entries whose match lies in
the right image.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from stereojax.chain import bands
from stereojax.data.io import atomic_output
from stereojax.learning.losses import bce
from stereojax.learning.sampling import normalise
from stereojax.matching_cost.learned import head_at_pixels, tower_features
from stereojax.models.nets import MatchNet

#: target file format version (in each .npz)
FORMAT = 1
#: extra sampling weight of a depth-edge pixel and of a weak-texture pixel (a plain pixel: 1)
EDGE_WEIGHT = 4.0
FLAT_WEIGHT = 2.0
#: weak texture: local standard deviation (5x5, grey 0..255) below this
FLAT_STD = 4.0


class DenseTargets(NamedTuple):
    """Cached targets of many frames as device arrays (a pytree).

    left, right: ``f32[N, Hmax, Wmax]`` normalised grey images (zero padded); index, y, x:
    ``i32[M]`` the target pixels; offset ``i32[M]`` the first disparity of each pixel's band;
    target ``f32[M, K]`` the teacher's similarity at disparity offset + k."""

    left: jax.Array
    right: jax.Array
    index: jax.Array
    y: jax.Array
    x: jax.Array
    offset: jax.Array
    target: jax.Array

    @property
    def size(self) -> int:
        return int(self.index.shape[0])

    @property
    def width(self) -> int:
        return int(self.target.shape[1])


def sample_weights(grey: np.ndarray, offset: np.ndarray, margin: int) -> np.ndarray:
    """``f32[H, W]`` sampling weights: 1, plus EDGE_WEIGHT where the coarse band offset steps by
    more than 2 px to a neighbour (a depth edge), plus FLAT_WEIGHT where the 5x5 standard
    deviation is below FLAT_STD (weak texture); 0 within ``margin`` of the border."""

    g = np.asarray(grey, np.float32)
    off = np.asarray(offset, np.float32)
    step = np.zeros_like(off)
    step[:, 1:] = np.maximum(step[:, 1:], np.abs(np.diff(off, axis=1)))
    step[1:, :] = np.maximum(step[1:, :], np.abs(np.diff(off, axis=0)))
    edge = cv2.dilate((step > 2).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    mean = cv2.blur(g, (5, 5))
    std = np.sqrt(np.maximum(cv2.blur(g * g, (5, 5)) - mean * mean, 0.0))
    w = 1.0 + EDGE_WEIGHT * edge + FLAT_WEIGHT * (std < FLAT_STD)
    w[:margin], w[-margin:], w[:, :margin], w[:, -margin:] = 0, 0, 0, 0
    return w.astype(np.float32)


@functools.partial(jax.jit, static_argnames=("config",))
def _band_offsets(left, right, config):

    return bands(left, right, config)[0]


@functools.partial(jax.jit, static_argnames=("net",))
def _similarities(net, variables, left, right, ys, xs, cand):

    fl, fr = tower_features(net, variables, left, right)
    return 1.0 - head_at_pixels(MatchNet(net), variables, fl, fr, ys, xs, cand)


def teacher_targets(teacher, config, left, right, n_pixels: int, seed: int = 0) -> dict:
    """The teacher's band similarities at ``n_pixels`` pixels of one grey pair ``f32[H, W]``:
    ``{"y", "x", "offset", "target"}`` (``target`` ``f16[n, K]``; entries whose match leaves the
    right image are NaN). ``config``: the banded learned chain the teacher runs with."""
    left = jnp.asarray(left, jnp.float32)
    right = jnp.asarray(right, jnp.float32)
    off_l = np.asarray(_band_offsets(left, right, config))
    k = config.band.width
    r = teacher.net.layers
    w = sample_weights(np.asarray(left), off_l, r + 1)
    rng = np.random.default_rng(seed)
    p = w.ravel() / w.sum()
    picked = rng.choice(w.size, size=min(n_pixels, int((w > 0).sum())), replace=False, p=p)
    ys, xs = np.unravel_index(np.sort(picked), w.shape)
    offs = off_l[ys, xs]
    cand = offs[:, None] + np.arange(k)[None, :]
    s = np.asarray(_similarities(teacher.net, teacher.variables, left, right, jnp.asarray(ys, jnp.int32),
                                 jnp.asarray(xs, jnp.int32), jnp.asarray(cand, jnp.int32)))
    s = np.where(xs[:, None] - cand >= r, s, np.nan)     # the match (with its patch) must lie in the image
    return {"y": ys.astype(np.int16), "x": xs.astype(np.int16), "offset": offs.astype(np.int16),
            "target": s.astype(np.float16)}


def cache_targets(frames, teacher, config, out_dir, n_pixels: int, progress: bool = True) -> list[Path]:
    """:func:`teacher_targets` of every ``(name, load)`` frame (``load() -> (left, right)`` grey
    images), each written to ``out_dir/<name>.npz`` atomically; a frame whose file is there and
    was made with the same teacher, chain and pixel count is kept (a killed run resumes).
    Returns the files in frame order."""


    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    key = json.dumps({"format": FORMAT, "config": config.to_dict(), "n_pixels": int(n_pixels),
                      "teacher": str(getattr(teacher, "source", ""))}, sort_keys=True, default=str)
    files = []
    for i, (name, load) in enumerate(tqdm(list(frames), desc="teacher targets", unit="frame", disable=not progress)):
        path = out / f"{name}.npz"
        files.append(path)
        if path.is_file():
            try:
                with np.load(path) as z:
                    if str(z["key"]) == key:
                        continue
            except (OSError, ValueError, KeyError):
                pass
        left, right = load()
        t = teacher_targets(teacher, config, left, right, n_pixels, seed=i)
        with atomic_output(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, key=np.array(key), left=np.asarray(left, np.float32),
                         right=np.asarray(right, np.float32), **t)
    return files


def load_targets(files) -> DenseTargets:
    """The cached targets of ``files`` (:func:`cache_targets`) as one :class:`DenseTargets`; the
    images normalised as for training (:func:`stereojax.learning.sampling.normalise`)."""

    got = []
    for f in files:
        with np.load(f) as z:
            got.append({k: z[k] for k in ("left", "right", "y", "x", "offset", "target")})
    hmax = max(g["left"].shape[0] for g in got)
    wmax = max(g["left"].shape[1] for g in got)

    def pad(img):
        return np.pad(normalise(img), ((0, hmax - img.shape[0]), (0, wmax - img.shape[1])))

    cat = {k: np.concatenate([g[k] for g in got]) for k in ("y", "x", "offset", "target")}
    index = np.concatenate([np.full(len(g["y"]), i, np.int32) for i, g in enumerate(got)])
    return DenseTargets(left=jnp.asarray(np.stack([pad(g["left"]) for g in got])),
                        right=jnp.asarray(np.stack([pad(g["right"]) for g in got])),
                        index=jnp.asarray(index), y=jnp.asarray(cat["y"], jnp.int32),
                        x=jnp.asarray(cat["x"], jnp.int32), offset=jnp.asarray(cat["offset"], jnp.int32),
                        target=jnp.asarray(cat["target"].astype(np.float32)))


def dense_batch(key, data: DenseTargets, batch: int, patch_size: int):
    """(left patches ``f32[B, P, P, 1]``, right strips ``f32[B, P, K + P - 1, 1]``, targets
    ``f32[B, K]``, valid ``bool[B, K]``) of ``batch`` target pixels drawn at random. Strip column
    j is centred on x - (offset + K - 1) + j, so the tower's output j is disparity
    offset + K - 1 - j."""
    k = data.width
    r = patch_size // 2
    i = jax.random.randint(key, (batch,), 0, data.size)
    img, y, x, off = data.index[i], data.y[i], data.x[i], data.offset[i]
    dy = jnp.arange(patch_size) - r
    rows = (y[:, None] + dy[None, :])[:, :, None]                          # [B, P, 1]
    lcols = (x[:, None] + dy[None, :])[:, None, :]                         # [B, 1, P]
    ref = data.left[img[:, None, None], rows, lcols][..., None]
    first = x - (off + k - 1) - r                                          # leftmost strip column
    scols = first[:, None] + jnp.arange(k + 2 * r)[None, :]
    inside = (scols >= 0)[:, None, :]
    strip = jnp.where(inside, data.right[img[:, None, None], rows, jnp.maximum(scols, 0)[:, None, :]], 0.0)
    target = data.target[i]
    return ref, strip[..., None], jnp.nan_to_num(target), jnp.isfinite(target)


def band_scores(model: MatchNet, variables, ref, strip, train: bool):
    """The student's scores ``f32[B, K]`` (band order: disparity offset + k) of left patches
    against right strips, and the batch-norm updates when ``train``."""
    kw = {"mutable": ["batch_stats"]} if train else {}
    out = model.apply(variables, ref, train, method=MatchNet.features, **kw)
    fl, up1 = (out if train else (out, None))
    out = model.apply(variables, strip, train, method=MatchNet.features, **kw)
    fs, _ = (out if train else (out, None))
    fl, fs = fl[:, 0, 0], fs[:, 0, ::-1]                                   # [B, F], [B, K, F]
    return model.apply(variables, jnp.broadcast_to(fl[:, None, :], fs.shape), fs, method=MatchNet.compare), up1


def dense_loss(model: MatchNet, variables, data: DenseTargets, key, batch: int, patch_size: int):
    """Mean cross-entropy between the student's band similarities and the teacher's, over the
    valid band entries of ``batch`` random target pixels (tower in training mode)."""

    ref, strip, target, valid = dense_batch(key, data, batch, patch_size)
    scores, _ = band_scores(model, variables, ref, strip, train=True)
    return jnp.sum(jnp.where(valid, bce(scores, target), 0.0)) / jnp.maximum(valid.sum(), 1)
