"""stereojax.matching_cost.classical: census and SAD costs against their numpy references (full volume,
right view, bands) and the "neutral" out-of-view border."""

import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.disparity import right_view
from stereojax.matching_cost import classical as cost, classical as cost_mod

from .. import reference as ref
from ..band_reference import D, _band, _case
from ..helpers import random_pair


@pytest.fixture
def pair():
    return random_pair()


@pytest.mark.parametrize("border", ["worst", "replicate"])
def test_census_matches_reference(pair, border):
    left, right = pair
    got = np.asarray(cost.census_cost(jnp.asarray(left), jnp.asarray(right), 5, (1, 2), border=border))
    np.testing.assert_allclose(got, ref.census_cost(left, right, 5, (1, 2), border), atol=1e-6)


def test_census_right_view_is_skewed_left_view(pair):
    left, right = pair
    cl = np.asarray(cost.census_cost(jnp.asarray(left), jnp.asarray(right), 5, (1, 1), "left", "worst"))
    cr = np.asarray(cost.census_cost(jnp.asarray(left), jnp.asarray(right), 5, (1, 1), "right", "worst"))
    np.testing.assert_allclose(cr, np.asarray(right_view.right_cost_from_left(jnp.asarray(cl))), atol=1e-6)


@pytest.mark.parametrize("border", ["worst", "replicate"])
def test_sad_matches_reference(pair, border):
    left, right = pair
    got = np.asarray(cost.sad_cost(jnp.asarray(left), jnp.asarray(right), 4, 1, border=border))
    np.testing.assert_allclose(got, ref.sad_cost(left, right, 4, 1, border), atol=1e-5)


@pytest.mark.parametrize("border", ["replicate", "worst"])
def test_census_band_is_the_full_census_at_the_bands(border):
    k = 4
    _, off, grey, right = _case(6, k)
    full = np.asarray(cost.census_cost(jnp.asarray(grey), jnp.asarray(right), D, (1, 2), border=border))
    got = cost.census_band(jnp.asarray(grey), jnp.asarray(right), jnp.asarray(off), k, D, (1, 2), border)
    np.testing.assert_allclose(np.asarray(got.cost), _band(full, off, k), atol=1e-6)


def test_neutral_border_sets_only_the_out_of_view_entries():
    rng = np.random.default_rng(0)
    vol = rng.random((3, 6, 4)).astype(np.float32)
    out = np.asarray(cost_mod.neutral_border(jnp.asarray(vol), 0.5))
    for x in range(6):
        inside = vol[:, x, :x + 1]
        want = inside.min(-1) + 0.5 * (inside.mean(-1) - inside.min(-1))
        np.testing.assert_allclose(out[:, x, :x + 1], inside)
        for d in range(x + 1, 4):
            np.testing.assert_allclose(out[:, x, d], want, rtol=1e-6)
