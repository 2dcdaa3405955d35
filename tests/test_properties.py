"""Property-based tests: any valid pair gives a finite map of the input's shape in range."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import stereojax
from stereojax import StereoInputError
from stereojax.config import AggregationConfig, CostConfig, StereoConfig

# few distinct shapes, because every new shape compiles the chain once
SHAPES = [(12, 20), (16, 24), (13, 31)]
SMALL = StereoConfig(max_disp=4, cost=CostConfig(census_radius=(1, 2)),
                     cbca=AggregationConfig(arm_length=3))


@st.composite
def pairs(draw):
    h, w = draw(st.sampled_from(SHAPES))
    dtype = draw(st.sampled_from([np.uint8, np.uint16, np.float32]))
    colour = draw(st.booleans())
    max_disp = draw(st.integers(1, 8))
    shape = (h, w, 3) if colour else (h, w)
    seed = draw(st.integers(0, 2 ** 16))
    rng = np.random.default_rng(seed)
    if dtype == np.float32:
        left, right = rng.random(shape, np.float32), rng.random(shape, np.float32)
    else:
        hi = np.iinfo(dtype).max
        left = rng.integers(0, hi, shape, endpoint=True).astype(dtype)
        right = rng.integers(0, hi, shape, endpoint=True).astype(dtype)
    return left, right, max_disp


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pairs())
def test_disparity_shape_and_range(case):
    left, right, max_disp = case
    cfg = SMALL.with_max_disp(max_disp)
    disp = stereojax.disparity(left, right, cfg)
    assert disp.shape == left.shape[:2]
    assert np.all(np.isfinite(disp))
    assert disp.min() >= 0 and disp.max() <= max_disp - 1


@settings(max_examples=15, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12))
def test_too_small_images_are_rejected_cleanly(h, w):
    img = np.zeros((h, w), np.uint8)
    try:
        disp = stereojax.disparity(img, img, SMALL.with_max_disp(min(4, max(w - 1, 1))))
    except StereoInputError:
        return
    assert disp.shape == (h, w)
