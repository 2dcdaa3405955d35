"""Property-based: the native kernels (XLA FFI calls) equal the JAX kernels on small random volumes
(H, W in 3..12, band widths 3..8 of up to 16 disparities, random band offsets, random padding on
the right and bottom): SGM (4 and 8 paths, bands and the full range), CBCA on bands and the census
band cost (issue 51, "Equality"). Only the real pixels are compared where a case is padded."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from stereojax.aggregation import cross_based
from stereojax.config import SGMConfig
from stereojax.matching_cost import classical
from stereojax.optimization import semi_global
from stereojax.volume import CostVolume, real_pixels

from .. import native_cases as nc
from ..helpers import require_native

#: every example has a new shape, so each compiles the JAX kernel once: few examples (about 1 s,
#: 0.5 s and 0.3 s an example for SGM, CBCA and census; 60 of each passed when written)
def _property(examples):
    return settings(max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module", autouse=True)
def _native():
    require_native()


@st.composite
def cases(draw, k_min=3):
    """A random case: shape, band width K <= D <= 16, real (rows, columns), a seed."""
    h, w = draw(st.integers(3, 12)), draw(st.integers(3, 12))
    k = draw(st.integers(k_min, 8))
    d = draw(st.integers(k, 16))
    padded = draw(st.booleans())
    rows = draw(st.integers(1, h)) if padded else h
    cols = draw(st.integers(1, w)) if padded else w
    return h, w, k, d, (rows, cols) if padded else None, draw(st.integers(0, 2 ** 31 - 1))


def _inputs(h, w, k, d, seed):
    rng = np.random.default_rng(seed)
    cost = rng.random((h, w, k)).astype(np.float32)
    off = rng.integers(0, d - k + 1, (h, w)).astype(np.int32)
    left = rng.integers(0, 256, (h, w)).astype(np.float32)
    right = rng.integers(0, 256, (h, w)).astype(np.float32)
    return cost, off, left, right


def _real(a, valid):
    a = np.asarray(a)
    return a if valid is None else a[:valid[0], :valid[1]]


@functools.partial(jax.jit, static_argnames=("cfg", "kernels"))
def _sgm(vol, left, right, cfg, kernels):
    if kernels == "xla":
        return semi_global.sgm_volume_xla(vol, left, right, cfg)
    return semi_global.sgm_volume(vol, left, right, cfg, kernels="native")


@pytest.mark.slow
@_property(15)
@given(case=cases(), banded=st.booleans(), directions=st.sampled_from([4, 8]), adaptive=st.booleans(),
       vertical_factor=st.sampled_from([1.0, 1.5]), threshold=st.sampled_from([15.0, 80.0]))
def test_sgm_native_equals_jax_on_random_volumes(case, banded, directions, adaptive, vertical_factor, threshold):
    h, w, k, d, valid, seed = case
    cfg = SGMConfig(directions=directions, adaptive=adaptive, vertical_factor=vertical_factor,
                    grad_threshold=threshold, p1=0.3, p2=2.0)
    cost, off, left, right = _inputs(h, w, k if banded else d, d, seed)
    v = None if valid is None else jnp.array(valid, jnp.int32)
    vol = (CostVolume.band(jnp.asarray(cost), jnp.asarray(off), d, v) if banded
           else CostVolume.full(jnp.asarray(cost), v))
    l, r = jnp.asarray(left), jnp.asarray(right)
    got, want = _sgm(vol, l, r, cfg, "native").cost, _sgm(vol, l, r, cfg, "xla").cost
    nc.assert_close(_real(got, valid), _real(want, valid), rtol=1e-5,
                    what=f"sgm {case} banded={banded} {cfg.directions} paths adaptive={adaptive}")


@functools.partial(jax.jit, static_argnames=("iterations", "arm", "tau", "kernels"))
def _cbca(vol, grey, iterations, arm, tau, kernels):
    arms = cross_based.cross_arms(grey, tau, arm, real_pixels(grey.shape, vol.valid))
    if kernels == "xla":
        return cross_based.cbca_volume_xla(vol, arms, iterations, arm)
    return cross_based.cbca_volume(vol, arms, iterations, arm, kernels="native")


@pytest.mark.slow
@_property(20)
@given(case=cases(), iterations=st.integers(1, 2), arm=st.integers(1, 5), tau=st.sampled_from([10.0, 40.0]))
def test_cbca_band_native_equals_jax_on_random_volumes(case, iterations, arm, tau):
    h, w, k, d, valid, seed = case
    cost, off, left, _ = _inputs(h, w, k, d, seed)
    v = None if valid is None else jnp.array(valid, jnp.int32)
    vol = CostVolume.band(jnp.asarray(cost), jnp.asarray(off), d, v)
    got = _cbca(vol, jnp.asarray(left), iterations, arm, tau, "native").cost
    want = _cbca(vol, jnp.asarray(left), iterations, arm, tau, "xla").cost
    # to 1e-5 rather than bit for bit: XLA computes the JAX band kernel's neutral term
    # hs / h_len[..., None] as hs * (1 / h_len), one rounding away from the native division
    # (tests/aggregation/test_cross_based_native.py)
    nc.assert_close(_real(got, valid), _real(want, valid), rtol=1e-5,
                    what=f"cbca band {case} it={iterations} arm={arm} tau={tau}")


@functools.partial(jax.jit, static_argnames=("k", "d", "radius", "border", "kernels"))
def _census(left, right, off, valid, k, d, radius, border, kernels):
    if kernels == "xla":
        return classical.census_band_xla(left, right, off, k, d, radius, border, valid)
    return classical.census_band(left, right, off, k, d, radius, border, valid, kernels="native")


@pytest.mark.slow
@_property(25)
@given(case=cases(), ry=st.integers(1, 3), rx=st.integers(1, 4), border=st.sampled_from(["replicate", "worst"]),
       grey_levels=st.sampled_from([2, 256]))
def test_census_band_native_equals_jax_on_random_images(case, ry, rx, border, grey_levels):
    h, w, k, d, valid, seed = case
    rng = np.random.default_rng(seed)
    # few grey levels: many equal neighbours, where "neighbour < centre" must agree exactly
    left = jnp.asarray(rng.integers(0, grey_levels, (h, w)).astype(np.float32))
    right = jnp.asarray(rng.integers(0, grey_levels, (h, w)).astype(np.float32))
    off = jnp.asarray(rng.integers(0, d - k + 1, (h, w)).astype(np.int32))
    v = None if valid is None else jnp.array(valid, jnp.int32)
    got = _census(left, right, off, v, k, d, (ry, rx), border, "native")
    want = _census(left, right, off, v, k, d, (ry, rx), border, "xla")
    nc.assert_equal(_real(got.cost, valid), _real(want.cost, valid),
                    f"census band {case} radius={(ry, rx)} {border}")
