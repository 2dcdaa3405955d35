"""The native top-K candidate ranking (ranking.cc) against lax.top_k: the same disparities in the
same order, ties included, on real census volumes (bands and full range) and on volumes with
many ties (issue 51, "Equality")."""

import dataclasses

import jax
import numpy as np
import pytest

from stereojax.config import CostConfig, StereoConfig
from stereojax.matching_cost import learned
from stereojax.volume import CostVolume
from tests import native_cases as nc
from tests.helpers import require_native


def _cfg(candidates, kernels, max_disp=64):
    return StereoConfig(max_disp=max_disp, cost=CostConfig(method="learned", candidates=candidates), kernels=kernels)


@pytest.mark.parametrize("kind,padded", [("coarse48", True), pytest.param("full", False, marks=pytest.mark.slow),
                                         pytest.param("full", True, marks=pytest.mark.slow),
                                         pytest.param("coarse48", False, marks=pytest.mark.slow)])
def test_rank_native_equals_top_k_on_real_volumes(data_root, kind, padded):
    require_native()
    for name, left, right in nc.real_pairs(data_root, padded):
        _, vol = nc.volume(left, right, kind, padded)
        for k in (4, 8, 16):
            got = jax.jit(lambda v: learned.rank(v, _cfg(k, "native", vol.max_disp)))(vol)
            want = jax.jit(lambda v: learned.rank(v, _cfg(k, "xla", vol.max_disp)))(vol)
            assert got.shape[-1] == k
            nc.assert_equal(got, want, f"rank {name} {kind} K2={k}")


@pytest.mark.parametrize("levels", [2, 5])
def test_rank_native_keeps_top_ks_order_of_ties(levels):
    require_native()
    rng = np.random.default_rng(levels)
    cost = (rng.integers(0, levels, (9, 13, 48)) / levels).astype(np.float32)
    off = rng.integers(0, 16, (9, 13)).astype(np.int32)
    for vol in (CostVolume.band(cost, off, 64), CostVolume.full(cost)):
        md = vol.max_disp
        nc.assert_equal(learned.rank(vol, _cfg(8, "native", md)), learned.rank(vol, _cfg(8, "xla", md)),
                        f"rank ties {levels} banded={vol.banded}")
