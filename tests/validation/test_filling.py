"""stereojax.validation.filling: the sorting network of the filling's median."""

import jax.numpy as jnp
import numpy as np

from stereojax.validation import filling


def test_sort8_sorts_every_input():
    """The filling's median sorts its 8 candidates with a network of compare-exchanges: sorting
    every 0/1 input proves that it sorts any input (the 0-1 principle); random floats with ties
    and BIG too."""
    bits = (np.arange(256)[:, None] >> np.arange(8)[None, :]) & 1                    # [256, 8]
    got = np.stack([np.asarray(a) for a in filling.sort8([jnp.asarray(bits[:, i]) for i in range(8)])], 1)
    np.testing.assert_array_equal(got, np.sort(bits, axis=1))
    rng = np.random.default_rng(3)
    x = rng.integers(0, 5, (100, 8)).astype(np.float32)
    x[rng.random(x.shape) < 0.2] = 1e9
    got = np.stack([np.asarray(a) for a in filling.sort8([jnp.asarray(x[:, i]) for i in range(8)])], 1)
    np.testing.assert_array_equal(got, np.sort(x, axis=1))
