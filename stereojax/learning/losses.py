"""Element-wise training losses of the matching network (mean them yourself).

* :func:`bce` — binary cross-entropy on a logit (MC-CNN's loss).
* :func:`relaxed` — the paper's relaxed cross-entropy (Eq. 3.6) with margin delta: plain
  BCE, except that a positive whose similarity s is already in [1 - 3 delta, 1 - delta] is
  scored with -ln(delta + s), and a negative whose s is in [delta, 3 delta] with
  -ln(delta + 1 - s), so nearly-right answers are pushed less hard. delta = 0 is exactly BCE.
* :func:`hinge` — margin ranking loss of MC-CNN-fast on cosine scores of a positive and a
  negative pair: max(0, margin + s_neg - s_pos).

All take logits (scores) rather than probabilities, so that -ln(s) and -ln(1 - s) are
computed stably as softplus(-z) and softplus(z) at any s, including s -> 0 and s -> 1.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def bce(logit: jax.Array, label: jax.Array) -> jax.Array:
    """-[y ln s + (1 - y) ln(1 - s)] with s = sigmoid(logit); label 1 = match, 0 = non-match."""
    return label * jax.nn.softplus(-logit) + (1.0 - label) * jax.nn.softplus(logit)


def relaxed(logit: jax.Array, label: jax.Array, delta: float = 0.05) -> jax.Array:
    """The relaxed cross-entropy of paper Eq. 3.6 (see module docstring); f32 like ``logit``."""
    if delta == 0:
        return bce(logit, label)
    s = jax.nn.sigmoid(logit)
    # inside the relaxed bands the arguments of the logs are >= 1 - 2 delta > 1/3: no clipping
    # is needed there; outside them the plain (stable) BCE terms are used.
    pos_band = (s >= 1.0 - 3.0 * delta) & (s <= 1.0 - delta)
    neg_band = (s >= delta) & (s <= 3.0 * delta)
    safe = lambda v: jnp.maximum(v, 1e-12)   # only matters for the branch not taken
    pos = jnp.where(pos_band, -jnp.log(safe(delta + s)), jax.nn.softplus(-logit))
    neg = jnp.where(neg_band, -jnp.log(safe(delta + 1.0 - s)), jax.nn.softplus(logit))
    return label * pos + (1.0 - label) * neg


def hinge(score_pos: jax.Array, score_neg: jax.Array, margin: float = 0.2) -> jax.Array:
    """max(0, margin + s_neg - s_pos) on cosine scores of a positive and a negative pair."""
    return jnp.maximum(0.0, margin + score_neg - score_pos)
