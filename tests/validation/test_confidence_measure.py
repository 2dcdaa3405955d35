"""stereojax.validation.confidence_measure: the confidence map (margin of the aggregated cost x left-right
agreement) by hand."""

import jax.numpy as jnp
import numpy as np

from stereojax.validation import confidence_measure


def test_confidence_terms_by_hand():
    cost = np.array([[[0.2, 0.8, 0.5, 0.6], [0.3, 0.31, 0.9, 0.3]]], np.float32)    # [1, 2, 4]
    wta = np.argmin(cost, -1)                                                        # [[0, 0]]
    margin = np.asarray(confidence_measure.confidence(jnp.asarray(cost), jnp.asarray(wta), None))
    # pixel 0: best 0.2 at d 0, best at |d - 0| >= 2 is 0.5 -> (0.5 - 0.2) / 0.5; pixel 1: 0.3 vs 0.3 -> 0
    np.testing.assert_allclose(margin, [[0.6, 0.0]], atol=1e-6)
    # left-right: pixel 1 (d 0) sees D_R(1) = 3: off by 3, tolerance 1 -> exp(-2)
    disp_right = np.array([[0, 3]], np.int32)
    full = np.asarray(confidence_measure.confidence(jnp.asarray(cost), jnp.asarray(wta), jnp.asarray(disp_right), 1.0))
    np.testing.assert_allclose(full, margin * np.array([[1.0, np.exp(-2.0)]]), atol=1e-6)
