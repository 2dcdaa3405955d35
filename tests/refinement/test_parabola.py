"""stereojax.refinement.parabola: sub-pixel refinement against its numpy reference, and an exact parabola."""

import jax.numpy as jnp
import numpy as np

from stereojax.refinement import parabola

from .. import reference as ref


def test_subpixel_matches_reference_and_recovers_parabola():
    rng = np.random.default_rng(6)
    vol = rng.random((5, 7, 6)).astype(np.float32)
    disp = np.argmin(vol, -1).astype(np.float32)
    got = np.asarray(parabola.subpixel(jnp.asarray(vol), jnp.asarray(disp)))
    np.testing.assert_allclose(got, ref.subpixel(vol, disp), atol=1e-5)
    # an exact parabola with minimum at 2.3 is recovered exactly
    d = np.arange(6, dtype=np.float32)
    par = ((d - 2.3) ** 2)[None, None]
    assert abs(float(parabola.subpixel(jnp.asarray(par), jnp.asarray([[2.0]]))[0, 0]) - 2.3) < 1e-5
