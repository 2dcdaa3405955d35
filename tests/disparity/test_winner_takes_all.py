"""stereojax.disparity.winner_takes_all: the first minimum wins."""

import jax.numpy as jnp
import numpy as np

from stereojax.disparity import winner_takes_all


def test_wta_takes_first_minimum():
    vol = jnp.asarray(np.array([[[0.5, 0.1, 0.1, 0.9]]], np.float32))
    assert int(winner_takes_all.wta(vol)[0, 0]) == 1
