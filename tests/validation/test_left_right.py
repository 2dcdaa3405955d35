"""stereojax.validation.left_right: the left-right check against its numpy reference and by hand (with the
filling of what it rejects)."""

import jax.numpy as jnp
import numpy as np

from stereojax.validation import filling, left_right

from .. import reference as ref


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
