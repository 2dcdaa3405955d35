"""stereojax.optimization.semi_global: SGM against its numpy reference, on full volumes and on per-pixel bands."""

import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.config import SGMConfig
from stereojax.optimization.semi_global import sgm, sgm_volume
from stereojax.volume import CostVolume

from .. import reference as ref
from ..band_reference import D, _band, _case, ref_sgm_band
from ..helpers import random_pair


@pytest.fixture
def pair():
    return random_pair()


@pytest.mark.parametrize("directions", [4, 8])
@pytest.mark.parametrize("adaptive", [False, True])
def test_sgm_matches_reference(pair, directions, adaptive):
    left, right = pair
    rng = np.random.default_rng(3)
    vol = rng.random((9, 14, 5)).astype(np.float32)
    cfg = SGMConfig(directions=directions, p1=0.1, p2=0.4, adaptive=adaptive, q1=2.0, q2=4.0,
                    grad_threshold=60.0, vertical_factor=1.5)
    got = np.asarray(sgm(jnp.asarray(vol), jnp.asarray(left), jnp.asarray(right), cfg))
    want = ref.sgm(vol, left, right, directions, 0.1, 0.4, adaptive, 2.0, 4.0, 60.0, 1.5)
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_sgm_with_zero_penalties_is_the_cost(pair):
    left, right = pair
    vol = np.random.default_rng(4).random((9, 14, 5)).astype(np.float32)
    cfg = SGMConfig(p1=0.0, p2=0.0, adaptive=False)
    got = np.asarray(sgm(jnp.asarray(vol), jnp.asarray(left), jnp.asarray(right), cfg))
    # with zero penalties L_r = C + min - min, so every path returns C itself
    np.testing.assert_allclose(got, vol, atol=1e-6)


@pytest.mark.parametrize("directions,adaptive", [(4, False), (8, False), (4, True)])
def test_sgm_band_matches_reference(directions, adaptive):
    k = 4
    full, off, grey, right = _case(3, k)
    cfg = SGMConfig(directions=directions, p1=0.1, p2=0.5, adaptive=adaptive, q1=2.0, q2=4.0,
                    grad_threshold=60.0)
    vol = CostVolume.band(jnp.asarray(_band(full, off, k)), jnp.asarray(off), D)
    got = np.asarray(sgm_volume(vol, jnp.asarray(grey), jnp.asarray(right), cfg).cost)
    kw = dict(adaptive=True, q1=2.0, q2=4.0, thr=60.0) if adaptive else {}
    want = ref_sgm_band(_band(full, off, k), off, D, grey, right, directions, 0.1, 0.5, **kw)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4)
