"""The native median filter (median.cc) against its JAX kernel: exactly equal (the median of an
odd window is one of its values), on random maps with repeated values and on real disparity-like
maps, sizes 3 to 9, shapes smaller than the window included (the JAX kernel's
selection network grows with the square of the window: its compile, not the native kernel, sets
the sizes tested) (issue 51, "Equality")."""

import jax
import numpy as np
import pytest

from stereojax.filters import median
from tests.helpers import require_native


@pytest.mark.parametrize("size", [3, 5, pytest.param(9, marks=pytest.mark.slow)])   # 9: the shipped KITTI models'
@pytest.mark.parametrize("shape", [(2, 7), (40, 61)])
def test_median_native_equals_jax(shape, size):
    require_native()
    rng = np.random.default_rng(size * 1000 + shape[0] * 10 + shape[1])
    for disp in (rng.uniform(0, 100, shape).astype(np.float32),
                 rng.integers(0, 4, shape).astype(np.float32),                     # many ties
                 np.cumsum(rng.normal(0, 1, shape), axis=1).astype(np.float32)):  # smooth rows
        got = median.median_filter(disp, size, "native")
        want = median.median_filter(disp, size, "xla")
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    if shape == (40, 61):
        assert not np.array_equal(np.asarray(got), disp)   # it filtered something
