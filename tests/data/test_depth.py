"""stereojax.data.depth: disparity -> depth, depth files, point clouds and PLY files."""

import cv2
import numpy as np
import pytest

from stereojax.data import depth
from stereojax.data.datasets import Calibration
from stereojax.errors import OutputError, StereoInputError


def test_disparity_to_depth_by_hand():
    d = np.array([[10, 0, -1, np.nan, 0.4, 20, np.inf]], np.float32)
    z = depth.disparity_to_depth(d, baseline=0.5, focal=100)
    assert z.dtype == np.float32
    np.testing.assert_allclose(z, [[5, 0, 0, 0, 0, 2.5, 0]])
    # Middlebury: Z = B f / (d + doffs)
    np.testing.assert_allclose(depth.disparity_to_depth(np.array([[10.0]]), 0.5, 100, doffs=10), [[2.5]])
    np.testing.assert_allclose(depth.disparity_to_depth(np.array([[1.0]]), 0.5, 100, min_disp=2), [[0]])


def test_disparity_to_depth_rejects_bad_calibration():
    with pytest.raises(StereoInputError, match="baseline"):
        depth.disparity_to_depth(np.ones((2, 2)), 0, 100)
    with pytest.raises(StereoInputError, match="focal"):
        depth.disparity_to_depth(np.ones((2, 2)), 0.5, -3)
    with pytest.raises(StereoInputError, match="2-D"):
        depth.disparity_to_depth(np.ones((2, 2, 2)), 0.5, 100)


def test_write_depth_png_and_npy(tmp_path):
    z = np.array([[1.5, 0.0, np.nan], [300.0, 2.0 / 256, -4.0]], np.float32)
    depth.write_depth(tmp_path / "z.png", z)
    raw = cv2.imread(str(tmp_path / "z.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw, [[384, 0, 0], [65535, 2, 0]])  # 0 = unknown, clipped at 256 m
    depth.write_depth(tmp_path / "z.npy", z)
    got = np.load(tmp_path / "z.npy")
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, z)
    with pytest.raises(OutputError, match=r"\.png .* or \.npy"):
        depth.write_depth(tmp_path / "z.tiff", z)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["z.npy", "z.png"]


def test_point_cloud_by_hand():
    disp = np.array([[10, 10, 0],
                     [20, 10, 10]], np.float32)
    image = np.arange(18, dtype=np.uint8).reshape(2, 3, 3)
    calib = Calibration(baseline=0.5, focal=100, cx=1.0, cy=0.0)
    xyz, rgb = depth.point_cloud(disp, image, calib)
    assert xyz.dtype == np.float32 and rgb.dtype == np.uint8 and xyz.shape == (5, 3)
    # Z = 0.5 * 100 / d; X = (u - 1) Z / 100; Y = v Z / 100
    np.testing.assert_allclose(xyz, [[-0.05, 0, 5], [0, 0, 5],
                                     [-0.025, 0.025, 2.5], [0, 0.05, 5], [0.05, 0.05, 5]], atol=1e-6)
    np.testing.assert_array_equal(rgb, image.reshape(-1, 3)[[0, 1, 3, 4, 5]])
    # default principal point = image centre ((W-1)/2, (H-1)/2) = (1, 0.5); grey images repeat
    xyz2, rgb2 = depth.point_cloud(disp, image[..., 0], Calibration(baseline=0.5, focal=100))
    np.testing.assert_allclose(xyz2[0], [-0.05, -0.025, 5], atol=1e-6)
    assert (rgb2[:, 0] == rgb2[:, 2]).all()
    xyz3, _ = depth.point_cloud(disp, image, calib, max_depth=3)
    assert xyz3.shape == (1, 3)


def test_point_cloud_errors():
    with pytest.raises(StereoInputError, match="calibration"):
        depth.point_cloud(np.ones((2, 2)), np.zeros((2, 2), np.uint8), None)
    with pytest.raises(StereoInputError, match="image is 2x3x3"):
        depth.point_cloud(np.ones((2, 2)), np.zeros((3, 2, 3), np.uint8), Calibration(0.5, 100))


def _read_ply(path):
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode("ascii").splitlines(), data[end:]


def test_write_ply_binary_and_ascii(tmp_path):
    xyz = np.array([[0, 1, 2], [-1.5, 0.25, 10]], np.float32)
    rgb = np.array([[255, 0, 0], [1, 2, 3]], np.uint8)
    depth.write_ply(tmp_path / "b.ply", xyz, rgb)
    header, body = _read_ply(tmp_path / "b.ply")
    assert header[1] == "format binary_little_endian 1.0" and "element vertex 2" in header
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                     ("r", "u1"), ("g", "u1"), ("b", "u1")])
    np.testing.assert_array_equal(np.stack([rec["x"], rec["y"], rec["z"]], 1), xyz)
    np.testing.assert_array_equal(np.stack([rec["r"], rec["g"], rec["b"]], 1), rgb)

    depth.write_ply(tmp_path / "a.ply", xyz, rgb, binary=False)
    header, body = _read_ply(tmp_path / "a.ply")
    assert header[1] == "format ascii 1.0"
    np.testing.assert_allclose(np.loadtxt(body.decode().splitlines()), np.hstack([xyz, rgb]))

    depth.write_ply(tmp_path / "n.ply", xyz)  # no colours
    header, body = _read_ply(tmp_path / "n.ply")
    assert not any("red" in h for h in header) and len(body) == 2 * 12


def test_write_ply_rejects_bad_shapes(tmp_path):
    with pytest.raises(StereoInputError, match=r"\[N, 3\]"):
        depth.write_ply(tmp_path / "x.ply", np.zeros((4, 2)))
    with pytest.raises(StereoInputError, match="colours"):
        depth.write_ply(tmp_path / "x.ply", np.zeros((4, 3)), np.zeros((3, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_builtin_sample_depth_is_plausible():
    from stereojax.data import load_builtin_sample

    s = load_builtin_sample()
    z = depth.disparity_to_depth(s.gt, s.calib.baseline, s.calib.focal, s.calib.doffs)
    valid = z > 0
    np.testing.assert_array_equal(valid, s.gt_valid)
    # Middlebury Motorcycle: the scene lies roughly 2 to 5 m from the cameras
    assert 1.5 < np.percentile(z[valid], 5) and np.percentile(z[valid], 95) < 5.5
