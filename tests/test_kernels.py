"""numpy-vs-jax agreement for every stage of the chain, on tiny random inputs."""

import numpy as np
import pytest
import jax.numpy as jnp

from stereojax.aggregation import cross_based as aggregation
from stereojax.matching_cost import classical as cost
from stereojax.disparity import right_view
from stereojax.disparity import winner_takes_all
from stereojax.filters import bilateral
from stereojax.filters import median
from stereojax.refinement import parabola
from stereojax.validation import filling
from stereojax.validation import left_right
from stereojax.config import SGMConfig
from stereojax.optimization.semi_global import sgm

from . import reference as ref


@pytest.fixture
def pair():
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (9, 14)).astype(np.float32)
    right = rng.integers(0, 256, (9, 14)).astype(np.float32)
    return left, right


@pytest.fixture
def smooth_grey():
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, (4, 5)).astype(np.float32)
    return np.kron(base, np.ones((3, 3), np.float32)) + rng.normal(0, 3, (12, 15)).astype(np.float32)


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


def test_wta_takes_first_minimum():
    vol = jnp.asarray(np.array([[[0.5, 0.1, 0.1, 0.9]]], np.float32))
    assert int(winner_takes_all.wta(vol)[0, 0]) == 1


def test_lr_check_and_fill_match_reference():
    rng = np.random.default_rng(5)
    dl = rng.integers(0, 4, (6, 12)).astype(np.float32)
    dr = dl.copy()
    dr[rng.random(dl.shape) < 0.3] = rng.integers(0, 4)
    labels = np.asarray(left_right.lr_check(jnp.asarray(dl), jnp.asarray(dr), 4, 1.0))
    np.testing.assert_array_equal(labels, ref.lr_check(dl, dr, 4, 1.0))
    assert set(np.unique(labels)) <= {0, 1, 2}
    filled = np.asarray(filling.fill_disparity(jnp.asarray(dl), jnp.asarray(labels)))
    np.testing.assert_allclose(filled, ref.fill(dl, labels), atol=1e-6)


def test_lr_check_matches_reference_with_right_disparities_out_of_range():
    """The mismatch test (some d' < D with D_R(x - d') == d') as a scatter of the right pixels:
    right disparities off the grid, negative or at and above the range are never a d'."""
    rng = np.random.default_rng(11)
    for _ in range(5):
        dl = rng.uniform(0, 7, (5, 17)).astype(np.float32)
        dr = rng.uniform(-2, 9, (5, 17)).astype(np.float32)
        grid = rng.random(dr.shape) < 0.5
        dr[grid] = np.round(dr[grid])
        for d in (5, 7):
            got = np.asarray(left_right.lr_check(jnp.asarray(dl), jnp.asarray(dr), d, 1.0))
            np.testing.assert_array_equal(got, ref.lr_check(dl, dr, d, 1.0))


def test_lr_check_hand_case():
    # one row, width 6: left disparity 2 everywhere; right map agrees except at x = 1
    dl = np.full((1, 6), 2.0, np.float32)
    dr = np.array([[2, 0, 2, 2, 2, 2]], np.float32)
    labels = np.asarray(left_right.lr_check(jnp.asarray(dl), jnp.asarray(dr), 3, 0.0))
    # x = 0, 1: the match x - 2 leaves the image. x = 0: D_R(0 - d') == d' has no solution
    # (D_R(0) = 2 != 0): occlusion. x = 1: D_R(1 - 0) = 0 == 0: mismatch.
    # x = 3: D_R(1) = 0 != 2 and D_R(3) = 2 != 0, D_R(2) = 2 != 1, D_R(1) = 0 != 2: occlusion.
    assert labels.tolist() == [[2, 1, 0, 2, 0, 0]]


def test_subpixel_matches_reference_and_recovers_parabola():
    rng = np.random.default_rng(6)
    vol = rng.random((5, 7, 6)).astype(np.float32)
    disp = np.argmin(vol, -1).astype(np.float32)
    got = np.asarray(parabola.subpixel(jnp.asarray(vol), jnp.asarray(disp)))
    np.testing.assert_allclose(got, ref.subpixel(vol, disp), atol=1e-5)
    # an exact parabola with minimum at 2.3 is recovered exactly
    d = np.arange(6, dtype=np.float32)
    par = ((d - 2.3) ** 2)[None, None]
    assert abs(float(parabola.subpixel(jnp.asarray(par), jnp.asarray([[2.0]]))[0, 0]) - 2.3) < 1e-5


def test_median_matches_reference():
    img = np.random.default_rng(7).random((8, 9)).astype(np.float32)
    for size in (3, 5):
        np.testing.assert_allclose(np.asarray(median.median_filter(jnp.asarray(img), size)),
                                   ref.median(img, size), atol=1e-7)


def test_bilateral_matches_reference():
    rng = np.random.default_rng(8)
    disp, guide = rng.random((7, 8)).astype(np.float32) * 10, rng.random((7, 8)).astype(np.float32) * 255
    got = np.asarray(bilateral.bilateral_filter(jnp.asarray(disp), jnp.asarray(guide), 2, 1.7, 30.0))
    np.testing.assert_allclose(got, ref.bilateral(disp, guide, 2, 1.7, 30.0), atol=1e-5)


def test_sort8_sorts_every_input():
    """The filling's median sorts its 8 candidates with a network of compare-exchanges: sorting
    every 0/1 input proves that it sorts any input (the 0-1 principle); random floats with ties
    and BIG too."""
    bits = (np.arange(256)[:, None] >> np.arange(8)[None, :]) & 1                    # [256, 8]
    got = np.stack([np.asarray(a) for a in filling.sort8([jnp.asarray(bits[:, i]) for i in range(8)])], 1)
    np.testing.assert_array_equal(got, np.sort(bits, axis=1))
    rng = np.random.default_rng(3)
    x = rng.integers(0, 5, (100, 8)).astype(np.float32)
    x[rng.random(x.shape) < 0.2] = 1e9
    got = np.stack([np.asarray(a) for a in filling.sort8([jnp.asarray(x[:, i]) for i in range(8)])], 1)
    np.testing.assert_array_equal(got, np.sort(x, axis=1))
