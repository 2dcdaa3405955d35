"""stereojax.filters.median against its numpy reference."""

import jax.numpy as jnp
import numpy as np

from stereojax.filters import median

from .. import reference as ref


def test_median_matches_reference():
    img = np.random.default_rng(7).random((8, 9)).astype(np.float32)
    for size in (3, 5):
        np.testing.assert_allclose(np.asarray(median.median_filter(jnp.asarray(img), size)),
                                   ref.median(img, size), atol=1e-7)
