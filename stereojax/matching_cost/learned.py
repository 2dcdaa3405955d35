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

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from stereojax.models.nets import (LearnedModel,  # noqa: F401  (LearnedModel: re-exported)
                                   MatchNet, NetConfig)
from stereojax import kernels as kernels_mod
from stereojax.volume import CostVolume, real_pixels


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


def head_at_xla(model, variables, fl: jax.Array, fr: jax.Array, cand: jax.Array, rows_per_batch: int) -> jax.Array:
    """The JAX kernel of :func:`head_at`.

    The split first layer is computed a few rows at a time (at most ``rows_per_batch``, and at
    most 64 MB of pre-activation ``[rows, W, K, C1]``) inside ``lax.map``, so neither the
    projections of the whole image (``2 x [H, W, C1]``, 2 GB on a KITTI frame) nor the
    pre-activations are ever held at once; the work is the same as projecting once per image.
    """
    w, k = fl.shape[1], cand.shape[-1]
    c1 = model.cfg.widths[0]
    rows_per_batch = max(1, min(rows_per_batch, (64 << 20) // (w * k * c1 * 4)))

    def row(args):
        fl_r, fr_r, ct = args                                               # [W, F], [W, F], [W, K]
        at, bt = model.apply(variables, fl_r, fr_r, method=MatchNet.project)   # [W, C1]
        cols = jnp.maximum(jnp.arange(w)[:, None] - ct, 0)
        logit = model.apply(variables, at[:, None, :] + bt[cols], method=MatchNet.finish)
        return 1.0 - jax.nn.sigmoid(logit)

    return jax.lax.map(row, (fl, fr, cand), batch_size=rows_per_batch)


def head_params(variables, net: NetConfig) -> jax.Array:
    """The dense head's parameters packed as the native kernel reads them: first_left kernel and
    bias, first_right kernel, then each later layer's kernel and bias (``dense1``.., ``out``)."""
    p = variables["params"]["head"]
    parts = [p["first_left"]["kernel"], p["first_left"]["bias"], p["first_right"]["kernel"]]
    for name in [f"dense{i}" for i in range(1, len(net.widths))] + ["out"]:
        parts += [p[name]["kernel"], p[name]["bias"]]
    return jnp.concatenate([x.reshape(-1).astype(jnp.float32) for x in parts])


def head_at_native(model, variables, fl: jax.Array, fr: jax.Array, cand: jax.Array) -> jax.Array:
    """The native kernel (``head.cc``) of :func:`head_at_xla`: one row's projections at a time,
    the candidates through the layers in small register-blocked matrix products."""
    net = model.cfg
    h, w, k = cand.shape
    call = jax.ffi.ffi_call("stereojax_head", jax.ShapeDtypeStruct((h, w, k), jnp.float32), vmap_method="sequential")
    return call(fl.astype(jnp.float32), fr.astype(jnp.float32), cand.astype(jnp.int32), head_params(variables, net),
                widths=np.asarray(list(net.widths) + [1], np.int32), threads=np.int32(kernels_mod.threads()))


def head_band_native(model, variables, fl, fr, cand, offset, size: int, fill: float):
    """The native kernel of :func:`head_band_xla`: the head's costs and the band volume from one
    call (``head.cc``, StereojaxHeadBand)."""
    net = model.cfg
    h, w, k = cand.shape
    call = jax.ffi.ffi_call("stereojax_head_band", (jax.ShapeDtypeStruct((h, w, k), jnp.float32),
                                                   jax.ShapeDtypeStruct((h, w, size), jnp.float32)),
                            vmap_method="sequential")
    return call(fl.astype(jnp.float32), fr.astype(jnp.float32), cand.astype(jnp.int32), head_params(variables, net),
                offset.astype(jnp.int32), widths=np.asarray(list(net.widths) + [1], np.int32),
                fill=np.float32(fill), threads=np.int32(kernels_mod.threads()))


def head_band_xla(model, variables, fl, fr, cand, offset, size: int, fill: float, rows_per_batch: int):
    """(cost ``f32[H, W, K]`` of :func:`head_at_xla`, the volume ``f32[H, W, size]`` that holds
    each cost at entry cand - offset and ``fill`` elsewhere)."""
    h, w, _ = cand.shape
    cost = head_at_xla(model, variables, fl, fr, cand, rows_per_batch)
    yy, xx = jnp.mgrid[:h, :w]
    vol = jnp.full((h, w, size), fill, jnp.float32).at[yy[..., None], xx[..., None], cand - offset[..., None]].set(cost)
    return cost, vol


def head_band(model, variables, fl, fr, cand, offset, size: int, fill: float, rows_per_batch: int,
              kernels: str = "xla"):
    """:func:`head_band_xla` with the kernel of the ``kernels`` setting: the head at the
    candidates and the band volume they fill, in one native call on the CPU."""
    return kernels_mod.select(kernels, functools.partial(head_band_native, model, variables, size=size, fill=fill),
                              functools.partial(head_band_xla, model, variables, size=size, fill=fill,
                                                rows_per_batch=rows_per_batch),
                              fl, fr, cand, offset)


def head_at(model, variables, fl: jax.Array, fr: jax.Array, cand: jax.Array, rows_per_batch: int,
            kernels: str = "xla") -> jax.Array:
    """``f32[H, W, K]``: head cost 1 - s at the disparities ``cand`` ``i32[H, W, K]``.

    fl, fr: tower features of the left and right view ``f32[H, W, F]``. With the kernel of the
    ``kernels`` setting (:mod:`stereojax.kernels`; the chain passes its config's, and the
    default "xla" keeps the function differentiable for other callers)."""
    return kernels_mod.select(kernels, functools.partial(head_at_native, model, variables),
                              functools.partial(head_at_xla, model, variables, rows_per_batch=rows_per_batch),
                              fl, fr, cand)


def head_at_pixels(model, variables, fl, fr, ys, xs, cand, chunk: int = 2048) -> jax.Array:
    """``f32[M, K]``: head cost at pixels (ys, xs) ``i32[M]`` and disparities ``cand`` ``i32[M, K]``
    (features ``f32[H, W, F]`` gathered, then projected: no whole-image projections)."""
    m, k = cand.shape
    chunks = -(-m // chunk)
    pad = chunks * chunk - m

    def padded(x):
        return jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1)).reshape((chunks, chunk) + x.shape[1:])

    def one(args):
        y, x, c = args                                                       # [n], [n], [n, K]
        at, bt = model.apply(variables, fl[y, x], fr[y[:, None], jnp.maximum(x[:, None] - c, 0)],
                             method=MatchNet.project)                        # [n, C1], [n, K, C1]
        return 1.0 - jax.nn.sigmoid(model.apply(variables, at[:, None, :] + bt, method=MatchNet.finish))

    return jax.lax.map(one, (padded(ys), padded(xs), padded(cand))).reshape(chunks * chunk, k)[:m]


def candidate_config(config):
    """The census chain that proposes the learned head's candidates
    (:data:`stereojax.chain.CANDIDATE`), from the learned chain's own config: census window
    ``cost.census_radius`` in the chain's bands, cross arms of ``cbca`` (the same arms as the
    chain's, so they are made once), its ``cost.candidate_cbca`` passes, and ``sgm`` with
    ``cost.candidate_p1`` / ``candidate_p2`` (penalties on the census cost scale)."""

    c = config.cost
    return dataclasses.replace(
        config, cost=dataclasses.replace(c, method="census", border="replicate", candidates=0),
        cbca=dataclasses.replace(config.cbca, iterations_before=c.candidate_cbca, iterations_after=0),
        sgm=dataclasses.replace(config.sgm, p1=c.candidate_p1, p2=c.candidate_p2))


def _ks(config) -> tuple[int, int]:
    """(K for every pixel, K2 for the least sure share; K2 == K when not adaptive)."""
    c = config.cost
    d = config.band.width if config.banded else config.max_disp
    k1 = min(c.candidates, d)
    k2 = min(max(c.unsure_candidates, c.candidates), d) if c.unsure_share > 0 else k1
    return k1, k2


def rank_candidates(cand_vol: jax.Array, config) -> jax.Array:
    """``i32[H, W, K2]``: the disparities of lowest candidate cost, best first (K2 as
    :func:`adaptive_dense_cost` needs; one top_k of the whole volume: a top_k of the gathered
    rows of the unsure pixels alone is several times slower on the CPU)."""
    return jax.lax.top_k(-cand_vol, _ks(config)[1])[1].astype(jnp.int32)


def adaptive_dense_cost(net: NetConfig, variables, fl, fr, cand_vol: jax.Array, config,
                        fill: float = 1.0, valid=None) -> jax.Array:
    """PRUNED MODE, adaptive (not exact): ``f32[H, W, D]`` with the head evaluated

    1. for every pixel at the K = ``config.cost.candidates`` disparities of lowest cost in the
       candidate volume ``cand_vol``;
    2. for the ``config.cost.unsure_share`` of pixels where the head is least sure (the
       highest best head cost among those K: no good match found), also at the next
       candidates, up to K2 = ``config.cost.unsure_candidates`` in all.

    Every other entry gets ``fill``. Cost: K + share * (K2 - K) head evaluations per pixel
    instead of D. valid: ``i32[2]`` real size of a padded pair: the share is then of the real
    pixels, and padding pixels are never chosen, so the real pixels get exactly the choice of
    the unpadded pair.
    """
    return ranked_dense_cost(net, variables, fl, fr, rank_candidates(cand_vol, config), config, fill, valid)


def ranked_dense_cost(net: NetConfig, variables, fl, fr, ranked: jax.Array, config,
                      fill: float = 1.0, valid=None, offset=None) -> jax.Array:
    """:func:`adaptive_dense_cost` from the ranked candidates ``i32[H, W, K2]``
    (:func:`rank_candidates`, absolute disparities). offset: ``i32[H, W]`` band offsets; the
    result is then the band ``f32[H, W, band.width]`` (entry k: disparity offset + k) instead
    of the full ``f32[H, W, D]``."""
    c = config.cost
    d = config.max_disp
    k1, k2 = _ks(config)
    model = MatchNet(net)
    h, w, _ = fl.shape
    m = int(c.unsure_share * h * w) if k2 > k1 else 0
    size = d if offset is None else config.band.width
    # a barrier keeps XLA from fusing the ranking into the head's loop (measured: 1.5x slower)
    ranked = jax.lax.optimization_barrier(ranked)
    cand = ranked[..., :k1]
    off = jnp.zeros((h, w), jnp.int32) if offset is None else offset
    cost, vol = head_band(model, variables, fl, fr, cand, off, size, fill, c.rows_per_tile, config.kernels)
    if m == 0:
        return vol
    unsure = cost.min(axis=-1)                                                # best head cost found
    if valid is not None:
        unsure = jnp.where(real_pixels((h, w), valid), unsure, -1.0)          # padding: never chosen
    pix = jnp.argsort(-unsure.reshape(-1), stable=True)[:m]                    # least sure first
    ys, xs = pix // w, pix % w
    more = ranked.reshape(h * w, -1)[pix, k1:]                                # [M, K2 - K]
    idx = more if offset is None else more - offset.reshape(-1)[pix][:, None]
    if valid is not None:   # the share is of the real pixels
        m_real = jnp.floor(c.unsure_share * valid[0] * valid[1]).astype(jnp.int32)
        idx = jnp.where((jnp.arange(m) < m_real)[:, None], idx, size)
    more_cost = head_at_pixels(model, variables, fl, fr, ys, xs, jnp.minimum(more, d - 1))
    return vol.at[ys[:, None], xs[:, None], idx].set(more_cost, mode="drop")


def rank_xla(vol: CostVolume, config) -> jax.Array:
    """The JAX kernel of :func:`rank`."""
    if not vol.banded:
        return rank_candidates(vol.cost, config)
    return (jax.lax.top_k(-vol.cost, _ks(config)[1])[1] + vol.offset[..., None]).astype(jnp.int32)


def rank_native(vol: CostVolume, config) -> jax.Array:
    """The native kernel (``ranking.cc``) of :func:`rank_xla`: the same order, ties included."""
    h, w, _ = vol.cost.shape
    call = jax.ffi.ffi_call("stereojax_rank", jax.ShapeDtypeStruct((h, w, _ks(config)[1]), jnp.int32),
                            vmap_method="sequential")
    return call(vol.cost.astype(jnp.float32), vol.offset.astype(jnp.int32), banded=np.int32(bool(vol.banded)),
                threads=np.int32(kernels_mod.threads()))


def rank(vol: CostVolume, config) -> jax.Array:
    """``i32[H, W, K2]``: the absolute disparities of lowest cost in the candidate chain's
    CostVolume, best first (full range: :func:`rank_candidates`), with the kernel of
    ``config.kernels`` (:mod:`stereojax.kernels`: native C++ on the CPU, else ``lax.top_k``)."""
    return kernels_mod.select(config.kernels, functools.partial(rank_native, config=config),
                              functools.partial(rank_xla, config=config), vol)


def band_volume(net: NetConfig, variables, fl, fr, ranked, config, offset=None, valid=None):
    """The learned :class:`~stereojax.volume.CostVolume` from tower features and ranked
    candidates (pruned mode), in the bands ``offset`` (None: full range)."""
    cost = ranked_dense_cost(net, variables, fl, fr, ranked, config, valid=valid, offset=offset)
    if offset is None:
        return CostVolume.full(cost, valid)
    return CostVolume.band(cost, offset, config.max_disp, valid)


def tower_features(net: NetConfig, variables, left: jax.Array, right: jax.Array, valid=None):
    """Tower features ``f32[H, W, F]`` of both views, in one batched call of the tower.

    valid: ``i32[2]`` (rows, columns) of the real image when the pair is padded to a size
    bucket; the normalisation statistics are then taken over that region only.
    """
    mask = real_pixels(left.shape, valid)
    if mask is None:
        mask = jnp.ones(left.shape, bool)

    def norm(g):
        n = jnp.maximum(mask.sum(), 1)
        mean = jnp.where(mask, g, 0.0).sum() / n
        std = jnp.sqrt(jnp.where(mask, (g - mean) ** 2, 0.0).sum() / n)
        return (g - mean) / jnp.maximum(std, 1e-6)

    r = net.layers
    x = jnp.stack([jnp.pad(norm(left), r, mode="edge"), jnp.pad(norm(right), r, mode="edge")])[..., None]
    f = MatchNet(net).apply(variables, x, False, method=MatchNet.features)
    return f[0], f[1]


def learned_volume(net: NetConfig, variables, features, ranked, config, offset=None, valid=None) -> CostVolume:
    """Left-view :class:`~stereojax.volume.CostVolume` of the chain ``config`` (a StereoConfig
    with ``cost.method == "learned"``) from the tower features ``(f32[H, W, F], f32[H, W, F])``
    (:func:`tower_features`), over the full range or in the bands ``offset`` ``i32[H, W]``.

    ``config.cost.candidates``: 0 = exact (every disparity of the band through the head; cosine
    head: full range only); K > 0 = pruned mode: the head runs at ``ranked`` ``i32[H, W, K2]``,
    the candidate chain's disparities (:data:`stereojax.chain.CANDIDATE`, :func:`rank`), and on
    ``cost.unsure_candidates`` for the ``cost.unsure_share`` of the pixels where it is least
    sure (:func:`adaptive_dense_cost`).
    """
    fl, fr = features
    d = config.max_disp
    if ranked is not None:
        return band_volume(net, variables, fl, fr, ranked, config, offset, valid)
    if offset is None:
        if net.head == "cosine":
            return CostVolume.full(cosine_cost(fl, fr, d), valid)
        return CostVolume.full(dense_cost(net, variables, fl, fr, d, config.cost.rows_per_tile), valid)
    if net.head == "cosine":
        raise ValueError("the cosine head runs over the full range only (set band.width = 0)")
    disp = offset[..., None] + jnp.arange(config.band.width, dtype=jnp.int32)
    cost = head_at(MatchNet(net), variables, fl, fr, disp, config.cost.rows_per_tile, config.kernels)
    return CostVolume.band(cost, offset, d, valid)
