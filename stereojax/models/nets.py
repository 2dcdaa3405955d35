"""Flax modules of the learned matching cost: Siamese feature tower and similarity heads.

The tower is four 3x3 convolutions without padding, each followed by batch normalisation
and (except, by default, the last) ReLU: a 9x9 grey patch becomes one feature vector
``f32[F]``, and a whole image padded by 4 pixels becomes ``f32[H, W, F]`` with the same
parameters (convolution is translation-equivariant; batch norm uses its running statistics
at inference). Heads compare a left and a right feature vector:

* ``downsize`` — the paper's head: concatenate, dense 512 -> 384 -> 256 -> 128 (ReLU), then
  one logit; similarity s = sigmoid(logit).
* ``uniform`` — MC-CNN-accurate ("slow"): the same with equal widths (e.g. 384 x 4).
* ``cosine`` — MC-CNN-fast: s = <f_L, f_R> of L2-normalised features, no parameters.

All heads return a *logit-like score* (for the cosine head the cosine itself); use
:func:`similarity` for s in the head's natural range.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from stereojax.errors import ConfigError

HEADS = ("downsize", "uniform", "cosine")


@dataclass(frozen=True)
class NetConfig:
    """Architecture of the matching network (hashable: used as a static jit argument).

    features: feature maps per conv layer (64 on CPU, 112 in MC-CNN).
    layers: conv layers in the tower (patch size = 2 * layers + 1).
    final_relu: ReLU after the last conv (off by default: the head / cosine sees signed features).
    head: "downsize", "uniform" or "cosine".
    widths: hidden widths of a dense head (downsize: 512, 384, 256, 128; uniform e.g. 384 x 4).
    """

    features: int = 64
    layers: int = 4
    final_relu: bool = False
    head: str = "downsize"
    widths: tuple[int, ...] = (512, 384, 256, 128)

    @property
    def patch_size(self) -> int:
        return 2 * self.layers + 1

    def validate(self) -> "NetConfig":
        if self.head not in HEADS:
            raise ConfigError(f"net.head must be one of {HEADS}, got {self.head!r}")
        if self.features < 1 or self.layers < 1:
            raise ConfigError(f"net.features and net.layers must be >= 1, got {self.features}, {self.layers}")
        if self.head != "cosine" and (not self.widths or min(self.widths) < 1):
            raise ConfigError(f"net.widths must be positive for a dense head, got {self.widths}")
        return self


def net_preset(head: str, features: int = 64) -> NetConfig:
    widths = {"downsize": (512, 384, 256, 128), "uniform": (384, 384, 384, 384), "cosine": ()}
    if head not in widths:
        raise ConfigError(f"unknown head {head!r}; choose one of {HEADS}")
    return NetConfig(features=features, head=head, widths=widths[head]).validate()


class FeatureTower(nn.Module):
    """``f32[B, h, w, 1]`` grey input -> ``f32[B, h - 2L, w - 2L, F]`` features (valid convs)."""

    features: int
    layers: int
    final_relu: bool = False

    @nn.compact
    def __call__(self, x, train: bool = False):
        for i in range(self.layers):
            x = nn.Conv(self.features, (3, 3), padding="VALID", use_bias=False, name=f"conv{i}")(x)
            x = nn.BatchNorm(use_running_average=not train, momentum=0.9, name=f"bn{i}")(x)
            if i < self.layers - 1 or self.final_relu:
                x = nn.relu(x)
        return x


class DenseHead(nn.Module):
    """Concatenated left/right features ``f32[..., 2F]`` -> logit ``f32[...]``.

    The first layer is kept as two projections (``left``, ``right``) whose sum equals a
    dense layer on the concatenation, so that the cost volume can compute each once per image.
    """

    widths: Sequence[int]

    def first_layer(self, fl, fr):
        return self.left(fl) + self.right(fr)

    def setup(self):
        self.left = nn.Dense(self.widths[0], use_bias=True, name="first_left")
        self.right = nn.Dense(self.widths[0], use_bias=False, name="first_right")
        self.hidden = [nn.Dense(w, name=f"dense{i + 1}") for i, w in enumerate(self.widths[1:])]
        self.out = nn.Dense(1, name="out")

    def rest(self, h):
        """Layers after the first (input: the first layer's pre-activation)."""
        h = nn.relu(h)
        for layer in self.hidden:
            h = nn.relu(layer(h))
        return self.out(h)[..., 0]

    def __call__(self, fl, fr):
        return self.rest(self.first_layer(fl, fr))


class LearnedModel(NamedTuple):
    """A trained matching network: its architecture and its variables (params, batch_stats)."""

    net: NetConfig
    variables: Any


class MatchNet(nn.Module):
    """Siamese tower + head. ``__call__(left_patches, right_patches)`` -> score ``f32[B]``."""

    cfg: NetConfig

    def setup(self):
        c = self.cfg
        self.tower = FeatureTower(c.features, c.layers, c.final_relu)
        if c.head != "cosine":
            self.head = DenseHead(tuple(c.widths))

    def features(self, images, train: bool = False):
        """``f32[B, h, w, 1]`` -> ``f32[B, h - 2L, w - 2L, F]``."""
        return self.tower(images, train)

    def compare(self, fl, fr):
        """Score of feature vectors ``f32[..., F]`` (logit, or cosine for the cosine head)."""
        if self.cfg.head == "cosine":
            return (_l2n(fl) * _l2n(fr)).sum(-1)
        return self.head(fl, fr)

    def project(self, fl, fr):
        """First head layer split per view (dense heads only): (``left(fl)``, ``right(fr)``)."""
        return self.head.left(fl), self.head.right(fr)

    def finish(self, h):
        """Head layers after the first, on the summed projections ``f32[..., widths[0]]``."""
        return self.head.rest(h)

    def __call__(self, left_patches, right_patches, train: bool = False):
        fl = self.features(left_patches, train)[:, 0, 0]
        fr = self.features(right_patches, train)[:, 0, 0]
        return self.compare(fl, fr)


def _l2n(f, eps=1e-6):
    return f / jnp.sqrt((f * f).sum(-1, keepdims=True) + eps)


def similarity(cfg: NetConfig, score):
    """Similarity in [0, 1] from a head's score: sigmoid for dense heads, (1 + cos) / 2 for cosine."""
    if cfg.head == "cosine":
        return 0.5 * (1.0 + score)
    return jax.nn.sigmoid(score)


def network_flops(cfg: NetConfig, height: int, width: int, evals_per_pixel: float) -> float:
    """FLOP (2 per multiply-add) of the network on a ``height x width`` pair: the tower on both
    views, the split first head layer once per pixel and view, and the layers after it at
    ``evals_per_pixel`` disparities per pixel (cosine head: one F-dot product per evaluation)."""
    f = cfg.features
    tower = 2 * (9 * f + (cfg.layers - 1) * 9 * f * f)                  # both views
    if cfg.head == "cosine":
        per_eval, first = f, 0
    else:
        w = tuple(cfg.widths) + (1,)
        first = 2 * f * w[0]                                             # left + right projection
        per_eval = sum(a * b for a, b in zip(w[:-1], w[1:]))
    return 2.0 * height * width * (tower + first + evals_per_pixel * per_eval)


def init_params(cfg: NetConfig, key) -> dict:
    """Fresh variables ``{"params": ..., "batch_stats": ...}`` for ``cfg``."""
    p = cfg.patch_size
    x = jnp.zeros((2, p, p, 1), jnp.float32)
    return MatchNet(cfg).init(key, x, x, train=False)

