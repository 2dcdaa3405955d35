"""stereojax.learning.losses: the relaxed loss, its limits and its stability."""

import jax
import jax.numpy as jnp
import numpy as np

from stereojax.learning import losses


def test_relaxed_loss_definition_and_stability():
    delta = 0.05
    logit = lambda s: jnp.log(s) - jnp.log1p(-s)
    one, zero = jnp.float32(1), jnp.float32(0)
    # positive inside [1 - 3 delta, 1 - delta]: -ln(delta + s)
    s = jnp.float32(0.9)
    assert abs(float(losses.relaxed(logit(s), one, delta)) + np.log(0.95)) < 1e-5
    # positive outside: plain BCE
    s = jnp.float32(0.5)
    assert abs(float(losses.relaxed(logit(s), one, delta)) - float(losses.bce(logit(s), one))) < 1e-6
    # negative inside [delta, 3 delta]: -ln(delta + 1 - s)
    s = jnp.float32(0.1)
    assert abs(float(losses.relaxed(logit(s), zero, delta)) + np.log(0.95)) < 1e-5
    # delta = 0 is BCE; extreme logits stay finite, and so do their gradients
    z = jnp.array([-80.0, -5.0, 0.0, 5.0, 80.0])
    np.testing.assert_allclose(losses.relaxed(z, jnp.ones(5), 0.0), losses.bce(z, jnp.ones(5)))
    for lab in (0.0, 1.0):
        g = jax.grad(lambda q: losses.relaxed(q, jnp.full(5, lab), delta).sum())(z)
        assert np.all(np.isfinite(np.asarray(g)))
        assert np.all(np.isfinite(np.asarray(losses.relaxed(z, jnp.full(5, lab), delta))))
    assert float(losses.hinge(jnp.float32(0.9), jnp.float32(0.1), 0.2)) == 0.0
