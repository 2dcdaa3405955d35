"""stereojax.volume: a banded cost volume cut from a full one and written back."""

import jax.numpy as jnp
import numpy as np

from stereojax.volume import band_from_full

from .band_reference import D, _case


def test_band_from_full_and_to_full_round_trip():
    k = 4
    full, off, _, _ = _case(8, k)
    vol = band_from_full(jnp.asarray(full), jnp.asarray(off), k)
    back = np.asarray(vol.to_full(fill=-1.0))
    inside = (np.arange(D) >= off[..., None]) & (np.arange(D) < off[..., None] + k)
    np.testing.assert_array_equal(back[inside], full[inside])
    assert (back[~inside] == -1.0).all()
