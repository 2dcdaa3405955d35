"""stereojax.data.io: atomic writes, image/PFM/KITTI readers and writers, visualisations."""

import os
import struct

import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stereojax.data import io
from stereojax.errors import OutputError, StereoInputError


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir())


def test_atomic_output_writes_and_keeps_extension(tmp_path):
    target = tmp_path / "sub" / "dir" / "out.png"  # folder created on demand
    with io.atomic_output(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".png" and tmp != target
        tmp.write_bytes(b"abc")
    assert target.read_bytes() == b"abc"
    assert _leftovers(target.parent) == ["out.png"]


def test_atomic_output_leaves_no_file_when_writer_raises(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError, match="boom"):
        with io.atomic_output(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert _leftovers(tmp_path) == []


def test_atomic_output_keeps_old_file_when_writer_raises(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(KeyError):
        with io.atomic_output(target) as tmp:
            tmp.write_text("new")
            raise KeyError("x")
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == ["out.txt"]


def test_atomic_output_oserror_becomes_output_error(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(OutputError, match=r"cannot write .*out\.txt: disk full"):
        with io.atomic_output(target) as tmp:
            tmp.write_text("x")
            raise OSError(28, "disk full")
    assert _leftovers(tmp_path) == []


def test_atomic_output_unwritable_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("i am a file")
    with pytest.raises(OutputError, match="cannot write"):
        with io.atomic_output(blocker / "out.png"):
            pass
    (tmp_path / "adir.png").mkdir()
    with pytest.raises(OutputError, match="folder"):
        with io.atomic_output(tmp_path / "adir.png"):
            pass


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores folder permissions")
def test_atomic_output_read_only_folder(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="cannot write"):
            io.write_png(ro / "x.png", np.zeros((2, 2), np.uint8))
    finally:
        ro.chmod(0o700)


def test_png_round_trip_rgb_grey_uint16(tmp_path):
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0] = 200  # red
    rgb[1, 2] = (1, 2, 3)
    io.write_png(tmp_path / "rgb.png", rgb)
    got = io.read_image(tmp_path / "rgb.png")
    assert got.dtype == np.uint8 and got.shape == (4, 5, 3)
    np.testing.assert_array_equal(got, rgb)
    # on disk it is a normal PNG whose first (OpenCV: blue) channel is our blue
    assert cv2.imread(str(tmp_path / "rgb.png"))[0, 0, 2] == 200

    grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
    io.write_png(tmp_path / "g.png", grey)
    np.testing.assert_array_equal(io.read_image(tmp_path / "g.png"), grey)

    deep = (np.arange(20, dtype=np.uint16) * 3000).reshape(4, 5)
    io.write_png(tmp_path / "d.png", deep)
    got = io.read_image(tmp_path / "d.png")
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, deep)


def test_read_image_drops_alpha(tmp_path):
    rgba = np.zeros((3, 3, 4), np.uint8)
    rgba[..., 1] = 77
    rgba[..., 3] = 128
    io.write_png(tmp_path / "a.png", rgba)
    got = io.read_image(tmp_path / "a.png")
    assert got.shape == (3, 3, 3) and (got[..., 1] == 77).all() and (got[..., 0] == 0).all()


def _good_png(tmp_path):
    p = tmp_path / "good.png"
    rng = np.random.default_rng(0)
    io.write_png(p, rng.integers(0, 256, (40, 50, 3), dtype=np.uint8))
    return p


@pytest.mark.parametrize("case", ["missing", "folder", "empty", "truncated", "corrupt", "text"])
def test_read_image_bad_files(tmp_path, case):
    data = _good_png(tmp_path).read_bytes()
    p = tmp_path / "bad.png"
    if case == "folder":
        p.mkdir()
    elif case == "empty":
        p.write_bytes(b"")
    elif case == "truncated":
        p.write_bytes(data[: len(data) // 2])
    elif case == "corrupt":
        p.write_bytes(data[:8] + bytes(range(256)) * 4)
    elif case == "text":
        p.write_text("hello, I am not an image\n")
    with pytest.raises(StereoInputError, match="bad.png") as exc:
        io.read_image(p)
    assert "\n" not in str(exc.value)


def test_read_image_truncated_jpeg(tmp_path):
    ok, buf = cv2.imencode(".jpg", np.random.default_rng(1).integers(0, 256, (64, 64, 3), dtype=np.uint8))
    p = tmp_path / "t.jpg"
    p.write_bytes(buf.tobytes()[: len(buf) * 2 // 3])
    with pytest.raises(StereoInputError, match="truncated"):
        io.read_image(p)


def test_write_png_rejects_bad_input(tmp_path):
    with pytest.raises(StereoInputError, match="float"):
        io.write_png(tmp_path / "f.png", np.zeros((2, 2), np.float32))
    with pytest.raises(StereoInputError, match="shape"):
        io.write_png(tmp_path / "f.png", np.zeros((2, 2, 2), np.uint8))
    with pytest.raises(OutputError, match="extension|encode"):
        io.write_png(tmp_path / "f.notaformat", np.zeros((2, 2), np.uint8))
    assert _leftovers(tmp_path) == []


def test_pfm_rows_are_bottom_up(tmp_path):
    # hand-written little-endian 2x3 file: the first stored row is the *bottom* row
    p = tmp_path / "hand.pfm"
    stored = [4, 5, 6, 1, 2, 3]
    p.write_bytes(b"Pf\n3 2\n-1.0\n" + struct.pack("<6f", *stored))
    np.testing.assert_array_equal(io.read_pfm(p), [[1, 2, 3], [4, 5, 6]])
    # big-endian (positive scale); the magnitude of the scale is ignored
    p.write_bytes(b"Pf\n3 2\n0.5\n" + struct.pack(">6f", *stored))
    got = io.read_pfm(p)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, [[1, 2, 3], [4, 5, 6]])


def test_pfm_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    grey = rng.normal(size=(5, 7)).astype(np.float32)
    grey[1, 2] = np.inf
    io.write_pfm(tmp_path / "g.pfm", grey)
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "g.pfm"), grey)
    colour = rng.normal(size=(3, 4, 3)).astype(np.float32)
    io.write_pfm(tmp_path / "c.pfm", colour)
    got = io.read_pfm(tmp_path / "c.pfm")
    assert got.shape == (3, 4, 3)
    np.testing.assert_array_equal(got, colour)
    assert (tmp_path / "g.pfm").read_bytes().startswith(b"Pf\n7 5\n")


def test_pfm_bad_files(tmp_path):
    p = tmp_path / "x.pfm"
    p.write_bytes(b"")
    with pytest.raises(StereoInputError, match="empty"):
        io.read_pfm(p)
    p.write_bytes(b"P6\n3 2\n255\n" + bytes(18))
    with pytest.raises(StereoInputError, match="magic"):
        io.read_pfm(p)
    p.write_bytes(b"Pf\n3 2\n-1.0\n" + bytes(10))
    with pytest.raises(StereoInputError, match="truncated"):
        io.read_pfm(p)
    p.write_bytes(b"Pf\nthree 2\n-1.0\n" + bytes(24))
    with pytest.raises(StereoInputError, match="header"):
        io.read_pfm(p)
    with pytest.raises(StereoInputError, match="no such file"):
        io.read_pfm(tmp_path / "missing.pfm")
    with pytest.raises(StereoInputError, match="shape"):
        io.write_pfm(tmp_path / "y.pfm", np.zeros((2, 2, 2), np.float32))


def test_kitti_disparity_round_trip(tmp_path):
    disp = np.array([[0.0, 1.5, 10.25, np.nan],
                     [-2.0, 300.0, 0.001, 42.7]], np.float32)
    valid = np.array([[True, True, False, True], [True, True, True, True]])
    p = tmp_path / "d.png"
    io.write_kitti_disparity(p, disp, valid)
    raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    # 0 valid -> 1 (devkit), masked/NaN/negative -> 0, 300 px clipped to 65535, 0.001 -> 1
    np.testing.assert_array_equal(raw, [[1, 384, 0, 0], [0, 65535, 1, round(42.7 * 256)]])
    got, ok = io.read_kitti_disparity(p)
    assert got.dtype == np.float32 and ok.dtype == bool
    np.testing.assert_array_equal(ok, raw > 0)
    np.testing.assert_allclose(got[0, 1], 1.5)
    np.testing.assert_allclose(got[1, 3], 42.7, atol=1 / 512)
    assert got[0, 2] == 0 and got[1, 0] == 0


def test_kitti_disparity_rejects_non_uint16(tmp_path):
    p = tmp_path / "u8.png"
    io.write_png(p, np.zeros((3, 3), np.uint8))
    with pytest.raises(StereoInputError, match="uint16"):
        io.read_kitti_disparity(p)
    io.write_png(p, np.zeros((3, 3, 3), np.uint16))
    with pytest.raises(StereoInputError, match="single-channel"):
        io.read_kitti_disparity(p)
    with pytest.raises(StereoInputError, match="2-D"):
        io.write_kitti_disparity(tmp_path / "x.png", np.zeros((2, 2, 2), np.float32))


def test_colorize_disparity():
    disp = np.array([[0.0, 5.0, 10.0, 20.0, np.nan, -1.0]], np.float32)
    valid = np.array([[True, True, True, True, True, False]])
    rgb = io.colorize_disparity(disp, max_disp=10, valid=valid)
    assert rgb.dtype == np.uint8 and rgb.shape == (1, 6, 3)
    assert (rgb[0, 4] == 0).all() and (rgb[0, 5] == 0).all()  # NaN and invalid black
    assert (rgb[0, 2] == rgb[0, 3]).all()  # saturates at max_disp
    assert len({tuple(c) for c in rgb[0, :3]}) == 3
    assert rgb[0, 0].sum() > 0  # disparity 0 is a colour, not black
    # default max_disp = largest valid value
    np.testing.assert_array_equal(io.colorize_disparity(disp[:, :4]), io.colorize_disparity(disp[:, :4], 20))
    assert (io.colorize_disparity(np.full((2, 2), np.nan, np.float32)) == 0).all()


def test_error_map_colours_by_kitti_criterion():
    gt = np.array([[10.0, 100.0, 0.0, 20.0]], np.float32)
    disp = np.array([[10.0, 110.0, 5.0, np.nan]], np.float32)
    valid = np.array([[True, True, False, True]])
    img = io.error_map(disp, gt, valid, dilate=False)
    assert img.dtype == np.uint8 and img.shape == (1, 4, 3)
    # error 0 -> darkest blue; error 10 on gt 100 -> min(10/3, 10/5) = 2 -> band [2, 4): orange
    assert tuple(img[0, 0]) == (49, 54, 149)
    assert tuple(img[0, 1]) == (253, 174, 97)
    assert tuple(img[0, 2]) == (0, 0, 0)  # no ground truth
    assert tuple(img[0, 3]) == (165, 0, 38)  # missing estimate = worst
    noc = np.array([[True, False, False, True]])
    half = io.error_map(disp, gt, valid, noc_valid=noc, dilate=False)
    assert tuple(half[0, 1]) == (126, 87, 48)  # occluded GT drawn at half brightness
    grown = io.error_map(disp, gt, valid)
    # the no-GT pixel takes its worst neighbour's colour; GT pixels keep theirs
    assert tuple(grown[0, 2]) == (165, 0, 38) and tuple(grown[0, 0]) == (49, 54, 149)


def test_writers_produce_readable_files(tmp_path):
    disp = np.linspace(0, 30, 12, dtype=np.float32).reshape(3, 4)
    io.write_color_disparity(tmp_path / "c.png", disp, max_disp=30)
    assert io.read_image(tmp_path / "c.png").shape == (3, 4, 3)
    io.write_error_map(tmp_path / "e.png", disp, disp + 1, np.ones((3, 4), bool))
    e = io.read_image(tmp_path / "e.png")
    assert e.shape == (3, 4, 3) and (e[1, 1] == (171, 217, 233)).all()  # 1 px: n_err 1/3 in [0.25, 0.5)
    with pytest.raises(StereoInputError, match="ground truth is 2x2"):
        io.error_map(disp, np.zeros((2, 2), np.float32), np.ones((2, 2), bool))


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
