"""The native confidence (confidence_measure.cc) against its JAX kernel, on real crops' census
volumes after SGM, banded and full range, with and without the right view (issue 51,
"Equality"): to 1e-6 (exp may differ in its last bit), and exactly where it is 0 or 0.5 times the
margin."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.config import SGMConfig
from stereojax.disparity import right_view, winner_takes_all
from stereojax.optimization import semi_global
from stereojax.validation import confidence_measure
from tests import native_cases as nc
from tests.helpers import require_native

#: the cases of make test-fast (tests/conftest.py); the others are marked slow
FAST_CASES = {"test_confidence_native_equals_jax[coarse48-True]"}


@pytest.mark.parametrize("kind,padded", [("coarse48", True), ("full", False), ("coarse", False)])
def test_confidence_native_equals_jax(data_root, kind, padded):
    require_native()
    for name, left, right in nc.real_pairs(data_root, padded):
        _, vol = nc.volume(left, right, kind, padded)
        vol = jax.jit(lambda v, l, r: semi_global.sgm_volume(v, l, r, SGMConfig(), "xla"))(vol, left, right)
        disp = winner_takes_all.wta_volume(vol, "xla")
        roff = vol.offset if vol.banded else jnp.zeros(vol.shape, jnp.int32)
        dright = right_view.right_wta(vol, roff, 1.0, "xla")
        for dr in (dright, None):
            got = jax.jit(lambda v, d, r: confidence_measure.confidence_volume(v, d, r, 1.0, "native"))(vol, disp, dr)
            want = jax.jit(lambda v, d, r: confidence_measure.confidence_volume(v, d, r, 1.0, "xla"))(vol, disp, dr)
            got, want = np.asarray(got), np.asarray(want)
            assert 0.05 < want.mean() < 0.95, (name, want.mean())
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7, err_msg=f"{name} {kind} right={dr is not None}")
            np.testing.assert_array_equal(got == 0, want == 0)
