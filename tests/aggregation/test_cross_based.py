"""stereojax.aggregation.cross_based: the cross arms and the cross-based aggregation against their numpy
references, on full volumes and on per-pixel bands."""

import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.aggregation import cross_based as aggregation
from stereojax.volume import CostVolume

from .. import reference as ref
from ..band_reference import D, _arms, _band, _case, ref_cbca_band


@pytest.fixture
def smooth_grey():
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, (4, 5)).astype(np.float32)
    return np.kron(base, np.ones((3, 3), np.float32)) + rng.normal(0, 3, (12, 15)).astype(np.float32)


def test_cross_arms_match_reference(smooth_grey):
    arms = aggregation.cross_arms(jnp.asarray(smooth_grey), 20.0, 3)
    np.testing.assert_array_equal(np.stack([np.asarray(a) for a in arms]), ref.cross_arms(smooth_grey, 20.0, 3))


@pytest.mark.parametrize("max_arm", [0, 3])   # 0: integral images, 3: shifted sums
def test_cbca_matches_reference(smooth_grey, max_arm):
    rng = np.random.default_rng(2)
    vol = rng.random((12, 15, 4)).astype(np.float32)
    arms = aggregation.cross_arms(jnp.asarray(smooth_grey), 20.0, 3)
    got = np.asarray(aggregation.cbca(jnp.asarray(vol), arms, 2, max_arm))
    want = ref.cbca(vol, [np.asarray(a) for a in arms], 2)
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_cbca_of_constant_volume_is_constant(smooth_grey):
    arms = aggregation.cross_arms(jnp.asarray(smooth_grey), 20.0, 3)
    vol = jnp.full((12, 15, 3), 0.25, jnp.float32)
    np.testing.assert_allclose(np.asarray(aggregation.cbca(vol, arms, 3, 3)), 0.25, atol=1e-6)


@pytest.mark.parametrize("seed,k", [(0, 3), (1, 5)])
def test_cbca_band_matches_reference(seed, k):
    full, off, grey, _ = _case(seed, k)
    arms = _arms(grey)
    vol = CostVolume.band(jnp.asarray(_band(full, off, k)), jnp.asarray(off), D)
    got = np.asarray(aggregation.cbca_volume(vol, arms, 2, 3).cost)
    want = ref_cbca_band(_band(full, off, k), off, [np.asarray(a) for a in arms], 2)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
