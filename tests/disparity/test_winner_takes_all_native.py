"""The native WTA and right-view kernels (winner_takes_all.cc, right_view.cc) against their JAX
kernels: exactly equal (integer outputs), on real KITTI and Middlebury crops' census volumes
after SGM (where ties are rare) and before it (ties), banded and full range, K = 48 and others,
padded and unpadded (issue 51, "Equality")."""

import jax
import numpy as np
import pytest

from stereojax.config import SGMConfig
from stereojax.disparity import right_view, winner_takes_all
from stereojax.optimization import semi_global
from tests import native_cases as nc
from tests.helpers import require_native


def _volumes(data_root, kind, padded):
    for name, left, right in nc.real_pairs(data_root, padded):
        _, vol = nc.volume(left, right, kind, padded)
        yield f"{name}-{kind}", vol
        sgm = jax.jit(lambda v, l, r: semi_global.sgm_volume(v, l, r, SGMConfig(), "xla"))(vol, left, right)
        yield f"{name}-{kind}-sgm", sgm


@pytest.mark.parametrize("kind,padded", [
    ("full", False), ("coarse48", True),
    *(pytest.param(k, p, marks=pytest.mark.slow) for k, p in [("full", True), ("coarse", False), ("coarse", True),
                                                           ("random", False), ("random", True), ("coarse48", False)]),
])
def test_wta_and_right_view_native_equal_jax(data_root, kind, padded):
    require_native()
    for what, vol in _volumes(data_root, kind, padded):
        native = jax.jit(lambda v: winner_takes_all.wta_volume(v, "native"))(vol)
        xla = jax.jit(lambda v: winner_takes_all.wta_volume(v, "xla"))(vol)
        nc.assert_equal(native, xla, f"WTA {what}")
        roff = np.roll(np.asarray(vol.offset), 3, axis=1) if vol.banded else np.zeros(vol.shape, np.int32)
        native = jax.jit(lambda v, o: right_view.right_wta(v, o, 1.0, "native"))(vol, roff)
        xla = jax.jit(lambda v, o: right_view.right_wta(v, o, 1.0, "xla"))(vol, roff)
        nc.assert_equal(native, xla, f"right view {what}")


def test_wta_native_first_minimum_wins_on_ties():
    require_native()
    from stereojax.volume import CostVolume
    cost = np.zeros((2, 3, 48), np.float32)
    cost[0, 0, [5, 9]] = -1.0                   # a tie: the first index wins
    cost[1, 2, 47] = -2.0
    vol = CostVolume.band(cost, np.full((2, 3), 4, np.int32), 100)
    got = np.asarray(winner_takes_all.wta_volume(vol, "native"))
    assert got[0, 0] == 5 + 4 and got[1, 2] == 47 + 4 and got[0, 1] == 4
    np.testing.assert_array_equal(got, np.asarray(winner_takes_all.wta_volume(vol, "xla")))
