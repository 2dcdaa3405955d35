"""The native filling after the left-right check (filling.cc) against its JAX kernel: exactly
equal, on random label maps with every label and on the labels of a real KITTI crop's chain
(issue 51, "Equality")."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax import chain
from stereojax.validation import filling
from tests import native_cases as nc
from tests.helpers import require_native


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (7, 3), (40, 61)])
@pytest.mark.parametrize("share", [0.1, 0.5, 0.95])
def test_fill_native_equals_jax_on_random_labels(shape, share):
    require_native()
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    disp = rng.uniform(0, 60, shape).astype(np.float32)
    labels = rng.choice(3, shape, p=[1 - share, share / 2, share / 2]).astype(np.int32)
    got = jax.jit(lambda d, l: filling.fill_disparity(d, l, "native"))(disp, labels)
    want = jax.jit(lambda d, l: filling.fill_disparity(d, l, "xla"))(disp, labels)
    nc.assert_equal(got, want, f"fill {shape} {share}")
    changed = labels != 0
    if changed.any() and share < 0.9:   # the filling did something, not a copy of its input
        assert not np.array_equal(np.asarray(got)[changed], disp[changed])


@pytest.mark.slow
def test_fill_native_equals_jax_on_a_real_chain(data_root):
    require_native()
    cfg = dataclasses.replace(stereojax.preset("census", nc.D), kernels="xla")
    for name, left, right in nc.real_pairs(data_root, padded=False):
        st = chain.run(chain.STAGES[:chain._index("left-right check + filling") + 1],
                       chain.initial(jnp.asarray(left), jnp.asarray(right)), cfg)
        assert (np.asarray(st.labels) != 0).mean() > 0.01, name
        disp = st.disp_wta.astype(jnp.float32)
        nc.assert_equal(filling.fill_disparity(disp, st.labels, "native"),
                        filling.fill_disparity(disp, st.labels, "xla"), f"fill {name}")
