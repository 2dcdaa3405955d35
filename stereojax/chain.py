"""The method's chain, written once: bands -> matching cost -> CBCA -> SGM -> CBCA -> WTA ->
right view and left-right check -> filling -> confidence -> sub-pixel -> median -> bilateral.

Every stage after the matching cost takes and returns a state dict whose volume is a
:class:`~stereojax.volume.CostVolume` (full range or per-pixel bands, see
:mod:`stereojax.volume`); :data:`STAGES` lists them in order, :func:`run` runs them, and
``stereojax bench`` times the same list one stage at a time. The front of the chain (the
coarse pass that sets the bands, and the matching cost in those bands) is :func:`front`:
:func:`bands`, then :func:`classic_volume` or the learned cost of :mod:`stereojax.learned_cost`.

This module is the only one that knows the methods: :func:`model_args` checks a model against
the cost method, and :func:`two_programs` says when a method runs as two compiled programs
(:func:`first_program`, :func:`second_program`; the pruned learned cost, for its peak memory).
The inference code (:mod:`stereojax.pipeline`: inputs, buckets, compiled programs, Predictor)
compiles what this module gives it without naming a method.
"""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp

from . import aggregation, coarse, cost as cost_mod, refine
from .compile_cache import real_pixels
from .sgm import sgm, sgm_volume
from .volume import OUT_OF_BAND, CostVolume


# ---- front: bands and the classical matching cost -------------------------------------------

def bands(left: jax.Array, right: jax.Array, config, valid=None):
    """(left offsets, right offsets) ``i32[H, W]`` from the coarse pass when the config is
    banded (:mod:`stereojax.coarse`), else (None, None): the full range."""
    if not config.banded:
        return None, None
    return coarse.bands(left, right, config, valid)


def limit_bands(offsets, limits, config):
    """Band offsets moved inside per-pixel disparity limits ``i32[2, H, W]`` (MIN <= d < MAX in
    the chain's disparities; None: unchanged): each band starts at or after MIN and, where the
    limits are at least K wide, ends at or before MAX - 1, so that it holds as much of the
    allowed range as it can."""
    if offsets is None or limits is None:
        return offsets
    k = config.band.width
    lo, hi = limits[0], limits[1]
    off = jnp.clip(offsets, lo, jnp.maximum(lo, hi - k))
    return jnp.clip(off, 0, config.max_disp - k)


def classic_volume(left: jax.Array, right: jax.Array, config, offsets, valid=None) -> CostVolume:
    """The census or SAD cost of the left view in the bands ``offsets`` (None: full range)."""
    if offsets is None:
        return CostVolume.full(cost_mod.matching_cost(left, right, config.max_disp, config.cost, "left"), valid)
    return cost_mod.band_cost(left, right, offsets, config.band.width, config.max_disp, config.cost, valid)


def limited_bands(left, right, config, valid=None, limits=None):
    """:func:`bands`, the left view's moved inside the per-pixel ``limits`` (:func:`limit_bands`)."""
    off_l, off_r = bands(left, right, config, valid)
    return limit_bands(off_l, limits, config), off_r


def model_args(config, model):
    """(variables, net) for the jitted chain, checking ``model`` against the cost method: a
    :class:`~stereojax.learned_cost.LearnedModel` for the learned cost, None for the classical ones."""
    from .errors import ConfigError

    if config.cost.method == "learned":
        from .learned_cost import LearnedModel

        if not isinstance(model, LearnedModel):
            raise ConfigError("cost method 'learned' needs params=LearnedModel (e.g. "
                              "stereojax.load_model('weights.msgpack')), got "
                              f"{type(model).__name__}")
        return model.variables, model.net
    if model is not None:
        raise ConfigError(f"cost method {config.cost.method!r} is classical and takes no network "
                          "parameters; pass params=None")
    return None, None


def left_volume(left, right, config, variables, net, valid=None, offset=None) -> CostVolume:
    """The left-view matching cost of the config's method in the bands ``offset`` (None: full)."""
    if config.cost.method == "learned":
        from .learned_cost import learned_volume

        return learned_volume(net, variables, left, right, config, valid, offset)
    return classic_volume(left, right, config, offset, valid)


def front(left, right, config, variables=None, net=None, valid=None, limits=None):
    """(the left-view :class:`CostVolume`, the right view's band offsets or None): the coarse
    pass's bands, moved inside the per-pixel ``limits``, and the matching cost in them."""
    off_l, off_r = limited_bands(left, right, config, valid, limits)
    return left_volume(left, right, config, variables, net, valid, off_l), off_r


def two_programs(config, net) -> bool:
    """Whether the chain runs as two compiled programs (:func:`first_program`, then
    :func:`second_program`): the pruned learned cost does, so that the candidate chain's volumes
    are gone before the learned volume exists and the peak memory is that of the larger half
    (measured on a KITTI frame: 3.2 GiB peak RSS instead of 4.3 as one program)."""
    return config.cost.method == "learned" and config.cost.candidates > 0 and net is not None \
        and net.head != "cosine"


@functools.partial(jax.jit, static_argnames=("config", "net"))
def first_program(left, right, valid, config, variables=None, net=None, limits=None):
    """First program of a two-program chain: tower features of both views, the bands of both
    views (the left ones inside ``limits``) and the ranked census candidates ``i32[H, W, K2]``."""
    from .learned_cost import ranked_candidates, tower_features

    fl, fr = tower_features(net, variables, left, right, valid)
    off_l, off_r = limited_bands(left, right, config, valid, limits)
    return fl, fr, ranked_candidates(left, right, config, off_l, valid), (off_l, off_r)


def carry_volume(carry, config, variables, net, valid=None):
    """(the left-view CostVolume, the right view's offsets) from :func:`first_program`'s outputs:
    the head at the candidates."""
    from .learned_cost import band_volume

    fl, fr, ranked, (off_l, off_r) = carry
    return band_volume(net, variables, fl, fr, ranked, config, off_l, valid), off_r


@functools.partial(jax.jit, static_argnames=("config", "net", "confidence"))
def second_program(left, right, valid, carry, config, variables=None, net=None, confidence: bool = False,
                   limits=None):
    """Second program of a two-program chain: the volume from ``carry`` (:func:`carry_volume`),
    then every stage of :data:`STAGES`; the disparity (and confidence)."""
    vol, off_r = carry_volume(carry, config, variables, net, valid)
    return result(run(vol, off_r, left, right, config, limits=limits), confidence)


def result(out: dict, confidence: bool):
    """The disparity of :func:`run`'s output, or (disparity, confidence) when asked for."""
    return (out["disparity"], out["confidence"]) if confidence else out["disparity"]


# ---- the stages after the matching cost -----------------------------------------------------

def _arms(st, config):
    mask = real_pixels(st["left"].shape, st["vol"].valid)
    st["arms"] = aggregation.cross_arms(st["left"], config.cbca.tau, config.cbca.arm_length, mask)
    return st


def _neutral(st, config):
    if config.cost.border == "neutral":
        st["vol"] = cost_mod.neutral_border_volume(st["vol"])
    return st


def _cbca(st, config, iterations: int, key: str):
    st["vol"] = st[key] = aggregation.cbca_volume(st["vol"], st["arms"], iterations, config.cbca.arm_length)
    return st


def _cbca_before(st, config):
    return _cbca(st, config, config.cbca.iterations_before, "cost_cbca")


def _sgm(st, config):
    st["vol"] = st["cost_sgm"] = sgm_volume(st["vol"], st["left"], st["right"], config.sgm)
    return st


def _cbca_after(st, config):
    return _cbca(st, config, config.cbca.iterations_after, "cost_final")


def _limits(st, config):
    """Per-pixel disparity limits (``st["limits"]`` ``i32[2, H, W]``, MIN <= d < MAX; absent:
    none): every entry outside them costs :data:`~stereojax.volume.OUT_OF_BAND`, so WTA, the
    right view, the confidence and the sub-pixel fit choose inside them."""
    limits = st.get("limits")
    if limits is None:
        return st
    vol = st["vol"]
    d = vol.disparities() if vol.banded else jnp.arange(vol.k, dtype=jnp.int32)[None, None, :]
    inside = (d >= limits[0][..., None]) & (d < limits[1][..., None])
    st["vol"] = vol.with_cost(jnp.where(inside, vol.cost, OUT_OF_BAND))
    return st


def _wta(st, config):
    st["disp_wta"] = refine.wta_volume(st["vol"])
    st["disp"] = st["disp_wta"].astype(jnp.float32)
    return st


def _right_view(st, config):
    if not config.refine.lr_check:
        return st
    vol = st["vol"]
    if config.refine.right_from_left:
        st["disp_right"] = refine.right_wta(vol, st["right_offset"], cost_mod.INVALID_COST)
    else:                      # full range only (config.validate): the right view aggregated on its own
        st["disp_right"] = refine.wta(_right_chain(st, config))
    return st


def _right_chain(st, config):
    """CBCA -> SGM -> CBCA of the right view's own full volume (``refine.right_from_left`` off)."""
    left, right, valid = st["left"], st["right"], st["vol"].valid
    d = config.max_disp
    if config.cost.method == "learned":
        # the network's right-view cost is exactly the skewed left one: C_R(x, d) = C_L(x + d, d)
        vol_r = refine.right_cost_from_left(st["cost"].cost, cost_mod.INVALID_COST,
                                            None if valid is None else valid[1])
    else:
        vol_r = cost_mod.matching_cost(left, right, d, config.cost, "right")
    w = left.shape[1]
    arms = aggregation.cross_arms(right, config.cbca.tau, config.cbca.arm_length, real_pixels(right.shape, valid))
    c1 = aggregation.cbca(vol_r, arms, config.cbca.iterations_before, config.cbca.arm_length)
    # mirrored (x -> W - 1 - x turns "match at x + d" into "match at x' - d"), padding on the left
    real = None if valid is None else (0, valid[0], w - valid[1], w)
    c2 = sgm(c1[:, ::-1], right[:, ::-1], left[:, ::-1], config.sgm, real)[:, ::-1]
    return aggregation.cbca(c2, arms, config.cbca.iterations_after, config.cbca.arm_length)


def _lr_fill(st, config):
    if not config.refine.lr_check:
        return st
    labels = refine.lr_check(st["disp"], st["disp_right"].astype(jnp.float32), config.max_disp,
                             config.refine.lr_tolerance)
    mask = st["vol"].real_mask()
    if mask is not None:    # padding never serves as a source of the filling
        labels = jnp.where(mask, labels, refine.MISMATCH)
    st["labels"] = labels
    st["disp"] = st["disp_filled"] = refine.fill_disparity(st["disp"], labels)
    return st


def _confidence(st, config):
    st["confidence"] = refine.confidence_volume(st["vol"], st["disp_wta"], st.get("disp_right"),
                                                config.refine.lr_tolerance)
    return st


def _subpixel(st, config):
    if config.refine.subpixel:
        st["disp"] = st["disp_subpixel"] = refine.subpixel_volume(st["vol"], st["disp"])
    return st


def _median(st, config):
    st["disp"] = st["disp_median"] = refine.median_filter(st["disp"], config.refine.median_size)
    return st


def _bilateral(st, config):
    r = config.refine
    disp = refine.bilateral_filter(st["disp"], st["left"], r.bilateral_radius, r.bilateral_sigma_space,
                                   r.bilateral_sigma_range)
    st["disparity"] = jnp.clip(disp, 0.0, float(config.max_disp - 1))
    limits = st.get("limits")
    if limits is not None:          # the filling and the filters never leave a pixel's limits
        st["disparity"] = jnp.clip(st["disparity"], limits[0].astype(jnp.float32),
                                   (limits[1] - 1).astype(jnp.float32))
    return st


#: the stages after the matching cost, in order: (name, stage(state, config) -> state)
STAGES: list[tuple[str, Callable]] = [
    ("cross arms", _arms),
    ("neutral out-of-view strip", _neutral),
    ("CBCA before SGM", _cbca_before),
    ("SGM", _sgm),
    ("CBCA after SGM", _cbca_after),
    ("per-pixel limits", _limits),
    ("WTA", _wta),
    ("right view + WTA", _right_view),
    ("left-right check + filling", _lr_fill),
    ("confidence", _confidence),
    ("sub-pixel", _subpixel),
    ("median", _median),
    ("bilateral", _bilateral),
]

#: state entries :func:`run` returns when asked to keep every intermediate result
KEPT = ("cost", "cost_cbca", "cost_sgm", "cost_final", "disp_wta", "disp_right", "labels",
        "disp_filled", "disp_subpixel", "disp_median", "confidence", "disparity")


def initial_state(vol: CostVolume, right_offset, left, right, limits=None) -> dict:
    if right_offset is None:
        right_offset = jnp.zeros(vol.shape, jnp.int32)
    return {"vol": vol, "cost": vol, "right_offset": right_offset, "left": left, "right": right,
            "limits": limits}


def run(vol: CostVolume, right_offset, left, right, config, keep: bool = False, limits=None) -> dict:
    """Every stage of :data:`STAGES` on the left-view volume; returns ``disparity``,
    ``confidence`` and ``disp_wta`` (``keep``: every entry of :data:`KEPT`, volumes as
    CostVolumes). ``limits``: per-pixel disparity limits ``i32[2, H, W]`` (MIN <= d < MAX, in
    the chain's disparities), or None."""
    st = initial_state(vol, right_offset, left, right, limits)
    for _, stage in STAGES:
        st = stage(st, config)
    names = KEPT if keep else ("disp_wta", "confidence", "disparity")
    return {k: st[k] for k in names if k in st}
