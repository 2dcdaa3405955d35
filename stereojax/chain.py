"""The method's chain, written once: bands -> tower -> candidates -> matching cost -> cross arms
-> CBCA -> SGM -> CBCA -> WTA -> right view and left-right check -> filling -> confidence ->
sub-pixel -> median -> bilateral.

Between stages passes one frozen :class:`State` (a pytree), whose fields say what each stage
reads and writes. A stage is ``State -> State`` (with the chain's static config);
:data:`STAGES` lists them in order, the one place where the order is written, and :func:`run`
runs any sub-list of it. The coarse pass that sets the bands (:data:`COARSE`) and the census
chain that ranks the learned head's candidates (:data:`CANDIDATE`) are sub-lists of the same
stages, run by the same :func:`run` on a config of their own (:func:`stereojax.matching_cost.coarse.coarse_config`,
:func:`stereojax.matching_cost.learned.candidate_config`). ``stereojax bench`` times :data:`STAGES` one
stage at a time.

What several stages share is computed once per frame and carried: the cross arms of the left
image at full resolution (the candidate chain's serve the final chain), the bands (the coarse
pass runs once for both views), the tower features. A stage that has nothing to do for a config
(no bands, a classical cost, a disabled check) returns the state unchanged.

This module is the only one that knows the methods: :func:`model_args` checks a model against
the cost method, and :func:`split` says where a method's chain is cut into two compiled programs
(:func:`first_program`, :func:`second_program`; the pruned learned cost, for its peak memory).
The inference code (:mod:`stereojax.inference.predictor`) compiles what this module gives it without naming
a method.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from stereojax.aggregation import cross_based as aggregation
from stereojax.aggregation.cross_based import Arms
from stereojax.config import CostConfig, StereoConfig
from stereojax.disparity import right_view, winner_takes_all
from stereojax.errors import ConfigError
from stereojax.filters import bilateral, median
from stereojax.matching_cost import cascade as cascade_mod, classical as cost_mod, coarse
from stereojax.matching_cost.learned import LearnedModel, candidate_config, learned_volume, rank, tower_features
from stereojax.models.nets import NetConfig
from stereojax.optimization.semi_global import sgm, sgm_volume
from stereojax.refinement import parabola
from stereojax.validation import confidence_measure, filling, left_right
from stereojax.volume import BIG, CostVolume, real_pixels

# ---- the state ------------------------------------------------------------------------------

@dataclass(frozen=True)
class State:
    """What passes between the stages of one frame (every image ``[H, W]``, padded to its size
    bucket on the right and bottom). None: not made (yet, or not by this config).

    Inputs: ``left``, ``right`` grey ``f32[H, W]``; ``valid`` ``i32[2]`` the real (rows, columns)
    or None (nothing padded); ``limits`` ``i32[2, H, W]`` per-pixel disparity limits
    (MIN <= d < MAX) or None; ``variables`` the network's variables and ``net`` its static
    NetConfig (learned cost only).

    Made by the stages, in order: ``offset`` / ``right_offset`` ``i32[H, W]`` the first disparity
    of each pixel's band in the left / right view (None: full range); ``features`` the tower
    features ``(f32[H, W, F], f32[H, W, F])``; ``ranked`` ``i32[H, W, K2]`` the candidate chain's
    disparities, best first; ``arms`` the left image's cross arms; ``vol`` the left view's
    :class:`CostVolume` (each stage replaces it, so the previous one can be freed);
    ``right_vol`` ``f32[H, W, D]`` the right view's own matching cost (only where the right view
    is aggregated on its own, ``refine.right_from_left`` off); ``disp_wta`` ``i32[H, W]`` the WTA
    disparity; ``disp_right`` ``i32[H, W]`` the right view's; ``labels`` ``i32[H, W]`` of the
    left-right check; ``disp`` ``f32[H, W]`` the disparity so far; ``confidence`` ``f32[H, W]``;
    ``disparity`` ``f32[H, W]`` the result.
    """

    left: jax.Array
    right: jax.Array
    valid: jax.Array | None = None
    limits: jax.Array | None = None
    variables: Any = None
    offset: jax.Array | None = None
    right_offset: jax.Array | None = None
    features: tuple | None = None
    ranked: jax.Array | None = None
    arms: Arms | None = None
    vol: CostVolume | None = None
    right_vol: jax.Array | None = None
    disp_wta: jax.Array | None = None
    disp_right: jax.Array | None = None
    labels: jax.Array | None = None
    disp: jax.Array | None = None
    confidence: jax.Array | None = None
    disparity: jax.Array | None = None
    net: Any = None

    def replace(self, **changes) -> "State":
        return dataclasses.replace(self, **changes)

    def real_mask(self):
        """``bool[H, W]`` real pixels, or None when nothing is padded."""
        return real_pixels(self.left.shape, self.valid)


#: the State's array fields (``net`` is static)
FIELDS = tuple(f.name for f in dataclasses.fields(State) if f.name != "net")
jax.tree_util.register_dataclass(State, data_fields=list(FIELDS), meta_fields=["net"])


class Stage(NamedTuple):
    """One stage: its name (in ``bench`` and the docs), ``fn(state, config) -> state``, and
    ``keep``: (key, field) pairs, the keys under which :func:`stereojax.inference.predictor.stages` keeps
    the fields this stage makes."""

    name: str
    fn: Callable
    keep: tuple = ()


# ---- front: bands, tower, candidates, matching cost -----------------------------------------

def limit_bands(offsets, limits, config):
    """Band offsets moved by per-pixel disparity limits ``i32[2, H, W]`` (MIN <= d < MAX in the
    chain's disparities; None: unchanged), each by as little as it takes: where the limits are at
    least K wide the band moves inside them, where they are narrower it moves to hold them whole.
    A band that already holds the allowed range stays where the coarse pass put it, so limits
    around the chain's own answer change none of the costs that SGM aggregates."""
    if offsets is None or limits is None:
        return offsets
    k = config.band.width
    lo, hi = limits[0], limits[1]
    off = jnp.clip(offsets, jnp.minimum(lo, hi - k), jnp.maximum(lo, hi - k))
    return jnp.clip(off, 0, config.max_disp - k)


def bands(left: jax.Array, right: jax.Array, config, valid=None):
    """(left offsets, right offsets) ``i32[H, W]`` of a banded config: :data:`COARSE` run on the
    pair averaged down by ``band.scale``, then :func:`stereojax.matching_cost.coarse.band_offsets`; (None,
    None) for the full range."""
    if not config.banded:
        return None, None
    s = config.band.scale
    vs = None if valid is None else -(-valid // s)
    st = State(coarse.downsample(left, s), coarse.downsample(right, s), vs)
    st = run(COARSE, st, coarse.coarse_config(config))
    return coarse.offsets_from(st.disp_wta, st.disp_right, config, left.shape)


def _bands(st: State, config) -> State:
    if not config.banded or st.offset is not None:     # given (a stream's prior): no coarse pass
        return st
    off_l, off_r = bands(st.left, st.right, config, st.valid)
    return st.replace(offset=limit_bands(off_l, st.limits, config), right_offset=off_r)


def _tower(st: State, config) -> State:
    if config.cost.method != "learned":
        return st

    feats = tower_features(st.net, st.variables, st.left, st.right, st.valid)
    return st.replace(features=jax.lax.optimization_barrier(feats))


def pruned(config, net) -> bool:
    """Whether the learned head runs at the candidate chain's candidates (pruned mode)."""
    return config.cost.method == "learned" and config.cost.candidates > 0 and net is not None \
        and net.head != "cosine"


def _candidates(st: State, config) -> State:
    if not pruned(config, st.net):
        return st

    sub = run(CANDIDATE, st, candidate_config(config))
    return st.replace(ranked=rank(sub.vol, config), arms=sub.arms)


def _matching_cost(st: State, config) -> State:
    """The left view's volume of the config's cost method in the bands (``st.offset``)."""
    if config.cost.method == "learned":
        vol = learned_volume(st.net, st.variables, st.features, st.ranked, config, st.offset, st.valid)
        right_vol = None
        if config.refine.lr_check and not config.refine.right_from_left:
            # the network's right-view cost is exactly the skewed left one: C_R(x, d) = C_L(x + d, d)
            right_vol = right_view.right_cost_from_left(vol.cost, cost_mod.INVALID_COST,
                                                    None if st.valid is None else st.valid[1])
        return st.replace(vol=vol, right_vol=right_vol, features=None, ranked=None)
    if st.offset is None:
        vol = CostVolume.full(cost_mod.matching_cost(st.left, st.right, config.max_disp, config.cost, "left",
                                                     config.kernels), st.valid)
    else:
        vol = cost_mod.band_cost(st.left, st.right, st.offset, config.band.width, config.max_disp, config.cost,
                                 st.valid, config.kernels)
    return st.replace(vol=vol)


# ---- the stages after the matching cost -----------------------------------------------------

def _arms(st: State, config) -> State:
    if st.arms is not None:     # made by the candidate chain, with the same tau and arm length
        return st
    return st.replace(arms=aggregation.cross_arms(st.left, config.cbca.tau, config.cbca.arm_length, st.real_mask()))


def _neutral(st: State, config) -> State:
    if config.cost.border != "neutral":
        return st
    return st.replace(vol=cost_mod.neutral_border_volume(st.vol))


def _cbca(st: State, config, iterations: int) -> State:
    if iterations == 0:
        return st
    return st.replace(vol=aggregation.cbca_volume(st.vol, st.arms, iterations, config.cbca.arm_length,
                                                  config.kernels))


def _cbca_before(st: State, config) -> State:
    return _cbca(st, config, config.cbca.iterations_before)


def _sgm(st: State, config) -> State:
    if config.sgm.directions == 0:
        return st
    return st.replace(vol=sgm_volume(st.vol, st.left, st.right, config.sgm, config.kernels))


def _cbca_after(st: State, config) -> State:
    return _cbca(st, config, config.cbca.iterations_after)


def _limits(st: State, config) -> State:
    """Per-pixel disparity limits (``st.limits``, MIN <= d < MAX; None: none): every entry
    outside them costs :data:`~stereojax.volume.BIG`, so WTA, the right view, the confidence and
    the sub-pixel fit choose inside them."""
    if st.limits is None:
        return st
    vol = st.vol
    d = vol.disparities() if vol.banded else jnp.arange(vol.k, dtype=jnp.int32)[None, None, :]
    inside = (d >= st.limits[0][..., None]) & (d < st.limits[1][..., None])
    return st.replace(vol=vol.with_cost(jnp.where(inside, vol.cost, BIG)))


def _wta(st: State, config) -> State:
    disp_wta = winner_takes_all.wta_volume(st.vol, config.kernels)
    return st.replace(disp_wta=disp_wta, disp=disp_wta.astype(jnp.float32))


def _right_view(st: State, config) -> State:
    if not config.refine.lr_check:
        return st
    if config.refine.right_from_left:
        right_offset = st.right_offset
        if right_offset is None:
            right_offset = jnp.zeros(st.vol.shape, jnp.int32)
        return st.replace(disp_right=right_view.right_wta(st.vol, right_offset, cost_mod.INVALID_COST,
                                                          config.kernels))
    # full range only (config.validate): the right view aggregated on its own
    return st.replace(disp_right=winner_takes_all.wta(_right_chain(st, config)), right_vol=None)


def _right_chain(st: State, config):
    """CBCA -> SGM -> CBCA of the right view's own full volume (``refine.right_from_left`` off)."""
    left, right, valid = st.left, st.right, st.valid
    vol_r = st.right_vol
    if vol_r is None:
        vol_r = cost_mod.matching_cost(left, right, config.max_disp, config.cost, "right", config.kernels)
    w = left.shape[1]
    arms = aggregation.cross_arms(right, config.cbca.tau, config.cbca.arm_length, real_pixels(right.shape, valid))
    c1 = aggregation.cbca(vol_r, arms, config.cbca.iterations_before, config.cbca.arm_length, config.kernels)
    # mirrored (x -> W - 1 - x turns "match at x + d" into "match at x' - d"), padding on the left
    real = None if valid is None else (0, valid[0], w - valid[1], w)
    c2 = sgm(c1[:, ::-1], right[:, ::-1], left[:, ::-1], config.sgm, real, config.kernels)[:, ::-1]
    return aggregation.cbca(c2, arms, config.cbca.iterations_after, config.cbca.arm_length, config.kernels)


def _lr_fill(st: State, config) -> State:
    if not config.refine.lr_check:
        return st
    labels = left_right.lr_check(st.disp, st.disp_right.astype(jnp.float32), config.max_disp,
                             config.refine.lr_tolerance)
    mask = st.real_mask()
    if mask is not None:    # padding never serves as a source of the filling
        labels = jnp.where(mask, labels, left_right.MISMATCH)
    return st.replace(labels=labels, disp=filling.fill_disparity(st.disp, labels, config.kernels))


def _confidence(st: State, config) -> State:
    return st.replace(confidence=confidence_measure.confidence_volume(st.vol, st.disp_wta, st.disp_right,
                                                                      config.refine.lr_tolerance, config.kernels))


def _texture(st: State, config) -> State:
    r = config.refine
    if r.texture_full <= 0 or st.confidence is None:
        return st
    factor = confidence_measure.texture_factor(st.left, config.cost.census_radius, r.texture_noise, r.texture_full)
    return st.replace(confidence=st.confidence * factor)


def _subpixel(st: State, config) -> State:
    if not config.refine.subpixel:
        return st
    return st.replace(disp=parabola.subpixel_volume(st.vol, st.disp))


def _median(st: State, config) -> State:
    return st.replace(disp=median.median_filter(st.disp, config.refine.median_size, config.kernels))


def _bilateral(st: State, config) -> State:
    r = config.refine
    disp = bilateral.bilateral_filter(st.disp, st.left, r.bilateral_radius, r.bilateral_sigma_space,
                                   r.bilateral_sigma_range)
    disp = jnp.clip(disp, 0.0, float(config.max_disp - 1))
    if st.limits is not None:          # the filling and the filters never leave a pixel's limits
        disp = jnp.clip(disp, st.limits[0].astype(jnp.float32), (st.limits[1] - 1).astype(jnp.float32))
    return st.replace(disparity=disp)


#: the chain, in order: the one place where the order is written
STAGES: list[Stage] = [
    Stage("coarse pass (bands)", _bands),
    Stage("tower features", _tower),
    Stage("candidate chain", _candidates),
    Stage("matching cost", _matching_cost, (("cost", "vol"),)),
    Stage("cross arms", _arms),
    Stage("neutral out-of-view strip", _neutral),
    Stage("CBCA before SGM", _cbca_before, (("cost_cbca", "vol"),)),
    Stage("SGM", _sgm, (("cost_sgm", "vol"),)),
    Stage("CBCA after SGM", _cbca_after, (("cost_final", "vol"),)),
    Stage("per-pixel limits", _limits),
    Stage("WTA", _wta, (("disp_wta", "disp_wta"),)),
    Stage("right view + WTA", _right_view, (("disp_right", "disp_right"),)),
    Stage("left-right check + filling", _lr_fill, (("labels", "labels"), ("disp_filled", "disp"))),
    Stage("confidence", _confidence, (("confidence", "confidence"),)),
    Stage("confidence texture", _texture, (("confidence_texture", "confidence"),)),
    Stage("sub-pixel", _subpixel, (("disp_subpixel", "disp"),)),
    Stage("median", _median, (("disp_median", "disp"),)),
    Stage("bilateral", _bilateral, (("disparity", "disparity"),)),
]


def stages_named(names) -> list[Stage]:
    """The stages of :data:`STAGES` with these names, in the chain's order (a sub-chain)."""
    unknown = set(names) - {s.name for s in STAGES}
    if unknown:
        raise KeyError(f"no stage named {sorted(unknown)}")
    return [s for s in STAGES if s.name in names]


def _index(name: str) -> int:
    return [s.name for s in STAGES].index(name)


# The sub-chains, by the names of their stages; :func:`run` looks them up in :data:`STAGES` when
# it runs, so the functions and their order come from that one list.
#: the front of the chain: everything up to and including the matching cost
FRONT = tuple(s.name for s in STAGES[:_index("matching cost") + 1])
#: everything after the matching cost
BACK = tuple(s.name for s in STAGES[_index("matching cost") + 1:])
#: the coarse pass (:func:`bands`): census over the full range, CBCA, SGM, both views' WTA
COARSE = ("matching cost", "cross arms", "CBCA before SGM", "SGM", "WTA", "right view + WTA")
#: the census chain that ranks the learned head's candidates (:func:`_candidates`)
CANDIDATE = ("matching cost", "cross arms", "CBCA before SGM", "SGM")


def run(stages, st: State, config, kept: dict | None = None) -> State:
    """Run ``stages`` (the names of a sub-list of :data:`STAGES`, or the list itself) on ``st``,
    in the chain's order. ``kept``: a dict that receives what each stage's :attr:`Stage.keep`
    names, where it exists (volumes as CostVolumes); None keeps nothing, so every volume is free
    once the next one exists."""
    names = [s if isinstance(s, str) else s.name for s in stages]
    for stage in stages_named(names):
        st = stage.fn(st, config)
        if kept is not None:
            kept.update({key: getattr(st, f) for key, f in stage.keep if getattr(st, f) is not None})
    return st


# ---- the method's models and its programs ---------------------------------------------------

def model_args(config, model):
    """(variables, net) for the jitted chain, checking ``model`` against the cost method: a
    :class:`~stereojax.matching_cost.learned.LearnedModel` for the learned cost, None for the classical ones."""

    if config.cost.method == "learned":
        if not isinstance(model, LearnedModel):
            raise ConfigError("cost method 'learned' needs params=LearnedModel (e.g. "
                              "stereojax.load_model('weights.msgpack')), got "
                              f"{type(model).__name__}")
        return model.variables, model.net
    if model is not None:
        raise ConfigError(f"cost method {config.cost.method!r} is classical and takes no network "
                          "parameters; pass params=None")
    return None, None


def initial(left, right, valid=None, limits=None, variables=None, net=None, bands=None) -> State:
    """The state a frame starts with; ``bands``: (left, right) band offsets ``i32[H, W]`` given
    instead of the coarse pass's (a banded config only)."""
    offset, right_offset = (None, None) if bands is None else bands
    return State(left, right, valid, limits, variables, offset=offset, right_offset=right_offset, net=net)


def split(config, net) -> int | None:
    """Where the chain is cut into two compiled programs (an index into :data:`STAGES`), or
    None for one program. The pruned learned cost is cut after its candidate chain, so that the
    candidate chain's volumes are gone before the learned volume exists and the peak memory is
    that of the larger half (measured on a KITTI frame: 3.2 GiB peak RSS instead of 4.3 as one
    program)."""
    return _index("candidate chain") + 1 if pruned(config, net) else None


def two_programs(config, net) -> bool:
    """Whether the chain runs as two compiled programs (:func:`split`)."""
    return split(config, net) is not None


def front(left, right, config, variables=None, net=None, valid=None, limits=None) -> State:
    """The state after :data:`FRONT` (bands, tower, candidates, matching cost) in one program."""
    return run(FRONT, initial(left, right, valid, limits, variables, net), config)


@functools.partial(jax.jit, static_argnames=("config", "net"))
def first_program(left, right, valid, config, variables=None, net=None, limits=None, bands=None) -> State:
    """First program of a two-program chain: :data:`STAGES` up to :func:`split` (the bands, the
    tower features of both views and the ranked candidates); the state without the variables."""
    st = run(STAGES[:split(config, net)], initial(left, right, valid, limits, variables, net, bands), config)
    return st.replace(variables=None)


def second_front(carry: State, config, variables=None) -> State:
    """The rest of :data:`FRONT` after :func:`first_program` (the head at the candidates)."""
    return run(FRONT[split(config, carry.net):], carry.replace(variables=variables), config)


@functools.partial(jax.jit, static_argnames=("config", "confidence"))
def second_program(carry: State, config, variables=None, confidence: bool = False):
    """Second program of a two-program chain: the stages of :data:`STAGES` after :func:`split`
    on :func:`first_program`'s state; the disparity (and confidence)."""
    st = run(STAGES[split(config, carry.net):], carry.replace(variables=variables), config)
    return result(st, confidence)


# ---- the cascade: the student everywhere, the full network where the student is unsure ------

#: the stages the cascade's student runs after its matching cost: up to its confidence map
CASCADE_STUDENT = tuple(s.name for s in STAGES[_index("matching cost") + 1:_index("confidence") + 1])


@functools.partial(jax.jit, static_argnames=("config",))
def cascade_student(carry: State, config, variables=None):
    """The cascade's second program (after :func:`first_program` of the student): the student's
    matching cost, and its chain up to the confidence; (the student's volume, its confidence)."""
    st = run(FRONT[split(config, carry.net):], carry.replace(variables=variables), config)
    vol = st.vol
    return vol, run(CASCADE_STUDENT, st, config).confidence


@functools.partial(jax.jit, static_argnames=("config", "cascade", "confidence"))
def cascade_second(carry: State, vol: CostVolume, conf, config, cascade, full_variables, confidence: bool = False):
    """The cascade's third program: the full network's cost at the ``cascade.share`` least
    confident pixels replaces the student's there (:mod:`stereojax.matching_cost.cascade`), and
    the chain after the matching cost (:data:`BACK`) runs once on the mixed volume."""
    ys, xs, used = cascade_mod.unsure_pixels(conf, cascade.share, carry.valid)
    cost, cand = cascade_mod.full_cost_rows(cascade.net, full_variables, carry.left, carry.right, carry.ranked,
                                            ys, xs, cascade.candidates, carry.valid)
    mixed = cascade_mod.mixed_volume(vol, ys, xs, used, cand, cost)
    st = carry.replace(vol=mixed, features=None, ranked=None, variables=None)
    return result(run(BACK, st, config), confidence)


def result(st: State, confidence: bool):
    """The disparity of a finished state, or (disparity, confidence) when asked for."""
    return (st.disparity, st.confidence) if confidence else st.disparity


# ---- the learned cost volume of a pair, for previews and tests -----------------------------

@functools.partial(jax.jit, static_argnames=("net", "max_disp", "rows_per_tile", "candidates"))
def learned_cost(net: NetConfig, variables, left: jax.Array, right: jax.Array, max_disp: int,
                 rows_per_tile: int = 32, candidates: int = 0) -> jax.Array:
    """Left-view cost volume ``f32[H, W, D]`` of grey images (0..255) ``f32[H, W]``.

    candidates: 0 = exact (every disparity through the head); K > 0 = pruned mode, the dense
    head only on the K best disparities of the census chain of the default settings. The
    chain itself runs :data:`FRONT`, which takes every setting from its config.
    """
    cfg = StereoConfig(max_disp=max_disp, cost=CostConfig(method="learned", rows_per_tile=rows_per_tile,
                                                          candidates=candidates))
    return front(left, right, cfg, variables, net).vol.cost


__all__ = ["State", "Stage", "STAGES", "FRONT", "BACK", "COARSE", "CANDIDATE", "run", "bands", "front",
           "split", "first_program", "second_program", "model_args", "limit_bands", "learned_cost"]
