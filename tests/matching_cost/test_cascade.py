"""The cascade (stereojax.matching_cost.cascade): which pixels are re-scored, how their rows are
replaced, and the chain around it."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax.errors import ConfigError
from stereojax.matching_cost.cascade import Cascade, mixed_volume, unsure_pixels
from stereojax.models.nets import LearnedModel, NetConfig, init_params
from stereojax.volume import CostVolume
from tests.helpers import shifted_pair


def test_unsure_pixels_are_the_least_confident_real_ones():
    rng = np.random.default_rng(0)
    conf = rng.random((6, 10)).astype(np.float32)
    ys, xs, used = unsure_pixels(jnp.asarray(conf), 0.25)
    assert used.all() and len(ys) == 15
    chosen = np.zeros_like(conf, bool)
    chosen[np.asarray(ys), np.asarray(xs)] = True
    assert conf[chosen].max() < conf[~chosen].min()
    # padded to a bucket: padding (even with the lowest confidence) is never chosen, and the share
    # is of the real pixels
    conf[:, 8:] = -1.0
    ys, xs, used = unsure_pixels(jnp.asarray(conf), 0.25, jnp.array([6, 8]))
    n = int(np.asarray(used).sum())
    assert n == 12
    assert (np.asarray(xs)[:n] < 8).all()
    real = conf[:, :8]
    picked = real[np.asarray(ys)[:n], np.asarray(xs)[:n]]
    assert picked.max() <= np.sort(real, axis=None)[n - 1]


def test_mixed_volume_replaces_whole_band_rows():
    h, w, k = 4, 5, 6
    cost = jnp.full((h, w, k), 0.3)
    offset = jnp.full((h, w), 10, jnp.int32)
    vol = CostVolume.band(cost, offset, 64)
    ys, xs = jnp.array([1, 2, 3]), jnp.array([0, 4, 2])
    used = jnp.array([True, True, False])
    cand = jnp.array([[12, 10], [15, 30], [11, 12]])       # 30 is outside the band: dropped
    new = jnp.array([[0.1, 0.2], [0.05, 0.9], [0.0, 0.0]])
    out = np.asarray(mixed_volume(vol, ys, xs, used, cand, new).cost)
    np.testing.assert_allclose(out[1, 0], [0.2, 1, 0.1, 1, 1, 1])
    np.testing.assert_allclose(out[2, 4], [1, 1, 1, 1, 1, 0.05])
    np.testing.assert_allclose(out[3, 2], 0.3)               # not used: unchanged
    untouched = np.ones((h, w), bool)
    untouched[1, 0] = untouched[2, 4] = False
    np.testing.assert_allclose(out[untouched], 0.3)


def _student(seed=0):
    net = NetConfig(features=4, widths=(8, 4))
    cfg = stereojax.StereoConfig(max_disp=16, cost=stereojax.CostConfig(method="learned", candidates=3, rows_per_tile=8),
                                 band=stereojax.config.BandConfig(width=8, scale=2, radius=1, unsure_radius=2, margin=2))
    return cfg.validate(), LearnedModel(net, init_params(net, jax.random.PRNGKey(seed)))


@pytest.fixture(scope="module")
def pair():
    return shifted_pair(5, h=40, w=72, seed=2)


@pytest.mark.slow
def test_the_student_as_its_own_full_network_changes_nothing(pair):
    """Re-scoring every pixel with the student's own network at its own candidates rebuilds the
    student's volume exactly, so the cascade's disparity is the student's; another network as
    the full one changes it."""
    cfg, student = _student()
    left, right = pair
    alone = stereojax.Predictor(cfg, student, confidence=True)(left, right)
    same = stereojax.Predictor(cfg, student, confidence=True, cascade=Cascade(student, 1.0, 3))(left, right)
    np.testing.assert_allclose(same[0], alone[0], atol=1e-4)
    np.testing.assert_allclose(same[1], alone[1], atol=1e-4)
    _, other = _student(seed=7)
    mixed = stereojax.Predictor(cfg, student, cascade=Cascade(other, 1.0, 3))(left, right)
    assert np.abs(mixed - alone[0]).max() > 0.5


@pytest.mark.slow
def test_a_padded_pair_gets_the_unpadded_choice(pair):
    """In a size bucket, the share is of the real pixels and padding is never re-scored: the
    cascade's disparity of a padded pair equals that of the pair compiled for its exact size
    (but within 4 px of the padded edges, where the chain's own filters see the padding)."""
    cfg, student = _student()
    _, full = _student(seed=7)
    left, right = pair
    cascade = Cascade(full, 0.3, 3)
    bucketed = stereojax.Predictor(cfg, student, cascade=cascade)(left[:, :69], right[:, :69])
    from stereojax.inference.programs import CompiledChain
    exact = CompiledChain((40, 69), cfg, student.net, (student.variables, full.variables), cascade=cascade.spec())
    direct = exact(left[:, :69].astype(np.float32), right[:, :69].astype(np.float32),
                   (student.variables, full.variables))
    np.testing.assert_allclose(bucketed[:-4, :-4], direct[:-4, :-4], atol=1e-4)


def test_bad_cascades_are_refused_in_one_line():
    cfg, student = _student()
    with pytest.raises(ConfigError, match="share"):
        stereojax.Predictor(cfg, student, cascade=Cascade(student, 0.0))
    exact = dataclasses.replace(cfg, cost=dataclasses.replace(cfg.cost, candidates=0)).validate()
    with pytest.raises(ConfigError, match="pruned"):
        stereojax.Predictor(exact, student, cascade=Cascade(student, 0.2))


def test_resolve_names_the_cascade_and_its_share():
    from stereojax.models.registry import resolve
    run = resolve("best", width=1242, height=375, dataset="kitti2015", cascade=0.2)
    assert run.chosen_line.startswith("cascade q = 20 %: learned cost, shipped model kitti2015_compact everywhere, "
                                      "shipped model kitti2015 at the 20 % least confident pixels")
    assert run.cascade[1] == 0.2 and run.label == "stereojax cascade kitti2015_compact + kitti2015 at q = 20 %"
    with pytest.raises(ConfigError, match="share"):
        resolve("best", width=1242, height=375, cascade=1.5)
    with pytest.raises(ConfigError, match="--method"):
        resolve("census", cascade=0.2)
