"""stereojax.filters.bilateral against its numpy reference."""

import jax.numpy as jnp
import numpy as np

from stereojax.filters import bilateral

from .. import reference as ref


def test_bilateral_matches_reference():
    rng = np.random.default_rng(8)
    disp, guide = rng.random((7, 8)).astype(np.float32) * 10, rng.random((7, 8)).astype(np.float32) * 255
    got = np.asarray(bilateral.bilateral_filter(jnp.asarray(disp), jnp.asarray(guide), 2, 1.7, 30.0))
    np.testing.assert_allclose(got, ref.bilateral(disp, guide, 2, 1.7, 30.0), atol=1e-5)
