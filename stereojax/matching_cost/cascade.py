"""The cascade's matching cost: the student's volume everywhere, the full network's cost at the
pixels where the student's chain is least sure.

The student (a compact network) runs the chain up to its confidence map. The ``share`` of real
pixels with the lowest confidence are *unsure*. At those pixels the full network's head runs at
the student's ``candidates`` best census candidates (the candidate chain's ranking, which both
networks' pruned heads use) and its cost replaces the student's whole band row: the head's cost
at the candidates, 1 elsewhere, exactly as the full network's own pruned volume holds it. The
rest of the chain (CBCA, SGM, ...) then runs once on the mixed volume
(:func:`stereojax.chain.cascade_second`).

The full network's tower runs on both whole images: on tiles around the unsure pixels and their
matches it would cost as much or more (experiments/results/cascade_premise.md: 0.78 of the
whole tower at 5 % of the pixels, 1.17 at 10 %, with 16x32 tiles), because those pixels lie
scattered along edges. Its head costs in proportion to the pixels it serves.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from stereojax.matching_cost.learned import head_at_pixels, tower_features
from stereojax.models.nets import MatchNet, NetConfig
from stereojax.volume import CostVolume, real_pixels


class CascadeSpec(NamedTuple):
    """What the cascade adds to the student's chain (hashable: a static argument).

    net: the full network's architecture; share: the share q of real pixels re-scored (0 < q <= 1);
    candidates: the full head's disparities per unsure pixel (the best of the candidate chain's
    ranking)."""

    net: NetConfig
    share: float
    candidates: int = 16


class Cascade(NamedTuple):
    """The cascade as a user gives it to :class:`~stereojax.inference.predictor.Predictor`: the
    full network (a :class:`~stereojax.models.nets.LearnedModel`) that re-scores the ``share`` of
    pixels where the student is least sure, at its ``candidates`` best candidates each."""

    full: object
    share: float
    candidates: int = 16

    def spec(self) -> CascadeSpec:
        return CascadeSpec(self.full.net, float(self.share), int(self.candidates))

    def check(self) -> "Cascade":
        from stereojax.errors import ConfigError
        if not 0.0 < float(self.share) <= 1.0:
            raise ConfigError(f"the cascade's share of re-scored pixels must be in (0, 1], got {self.share}")
        if int(self.candidates) < 1:
            raise ConfigError(f"the cascade's candidates must be >= 1, got {self.candidates}")
        if getattr(self.full, "net", None) is None or self.full.net.head == "cosine":
            raise ConfigError("the cascade's full network must be a LearnedModel with a dense head")
        return self


def unsure_pixels(confidence: jax.Array, share: float, valid=None) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(ys, xs, used) of the ``share`` of pixels with the lowest confidence ``f32[H, W]``, least
    sure first: ``i32[M]`` each with M = round(share x H x W) of the padded frame, and ``used``
    ``bool[M]`` (with ``valid``, only the first round(share x real pixels) are used, and padding
    is never chosen, so the real pixels get the choice of the unpadded pair)."""
    h, w = confidence.shape
    m = max(1, int(round(share * h * w)))
    score = confidence
    mask = real_pixels((h, w), valid)
    if mask is not None:
        score = jnp.where(mask, score, jnp.inf)
    pix = jnp.argsort(score.reshape(-1), stable=True)[:m]
    used = jnp.ones(m, bool)
    if valid is not None:
        m_real = jnp.round(share * valid[0] * valid[1]).astype(jnp.int32)
        used = jnp.arange(m) < jnp.maximum(m_real, 1)
    return (pix // w).astype(jnp.int32), (pix % w).astype(jnp.int32), used


def full_cost_rows(net: NetConfig, variables, left, right, ranked, ys, xs, candidates: int, valid=None):
    """``f32[M, K]`` the full network's head cost at pixels (ys, xs) and their ``candidates``
    best-ranked disparities ``ranked[ys, xs, :K]``, and those disparities ``i32[M, K]``; the
    tower runs on both whole images (:func:`tower_features`)."""
    fl, fr = tower_features(net, variables, left, right, valid)
    cand = ranked[ys, xs, :candidates]
    return head_at_pixels(MatchNet(net), variables, fl, fr, ys, xs, cand), cand


def mixed_volume(vol: CostVolume, ys, xs, used, cand, cost, fill: float = 1.0) -> CostVolume:
    """The student's volume with the rows of pixels (ys, xs) (where ``used``) replaced: ``fill``
    everywhere in the band but at the disparities ``cand`` ``i32[M, K]``, which get ``cost``."""
    m, k = cand.shape
    j = cand - vol.offset[ys, xs][:, None]                   # band index (0 for the full range)
    j = jnp.where((j >= 0) & (j < vol.k), j, vol.k)          # outside the band: dropped
    rows = jnp.full((m, vol.k), fill, vol.cost.dtype).at[jnp.arange(m)[:, None], j].set(cost, mode="drop")
    h = vol.shape[0]
    ys = jnp.where(used, ys, h)                              # unused: dropped
    return vol.with_cost(vol.cost.at[ys, xs].set(rows, mode="drop"))
