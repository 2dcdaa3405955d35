"""Property-based tests of the whole chain: any valid pair gives a finite map of the input's shape in range,
and any input gives a map or a typed error."""

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

import stereojax
from stereojax import StereoError, StereoInputError
from stereojax.config import AggregationConfig, CostConfig, StereoConfig

# few distinct shapes, because every new shape compiles the chain once
SHAPES = [(12, 20), (16, 24), (13, 31)]


SMALL = StereoConfig(max_disp=4, cost=CostConfig(census_radius=(1, 2)),
                     cbca=AggregationConfig(arm_length=3))


@st.composite
def pairs(draw):
    h, w = draw(st.sampled_from(SHAPES))
    dtype = draw(st.sampled_from([np.uint8, np.uint16, np.float32, np.float64]))
    colour = draw(st.booleans())
    max_disp = draw(st.integers(1, 8))
    shape = (h, w, 3) if colour else (h, w)
    seed = draw(st.integers(0, 2 ** 16))
    rng = np.random.default_rng(seed)
    if dtype in (np.float32, np.float64):
        left, right = rng.random(shape).astype(dtype), rng.random(shape).astype(dtype)
    else:
        hi = np.iinfo(dtype).max
        left = rng.integers(0, hi, shape, endpoint=True).astype(dtype)
        right = rng.integers(0, hi, shape, endpoint=True).astype(dtype)
    return left, right, max_disp


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pairs())
def test_disparity_shape_and_range(case):
    left, right, max_disp = case
    cfg = SMALL.with_max_disp(max_disp)
    disp = stereojax.disparity(left, right, cfg)
    assert disp.shape == left.shape[:2]
    assert np.all(np.isfinite(disp))
    assert disp.min() >= 0 and disp.max() <= max_disp - 1


@settings(max_examples=10, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12))
def test_too_small_images_are_rejected_cleanly(h, w):
    img = np.zeros((h, w), np.uint8)
    try:
        disp = stereojax.disparity(img, img, SMALL.with_max_disp(min(4, max(w - 1, 1))))
    except StereoInputError:
        return
    assert disp.shape == (h, w)


DTYPES = [np.uint8, np.uint16, np.float32, np.float64]


#: valid shapes and shapes smaller than SMALL's 7x7 window (each new shape compiles the chain)
ANY_SHAPES = [(12, 20), (9, 33), (16, 16), (6, 30), (20, 5)]


def _image(rng, shape, dtype, scale):
    if np.issubdtype(dtype, np.floating):
        return (rng.random(shape) * scale).astype(dtype)
    hi = np.iinfo(dtype).max
    return rng.integers(0, hi, shape, endpoint=True).astype(dtype)


@st.composite
def any_pairs(draw):
    h, w = draw(st.sampled_from(ANY_SHAPES))
    dl, dr = draw(st.sampled_from(DTYPES)), draw(st.sampled_from(DTYPES))
    cl, cr = draw(st.booleans()), draw(st.booleans())
    scale = draw(st.sampled_from([1.0, 255.0]))           # float images in 0..1 or 0..255
    max_disp = draw(st.integers(-2, w + 2))
    nan = draw(st.sampled_from([None, np.nan, np.inf]))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 16)))
    left = _image(rng, (h, w, 3) if cl else (h, w), dl, scale)
    right = _image(rng, (h, w, 3) if cr else (h, w), dr, scale)
    if nan is not None and np.issubdtype(dl, np.floating):
        left.flat[rng.integers(left.size)] = nan
    return left, right, max_disp


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(any_pairs())
def test_disparity_any_input_gives_a_map_or_a_stereo_error(case):
    import warnings

    left, right, max_disp = case
    cfg = StereoConfig(max_disp=max_disp, cost=SMALL.cost, cbca=SMALL.cbca)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", stereojax.InputWarning)   # colour/grey mixes are accepted
            disp = stereojax.disparity(left, right, cfg)
    except StereoError as exc:                           # only typed errors, with a message
        assert str(exc) and "\n" not in str(exc)
        h, w = left.shape[:2]
        bad_input = (max_disp <= 0 or max_disp >= w or min(h, w) < 7
                     or not (np.all(np.isfinite(left)) and np.all(np.isfinite(right))))
        assert bad_input, f"valid input rejected: {exc}"
        return
    assert disp.shape == left.shape[:2] and disp.dtype == np.float32
    assert np.all(np.isfinite(disp))
    assert disp.min() >= 0 and disp.max() <= max_disp
