"""Cost volume of a whole image pair from the matching network.

The tower runs once per image (the image padded by ``layers`` pixels, edge-replicated, so
that every pixel gets a 9x9 receptive field). Then, for the left view:

* cosine head: C(y, x, d) = (1 - cos(f_L(y, x), f_R(y, x - d))) / 2, one fused dot product
  per disparity;
* dense heads: the first dense layer acts on the concatenation [f_L, f_R], so it splits
  *exactly* into a left projection A = f_L W_L + b and a right projection B = f_R W_R,
  each computed once per image; for each disparity only relu(A(x) + B(x - d)) and the
  remaining layers run, over row tiles (``lax.map``) so that memory stays bounded.
  C = 1 - sigmoid(logit).

Columns with x - d < 0 compare with the right image's first column (``border="replicate"``,
as the classical costs do). The volume is ``f32[H, W, D]`` in [0, 1], lower is better.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from .nets import MatchNet, NetConfig


class LearnedModel(NamedTuple):
    """A trained matching network: its architecture and its variables (params, batch_stats)."""

    net: NetConfig
    variables: Any


def image_features(net: NetConfig, variables, grey: jax.Array) -> jax.Array:
    """``f32[H, W, F]`` tower features of a normalised grey image ``f32[H, W]``."""
    r = net.layers
    x = jnp.pad(grey, r, mode="edge")[None, :, :, None]
    return MatchNet(net).apply(variables, x, False, method=MatchNet.features)[0]


def normalise(grey: jax.Array) -> jax.Array:
    """Zero mean, unit variance per image (as in training)."""
    return (grey - grey.mean()) / jnp.maximum(grey.std(), 1e-6)


def _shift_right_features(fr: jax.Array, d) -> jax.Array:
    """out[y, x] = fr[y, max(x - d, 0)] for a traced disparity d."""
    w = fr.shape[1]
    cols = jnp.maximum(jnp.arange(w) - d, 0)
    return jnp.take(fr, cols, axis=1)


def cosine_cost(fl: jax.Array, fr: jax.Array, max_disp: int, rows_per_batch: int = 8) -> jax.Array:
    """``f32[H, W, D]`` cost of the cosine head from features ``f32[H, W, F]``.

    Per image row, all left-right dot products are one ``[W, F] x [F, W]`` matmul, from which
    the band x' = x - d is gathered; rows go through ``lax.map`` in small batches, so memory
    stays at a few rows of ``[W, W]``.
    """
    def unit(f):
        return f / jnp.sqrt((f * f).sum(-1, keepdims=True) + 1e-6)

    fl, fr = unit(fl), unit(fr)
    w = fr.shape[1]
    cols = jnp.maximum(jnp.arange(w)[:, None] - jnp.arange(max_disp)[None, :], 0)   # [W, D]

    def row(args):
        a, b = args                                                             # [W, F]
        return jnp.take_along_axis(a @ b.T, cols, axis=1)                       # [W, D]

    sims = jax.lax.map(row, (fl, fr), batch_size=rows_per_batch)
    return 0.5 * (1.0 - sims)


def dense_cost(net: NetConfig, variables, fl: jax.Array, fr: jax.Array, max_disp: int,
               rows_per_tile: int = 32) -> jax.Array:
    """``f32[H, W, D]`` cost of a dense head, with the exact split first layer (see module doc)."""
    model = MatchNet(net)
    a, b = model.apply(variables, fl, fr, method=MatchNet.project)            # [H, W, C1] each
    h, w, _ = a.shape
    tiles = -(-h // rows_per_tile)
    pad = tiles * rows_per_tile - h
    a_t = jnp.pad(a, ((0, pad), (0, 0), (0, 0))).reshape(tiles, rows_per_tile, w, -1)
    b_t = jnp.pad(b, ((0, pad), (0, 0), (0, 0))).reshape(tiles, rows_per_tile, w, -1)

    def tile_cost(ab):
        at, bt = ab                                                           # [R, W, C1]

        def one_disp(d):
            hpre = at + _shift_right_features(bt, d)
            logit = model.apply(variables, hpre, method=MatchNet.finish)      # [R, W]
            return 1.0 - jax.nn.sigmoid(logit)

        return jax.lax.map(one_disp, jnp.arange(max_disp))                    # [D, R, W]

    vol = jax.lax.map(tile_cost, (a_t, b_t))                                  # [T, D, R, W]
    vol = jnp.moveaxis(vol, 1, -1).reshape(tiles * rows_per_tile, w, max_disp)
    return vol[:h]


def naive_dense_cost(net: NetConfig, variables, fl, fr, max_disp: int) -> jax.Array:
    """Reference: the head applied to every concatenated pair (no split); small inputs only."""
    model = MatchNet(net)
    cols = []
    for d in range(max_disp):
        logit = model.apply(variables, fl, _shift_right_features(fr, d), method=MatchNet.compare)
        cols.append(1.0 - jax.nn.sigmoid(logit))
    return jnp.stack(cols, axis=-1)


def pruned_dense_cost(net: NetConfig, variables, fl: jax.Array, fr: jax.Array, candidates: jax.Array,
                      max_disp: int, rows_per_tile: int = 4, fill: float = 1.0) -> jax.Array:
    """PRUNED MODE (not exact): the dense head only at ``candidates`` ``i32[H, W, K]``.

    Every other entry of the ``f32[H, W, D]`` volume gets ``fill`` (the worst cost). With K
    candidates per pixel this costs K / D of :func:`dense_cost`.
    """
    model = MatchNet(net)
    a, b = model.apply(variables, fl, fr, method=MatchNet.project)            # [H, W, C1]
    h, w, c1 = a.shape
    k = candidates.shape[-1]
    tiles = -(-h // rows_per_tile)
    pad = tiles * rows_per_tile - h

    def tiled(x):
        return jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1)).reshape((tiles, rows_per_tile) + x.shape[1:])

    def tile_cost(args):
        at, bt, ct = args                                                     # [R, W, C1], [R, W, K]
        cols = jnp.maximum(jnp.arange(w)[None, :, None] - ct, 0)              # [R, W, K]
        rows = jnp.arange(rows_per_tile)[:, None, None]
        hpre = at[:, :, None, :] + bt[rows, cols]                             # [R, W, K, C1]
        logit = model.apply(variables, hpre, method=MatchNet.finish)          # [R, W, K]
        vol = jnp.full((rows_per_tile, w, max_disp), fill, jnp.float32)
        r_i = jnp.broadcast_to(rows, ct.shape)
        x_i = jnp.broadcast_to(jnp.arange(w)[None, :, None], ct.shape)
        return vol.at[r_i, x_i, ct].set(1.0 - jax.nn.sigmoid(logit))

    vol = jax.lax.map(tile_cost, (tiled(a), tiled(b), tiled(candidates)))
    return vol.reshape(tiles * rows_per_tile, w, max_disp)[:h]


def census_candidates(left: jax.Array, right: jax.Array, max_disp: int, k: int) -> jax.Array:
    """``i32[H, W, K]``: the K disparities of lowest census + CBCA + SGM cost (tuned census
    preset), the candidate generator of the pruned mode."""
    from . import aggregation, cost as cost_mod
    from .config import StereoConfig
    from .sgm import sgm

    c = StereoConfig()
    vol = cost_mod.census_cost(left, right, max_disp, c.cost.census_radius)
    arms = aggregation.cross_arms(left, c.cbca.tau, c.cbca.arm_length)
    vol = aggregation.cbca(vol, arms, c.cbca.iterations_before, c.cbca.arm_length)
    vol = sgm(vol, left, right, c.sgm)
    return jax.lax.top_k(-vol, k)[1].astype(jnp.int32)


@functools.partial(jax.jit, static_argnames=("net", "max_disp", "rows_per_tile", "candidates"))
def learned_cost(net: NetConfig, variables, left: jax.Array, right: jax.Array, max_disp: int,
                 rows_per_tile: int = 32, candidates: int = 0) -> jax.Array:
    """Left-view cost volume ``f32[H, W, D]`` of grey images (0..255) ``f32[H, W]``.

    candidates: 0 = exact (every disparity through the head); K > 0 = pruned mode, the dense
    head only on the K best disparities of the census pipeline (see :func:`pruned_dense_cost`).
    """
    fl = image_features(net, variables, normalise(left))
    fr = image_features(net, variables, normalise(right))
    if net.head == "cosine":
        return cosine_cost(fl, fr, max_disp)
    if candidates:
        cand = census_candidates(left, right, max_disp, min(candidates, max_disp))
        return pruned_dense_cost(net, variables, fl, fr, cand, max_disp, max(1, rows_per_tile // 8))
    return dense_cost(net, variables, fl, fr, max_disp, rows_per_tile)
