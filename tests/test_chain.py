"""The chain's order is written once (stereojax.chain.STAGES): the whole chain, its front, its two
programs, the coarse pass, the candidate chain and `stereojax bench` all run that list; the state
between the stages is a typed pytree; the per-pixel limits stage, and the bands it moves."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax import chain
from stereojax.app import bench
from stereojax.inference import programs
from stereojax.matching_cost.learned import LearnedModel
from stereojax.models.nets import NetConfig, init_params
from stereojax.volume import BIG, CostVolume

from .helpers import banded_census as _banded, shifted_pair


@pytest.fixture
def logged(monkeypatch):
    """STAGES with every function wrapped to log its stage's name and the config's cost method."""
    log = []

    def wrap(stage):
        def fn(st, config):
            log.append((stage.name, config.cost.method))
            return stage.fn(st, config)
        return stage._replace(fn=fn)

    monkeypatch.setattr(chain, "STAGES", [wrap(s) for s in chain.STAGES])
    return log


def _names(log, method=None):
    return [name for name, m in log if method is None or m == method]


def _tiny_learned():
    net = NetConfig(features=4, widths=(8, 4))
    cfg = stereojax.StereoConfig(max_disp=16, cost=stereojax.CostConfig(method="learned", candidates=3,
                                                                         rows_per_tile=8),
                                 band=stereojax.config.BandConfig(width=8, scale=2, radius=1, unsure_radius=2,
                                                                  margin=2))
    return cfg.validate(), LearnedModel(net, init_params(net, jax.random.PRNGKey(0)))


def test_the_order_is_written_once():
    names = [s.name for s in chain.STAGES]
    assert len(set(names)) == len(names)
    assert list(chain.FRONT) + list(chain.BACK) == names
    for sub in (chain.COARSE, chain.CANDIDATE):      # sub-lists, in the chain's order
        assert [n for n in names if n in sub] == list(sub)
    with pytest.raises(KeyError):
        chain.stages_named(["no such stage"])


def test_run_and_the_front_follow_stages(logged):
    """A banded census chain runs the coarse pass (census) inside the first stage, then every
    stage of STAGES in order; the front stops after the matching cost."""
    left, right = (a.astype(np.float32) for a in shifted_pair(3, h=32, w=64))
    cfg = stereojax.preset("census", 16)
    cfg = dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=8))
    st = jax.eval_shape(lambda a, b: programs._chain(a, b, cfg), left, right)     # traced, not compiled
    assert isinstance(st, chain.State) and st.disparity.shape == left.shape
    top = [s.name for s in chain.STAGES]
    inner = _names(logged)
    coarse = inner[1:1 + len(chain.COARSE)]
    assert inner[0] == "coarse pass (bands)" and coarse == list(chain.COARSE)
    assert inner[1 + len(chain.COARSE):] == top[1:]
    logged.clear()
    st = jax.eval_shape(lambda a, b: chain.front(a, b, cfg), left, right)
    assert _names(logged)[1 + len(chain.COARSE):] == list(chain.FRONT[1:]) and st.disparity is None


def test_two_programs_together_run_stages_once(logged):
    """The learned chain's two programs: the first ends after the candidate chain (which runs the
    census stages of CANDIDATE), the second runs the rest; together every stage once, in order."""
    cfg, model = _tiny_learned()
    assert chain.two_programs(cfg, model.net)
    left, right = (a.astype(np.float32) for a in shifted_pair(3, h=32, w=64))
    valid = np.array(left.shape, np.int32)
    net = model.net
    carry = jax.eval_shape(lambda a, b, v, w: chain.first_program.__wrapped__(a, b, v, cfg, w, net),
                           left, right, valid, model.variables)
    first = _names(logged, "learned")
    assert carry.ranked is not None and carry.vol is None and carry.variables is None
    assert _names(logged, "census")[-len(chain.CANDIDATE):] == list(chain.CANDIDATE)
    jax.eval_shape(lambda c, w: chain.second_program.__wrapped__(c, cfg, w), carry, model.variables)
    top = [s.name for s in chain.STAGES]
    assert first == top[:chain.split(cfg, net)]
    assert _names(logged, "learned") == top
    # and the two compiled programs give the one-program chain's disparity
    disp = chain.second_program(chain.first_program(left, right, valid, cfg, model.variables, net), cfg,
                                model.variables)
    whole = stereojax.disparity(left, right, cfg, params=model, bucket=False)
    np.testing.assert_allclose(np.asarray(disp), whole, atol=1e-5)


def test_the_candidate_chains_arms_serve_the_chain():
    """The cross arms are made once per frame: the candidate chain's are the chain's."""
    cfg, model = _tiny_learned()
    left, right = (a.astype(np.float32) for a in shifted_pair(3, h=32, w=64))
    st = jax.jit(lambda a, b, v: chain.run(chain.FRONT, chain.initial(a, b, variables=v, net=model.net), cfg))(
        left, right, model.variables)
    assert st.arms is not None
    again = chain.run(("cross arms",), st, cfg)
    assert again.arms is st.arms
    fresh = jax.jit(lambda s: chain.run(("cross arms",), s, cfg))(st.replace(arms=None))
    for a, b in zip(fresh.arms, st.arms):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_bench_times_the_stages_list(logged):
    """`stereojax bench`'s stage profile is STAGES itself: one row per stage that does something,
    in the chain's order."""
    left, right = shifted_pair(3, h=32, w=64)
    cfg = stereojax.preset("census", 16)
    cfg = dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=8))
    rows = bench.stage_timings(left, right, cfg, repeats=1)
    names = [s.name for s in chain.STAGES]
    assert list(rows) == [n for n in names if n in rows]
    assert {"coarse pass (bands)", "matching cost", "CBCA before SGM", "SGM", "WTA"} <= set(rows)
    assert "tower features" not in rows and "candidate chain" not in rows     # nothing to do for census
    assert rows["SGM"]["entries"] == 32 * 64 * 8
    assert set(_names(logged)) >= set(rows)


def test_the_state_is_a_frozen_pytree():
    left, right = (a.astype(np.float32) for a in shifted_pair(3, h=32, w=64))
    st = chain.initial(left, right)
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.left = right
    leaves = jax.tree_util.tree_leaves(st)
    assert len(leaves) == 2            # the two images; the empty fields are no leaves
    out = jax.jit(lambda s: chain.run(chain.STAGES, s, stereojax.preset("census", 16)))(st)
    assert isinstance(out, chain.State) and out.vol is not None and out.disparity.shape == left.shape


def test_the_limits_stage_against_numpy():
    """Entries outside a pixel's limits cost BIG, the others are untouched (full range
    and bands)."""
    rng = np.random.default_rng(0)
    h, w, d, k = 5, 7, 12, 4
    lo = rng.integers(0, 8, (h, w)).astype(np.int32)
    hi = (lo + rng.integers(1, 5, (h, w))).astype(np.int32)
    lim = jnp.asarray(np.stack([lo, hi]))
    full = rng.random((h, w, d)).astype(np.float32)
    got = chain._limits(chain.State(None, None, limits=lim, vol=CostVolume.full(jnp.asarray(full))), None).vol.cost
    disp = np.arange(d)[None, None, :]
    want = np.where((disp >= lo[..., None]) & (disp < hi[..., None]), full, BIG)
    np.testing.assert_array_equal(np.asarray(got), want)
    off = rng.integers(0, d - k + 1, (h, w)).astype(np.int32)
    band = rng.random((h, w, k)).astype(np.float32)
    vol = CostVolume.band(jnp.asarray(band), jnp.asarray(off), d)
    got = chain._limits(chain.State(None, None, limits=lim, vol=vol), None).vol.cost
    disp = off[..., None] + np.arange(k)
    want = np.where((disp >= lo[..., None]) & (disp < hi[..., None]), band, BIG)
    np.testing.assert_array_equal(np.asarray(got), want)


def test_bands_move_inside_the_limits():
    """A band moves by as little as it takes: inside limits K wide or wider, around narrower
    ones (a band that already holds them stays); always inside 0 .. D - K."""
    cfg = _banded(64, 16)
    rng = np.random.default_rng(1)
    off = rng.integers(0, 49, (6, 9)).astype(np.int32)
    lo = rng.integers(0, 60, (6, 9)).astype(np.int32)
    hi = np.minimum(lo + rng.integers(1, 40, (6, 9)), 64).astype(np.int32)
    got = np.asarray(chain.limit_bands(jnp.asarray(off), jnp.asarray(np.stack([lo, hi])), cfg))
    want = off.copy()
    for i, j in np.ndindex(off.shape):                  # the nearest start whose band fits or holds
        starts = [s for s in range(0, 49) if (lo[i, j] <= s and s + 16 <= hi[i, j]) or
                  (s <= lo[i, j] and hi[i, j] <= s + 16)]
        if starts:
            want[i, j] = min(starts, key=lambda s: abs(s - off[i, j]))
        else:                                            # limits reach past 0 .. D - K: its nearest end
            want[i, j] = np.clip(off[i, j], 0, 48)
    np.testing.assert_array_equal(got, want)
    wide = hi - lo >= 16
    assert np.all(got[wide] >= lo[wide]) and np.all(got[wide] + 16 <= hi[wide])
    narrow = ~wide & (hi <= 64)
    assert np.all(got[narrow] <= lo[narrow]) and np.all(got[narrow] + 16 >= hi[narrow])
    holds = (off <= lo) & (hi <= off + 16)
    np.testing.assert_array_equal(got[holds], off[holds])        # already holding them: unmoved
