"""Census: the native kernel (census.cc, an XLA FFI call) equals the JAX kernel bit for bit on real
KITTI 2015 and Middlebury crops: the full range in both views with every border, and bands (from
the coarse pass and from a smooth random field) with the replicate and worst borders, padded and
unpadded (issue 51, "Equality")."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.matching_cost import classical

from .. import native_cases as nc
from ..helpers import require_native


#: the cases of make test-fast (tests/conftest.py); the others are marked slow
FAST_CASES = {
    'test_census_cost_native_equals_jax_on_real_crops[right-worst-padded]',
    'test_census_cost_native_equals_jax_on_real_crops[left-replicate-unpadded]',
    'test_census_band_native_equals_jax_on_real_crops[coarse48-worst-padded]',
    'test_census_band_native_equals_jax_on_real_crops[random-replicate-unpadded]',
}


@pytest.fixture(scope="module", autouse=True)
def _native():
    require_native()


@pytest.mark.parametrize("padded", [False, True], ids=["unpadded", "padded"])
@pytest.mark.parametrize("border", ["replicate", "worst", "neutral"])
@pytest.mark.parametrize("view", ["left", "right"])
def test_census_cost_native_equals_jax_on_real_crops(data_root, view, border, padded):
    native = jax.jit(lambda l, r: classical.census_cost(l, r, nc.D, (3, 4), view, border, kernels="native"))
    xla = jax.jit(lambda l, r: classical.census_cost_xla(l, r, nc.D, (3, 4), view, border))
    for name, left, right in nc.real_pairs(data_root, padded):
        l, r = jnp.asarray(left), jnp.asarray(right)
        got, want = native(l, r), xla(l, r)
        assert got.shape == want.shape == (nc.H, nc.W, nc.D)
        nc.assert_equal(nc.real_part(got, padded), nc.real_part(want, padded),
                        f"census {view} {border} {'padded' if padded else 'unpadded'} {name}")


@pytest.mark.parametrize("padded", [False, True], ids=["unpadded", "padded"])
@pytest.mark.parametrize("border", ["replicate", "worst"])
@pytest.mark.parametrize("kind", ["coarse", "random", "coarse48"])
def test_census_band_native_equals_jax_on_real_crops(data_root, kind, border, padded):
    """Bands of K = 12 of D = 32 from the coarse pass and from a random field, and of K = 48 of
    D = 64 from the coarse pass (native_cases.KINDS)."""
    d, k, source = nc.KINDS[kind]
    valid = nc.valid_array(padded)
    native = jax.jit(lambda l, r, o: classical.census_band(l, r, o, k, d, (3, 4), border, valid, kernels="native"))
    xla = jax.jit(lambda l, r, o: classical.census_band_xla(l, r, o, k, d, (3, 4), border, valid))
    for i, (name, left, right) in enumerate(nc.real_pairs(data_root, padded)):
        off = jnp.asarray(nc.offsets(source, left, right, padded, i, d, k))
        l, r = jnp.asarray(left), jnp.asarray(right)
        got, want = native(l, r, off), xla(l, r, off)
        assert got.banded and got.k == k and got.max_disp == d
        np.testing.assert_array_equal(np.asarray(got.offset), np.asarray(off))
        if padded:
            np.testing.assert_array_equal(np.asarray(got.valid), nc.VALID)
        nc.assert_equal(nc.real_part(got.cost, padded), nc.real_part(want.cost, padded),
                        f"census band {kind} {border} {'padded' if padded else 'unpadded'} {name}")


def test_census_native_is_an_ffi_call_and_xla_is_not():
    img = jnp.zeros((8, 12), jnp.float32)
    text = {k: jax.jit(lambda l, r, k=k: classical.census_cost(l, r, 4, (1, 2), kernels=k)).lower(img, img).as_text()
            for k in ("native", "xla")}
    assert "stereojax_census" in text["native"] and "stereojax_census" not in text["xla"]
