"""SGM: the native kernel (semi_global.cc, an XLA FFI call) equals the JAX kernel to 1e-5 relative
on real KITTI 2015 and Middlebury crops: full range and bands (from the coarse pass and from a
smooth random field), padded and unpadded, 4 and 8 paths, adaptive penalties on and off, a
vertical factor != 1, and the mirrored padding of the right view's chain (issue 51, "Equality")."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.config import SGMConfig
from stereojax.matching_cost import classical
from stereojax.optimization import semi_global

from .. import native_cases as nc
from ..helpers import require_native


#: the cases of make test-fast (tests/conftest.py); the others are marked slow
FAST_CASES = {
    'test_sgm_volume_native_equals_jax_on_real_crops[coarse-padded-4paths-adaptive]',
    'test_sgm_volume_native_equals_jax_on_real_crops[full-unpadded-8paths-adaptive-vf1.5]',
    'test_sgm_volume_native_equals_jax_at_the_shipped_band_width[coarse48-padded-4paths-adaptive]',
    'test_sgm_full_range_with_real_bounds_native_equals_jax[mirrored-8paths-plain-vf2]',
}


@pytest.fixture(scope="module", autouse=True)
def _native():
    require_native()


CONFIGS = {
    "4paths-adaptive": SGMConfig(directions=4),
    "8paths-adaptive-vf1.5": SGMConfig(directions=8, vertical_factor=1.5, grad_threshold=10.0),
    "8paths-plain-vf2": SGMConfig(directions=8, adaptive=False, vertical_factor=2.0),
    "4paths-plain-vf0.5": SGMConfig(directions=4, adaptive=False, p1=0.3, p2=5.0, vertical_factor=0.5),
}


def _sgm_volume_case(data_root, kind, padded, config):
    cfg = CONFIGS[config]
    native = jax.jit(lambda v, l, r: semi_global.sgm_volume(v, l, r, cfg, kernels="native"))
    xla = jax.jit(lambda v, l, r: semi_global.sgm_volume_xla(v, l, r, cfg))
    for i, (name, left, right) in enumerate(nc.real_pairs(data_root, padded)):
        _, vol = nc.volume(left, right, kind, padded, seed=i)
        l, r = jnp.asarray(left), jnp.asarray(right)
        got, want = native(vol, l, r), xla(vol, l, r)
        np.testing.assert_array_equal(np.asarray(got.offset), np.asarray(vol.offset))
        nc.assert_close(nc.real_part(got.cost, padded), nc.real_part(want.cost, padded),
                        what=f"sgm {kind} {config} {'padded' if padded else 'unpadded'} {name}")


@pytest.mark.parametrize("config", list(CONFIGS))
@pytest.mark.parametrize("padded", [False, True], ids=["unpadded", "padded"])
@pytest.mark.parametrize("kind", ["full", "coarse", "random"])
def test_sgm_volume_native_equals_jax_on_real_crops(data_root, kind, padded, config):
    """D = 32: the full range, and bands of K = 12 from the coarse pass and a random field."""
    _sgm_volume_case(data_root, kind, padded, config)


@pytest.mark.parametrize("config", ["4paths-adaptive", "8paths-plain-vf2"])
@pytest.mark.parametrize("padded", [False, True], ids=["unpadded", "padded"])
@pytest.mark.parametrize("kind", ["full48", "coarse48"])
def test_sgm_volume_native_equals_jax_at_the_shipped_band_width(data_root, kind, padded, config):
    """K = 48 (the native kernel's constant-width path): the full range D = 48, and bands of 48 of
    D = 64 from the coarse pass."""
    _sgm_volume_case(data_root, kind, padded, config)


@pytest.mark.parametrize("config", ["4paths-adaptive", "8paths-adaptive-vf1.5", "8paths-plain-vf2"])
@pytest.mark.parametrize("how", ["none", "right", "mirrored"])
def test_sgm_full_range_with_real_bounds_native_equals_jax(data_root, how, config):
    """``sgm`` on the full range with the bounds of no padding (real=None), of padding on the
    right and bottom, and of the mirrored padding of the right view's chain (chain._right_chain:
    the right view's volume and images mirrored, real columns W - cols .. W - 1)."""
    cfg = CONFIGS[config]
    padded = how != "none"

    def run(cost, left, right, valid, kernels):
        if how == "none":
            return semi_global.sgm(cost, left, right, cfg, None, kernels)
        if how == "right":
            return semi_global.sgm(cost, left, right, cfg, (0, valid[0], 0, valid[1]), kernels)
        real = (0, valid[0], nc.W - valid[1], nc.W)
        return semi_global.sgm(cost[:, ::-1], right[:, ::-1], left[:, ::-1], cfg, real, kernels)[:, ::-1]

    native = jax.jit(functools.partial(run, kernels="native"))
    xla = jax.jit(functools.partial(run, kernels="xla"))
    view = "right" if how == "mirrored" else "left"
    census = jax.jit(lambda l, r: classical.census_cost_xla(l, r, nc.D, view=view))
    valid = jnp.array(nc.VALID, jnp.int32)
    for i, (name, left, right) in enumerate(nc.real_pairs(data_root, padded)):
        l, r = jnp.asarray(left), jnp.asarray(right)
        cost = jnp.asarray(nc.garbage_padding(np.asarray(census(l, r)), padded, seed=i))
        got, want = native(cost, l, r, valid), xla(cost, l, r, valid)
        nc.assert_close(nc.real_part(got, padded), nc.real_part(want, padded),
                        what=f"sgm full real={how} {config} {name}")


def test_sgm_native_is_an_ffi_call_and_xla_is_not():
    """The comparisons above compare two different programs: the native choice lowers to the
    stereojax_sgm custom call, the JAX one does not."""
    cost = jnp.zeros((6, 9, 4), jnp.float32)
    img = jnp.zeros((6, 9), jnp.float32)
    cfg = SGMConfig()
    text = {k: jax.jit(lambda c, l, r, k=k: semi_global.sgm(c, l, r, cfg, kernels=k)).lower(cost, img, img).as_text()
            for k in ("native", "xla")}
    assert "stereojax_sgm" in text["native"] and "stereojax_sgm" not in text["xla"]
