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


# ---- any input: a valid map or a StereoError, never anything else -------------------------------

from stereojax import StereoError  # noqa: E402
from stereojax.data import io  # noqa: E402

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


# ---- readers: write then read back -------------------------------------------------------------

@st.composite
def png_images(draw):
    h, w = draw(st.integers(1, 40)), draw(st.integers(1, 40))
    channels = draw(st.sampled_from([None, 3, 4]))
    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 16)))
    shape = (h, w) if channels is None else (h, w, channels)
    return rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)


@settings(max_examples=40, deadline=None)
@given(png_images())
def test_png_round_trip_any_shape_and_dtype(tmp_path_factory, img):
    p = tmp_path_factory.mktemp("png") / "x.png"
    io.write_png(p, img)
    got = io.read_image(p)
    assert got.dtype == img.dtype
    np.testing.assert_array_equal(got, img[..., :3] if img.ndim == 3 else img)   # alpha dropped


@settings(max_examples=40, deadline=None)
@given(png_images(), st.data())
def test_damaged_png_gives_a_stereo_input_error(tmp_path_factory, img, data):
    p = tmp_path_factory.mktemp("png") / "x.png"
    io.write_png(p, img)
    raw = p.read_bytes()
    how = data.draw(st.sampled_from(["truncate", "garbage", "random"]))
    if how == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif how == "garbage":                                # valid signature, random body
        raw = raw[:8] + data.draw(st.binary(min_size=0, max_size=200))
    else:
        raw = data.draw(st.binary(min_size=0, max_size=200))
    p.write_bytes(raw)
    try:
        got = io.read_image(p)
    except StereoInputError as exc:
        assert "x.png" in str(exc) and "\n" not in str(exc)
        return
    # only random bytes that happen to decode may pass, and then as a proper image
    assert how != "truncate" and got.dtype in (np.uint8, np.uint16) and got.size > 0


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30), st.integers(0, 2 ** 16))
def test_kitti_disparity_round_trip_any_shape(tmp_path_factory, h, w, seed):
    rng = np.random.default_rng(seed)
    disp = (rng.random((h, w)) * 255).astype(np.float32)
    valid = rng.random((h, w)) < 0.7
    p = tmp_path_factory.mktemp("kitti") / "d.png"
    io.write_kitti_disparity(p, disp, valid)
    got, ok = io.read_kitti_disparity(p)
    assert got.shape == (h, w) and got.dtype == np.float32
    np.testing.assert_array_equal(ok, valid)
    # a valid pixel never becomes 0 (KITTI's "no disparity"): below 1/512 px it is stored as 1/256
    expected = np.where(disp < 1 / 512, 1 / 256, disp)
    np.testing.assert_allclose(got[valid], expected[valid], atol=1 / 512 + 1e-6)
    assert np.all(got[~valid] == 0)
