"""The whole census chain with the native kernels (kernels="native") against the JAX kernels
(kernels="xla") on small real crops: the disparities agree on >= 99.5 % of the real pixels within
0.5 px, and the native program really calls the native kernels (their XLA FFI custom calls are in
its lowered text, and in none of the JAX program's), so that the comparison is never XLA against
XLA (issue 51, "Equality")."""

import dataclasses
import functools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax import chain
from stereojax.config import BandConfig

from .. import native_cases as nc
from ..helpers import require_native

MAX_DISP = 64


def _config(setting: str, kernels: str):
    cfg = stereojax.preset("census", MAX_DISP)
    if setting == "banded":        # bands of 16 of the 64 disparities, from the coarse pass
        cfg = dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=16))
    else:                          # full range, the right view aggregated on its own (sgm mirrored)
        cfg = dataclasses.replace(cfg, band=BandConfig(),
                                  refine=dataclasses.replace(cfg.refine, right_from_left=False))
    return dataclasses.replace(cfg, kernels=kernels).validate()


def _disparity(left, right, valid, config):
    return chain.run(chain.STAGES, chain.initial(left, right, valid), config).disparity


def _custom_calls(text: str) -> set[str]:
    return set(re.findall(r"custom_call @(stereojax_\w+)", text))


@pytest.mark.slow
@pytest.mark.parametrize("setting,crop,padded", [
    pytest.param("banded", "kitti2015", False, id="banded-kitti2015-unpadded"),
    pytest.param("banded", "middlebury", True, id="banded-middlebury-padded"),
    pytest.param("full-range", "kitti2015", True, id="full-range-right-chain-kitti2015-padded")])
def test_census_chain_native_agrees_with_xla_on_a_real_crop(data_root, setting, crop, padded):
    require_native()
    name, left, right = next(p for p in nc.real_pairs(data_root, padded) if p[0] == crop)
    args = (jnp.asarray(left), jnp.asarray(right), nc.valid_array(padded))
    disp, calls = {}, {}
    for kernels in ("native", "xla"):
        config = _config(setting, kernels)
        assert config.banded == (setting == "banded")
        lowered = jax.jit(functools.partial(_disparity, config=config)).lower(*args)
        calls[kernels] = _custom_calls(lowered.as_text())
        disp[kernels] = nc.real_part(lowered.compile()(*args), padded)
    assert {"stereojax_census", "stereojax_cbca", "stereojax_sgm"} <= calls["native"], calls["native"]
    assert not calls["xla"], calls["xla"]
    a, b = disp["native"], disp["xla"]
    assert np.all(np.isfinite(a)) and a.shape == b.shape
    agree = np.abs(a - b) <= 0.5
    print(f"chain {setting} {crop} {'padded' if padded else 'unpadded'}: {agree.mean():.4%} within 0.5 px, "
          f"{(a != b).sum()} of {a.size} pixels not equal, max {np.abs(a - b).max():.3g} px; "
          f"native calls {sorted(calls['native'])}")
    assert agree.mean() >= 0.995, (setting, crop, agree.mean())
