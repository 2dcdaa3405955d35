"""Raw stereo rigs: calibration from the shared chessboard views, the calibration files stereojax
reads, and rectification (issue 54)."""

import json

import cv2
import numpy as np
import pytest

from stereojax.data.calibration import rectified_or_raw
from stereojax.data.datasets import Calibration
from stereojax.data.stereo_rig import (RawCamera, Rectifier, calibrate, find_corners, read_rig, simulate_raw_pair,
                                      write_rig)
from stereojax.errors import StereoInputError

BOARD = (9, 6)


_CALIBRATED = {}


@pytest.fixture
def chessboard(data_root):
    """(folder, rig, report) of the shared chessboard rig, calibrated once per session."""
    folder = data_root / "calibration" / "opencv_stereo_chessboard"
    if "rig" not in _CALIBRATED:
        _CALIBRATED["rig"] = calibrate(str(folder / "left*.jpg"), str(folder / "right*.jpg"), BOARD, 0.025)
    return (folder, *_CALIBRATED["rig"])


def _corner_rows(folder, report, rect=None):
    """|row difference| of every matched corner pair, raw or after ``rect``."""
    out = []
    for a, b in report.used:
        gl, gr = cv2.imread(str(folder / a), 0), cv2.imread(str(folder / b), 0)
        if rect is not None:
            gl, gr = rect.rectify(gl, gr)
        cl, cr = find_corners(gl, BOARD), find_corners(gr, BOARD)
        if cl is not None and cr is not None:
            out.append(np.abs(cl.reshape(-1, 2)[:, 1] - cr.reshape(-1, 2)[:, 1]))
    return np.concatenate(out)


def test_chessboard_calibration_and_rectification_meet_the_targets(chessboard):
    folder, rig, report = chessboard
    assert len(report.used) == 13 and not report.dropped and not report.warnings
    assert rig.rms <= 0.5
    assert rig.size == (640, 480)
    assert 0.07 < rig.baseline < 0.10          # about 3.34 squares of 25 mm
    raw = _corner_rows(folder, report)
    rect = _corner_rows(folder, report, Rectifier(rig))
    assert np.median(raw) > 3.0                # the raw views are not rectified
    assert np.median(rect) <= 0.3 and np.percentile(rect, 95) <= 0.7
    assert rect.size >= 0.9 * raw.size         # the board is still found after rectification


@pytest.mark.parametrize("suffix", ["yaml", "xml", "json"])
def test_written_calibration_reads_back(chessboard, tmp_path, suffix):
    rig = chessboard[1]
    write_rig(tmp_path / f"stereo.{suffix}", rig)
    back, source = read_rig(str(tmp_path / f"stereo.{suffix}"))
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        np.testing.assert_allclose(getattr(back, name), getattr(rig, name), rtol=1e-9, atol=1e-12)
    assert back.size == rig.size and back.rms == pytest.approx(rig.rms)


def test_opencv_stereo_calibrate_output_with_m1_m2(chessboard, tmp_path):
    """OpenCV's own sample writes the camera matrices as M1 and M2."""
    rig = chessboard[1]
    fs = cv2.FileStorage(str(tmp_path / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", rig.K1), ("D1", rig.D1.reshape(1, -1)), ("M2", rig.K2), ("D2", rig.D2.reshape(1, -1)),
                       ("R", rig.R), ("T", rig.T.reshape(3, 1))):
        fs.write(key, value)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.release()
    back, _ = read_rig(str(tmp_path / "intrinsics.yml"))
    np.testing.assert_allclose(back.K2, rig.K2)


def test_missing_entries_are_named(chessboard, tmp_path):
    rig = chessboard[1]
    path = tmp_path / "partial.json"
    path.write_text(json.dumps({"K1": rig.K1.tolist(), "D1": rig.D1.tolist(), "K2": rig.K2.tolist(),
                                "image_width": 640, "image_height": 480}))
    with pytest.raises(StereoInputError, match=r"missing D2, R, T"):
        read_rig(str(path))


def _ros_file(path, k, d, r, p, size):
    path.write_text(
        f"image_width: {size[0]}\nimage_height: {size[1]}\ncamera_name: cam\ndistortion_model: plumb_bob\n"
        + "".join(f"{key}:\n  rows: {m.shape[0]}\n  cols: {m.shape[1]}\n  data: {m.reshape(-1).tolist()}\n"
                  for key, m in (("camera_matrix", k), ("distortion_coefficients", d.reshape(1, -1)),
                                 ("rectification_matrix", r), ("projection_matrix", p))))


def test_ros_camera_info_pair_rectifies_as_given(chessboard, tmp_path):
    """A pair of ROS camera_info files keeps its own R and P: the same rectified images."""
    folder, rig, _ = chessboard
    rect = Rectifier(rig)
    _ros_file(tmp_path / "left.yaml", rig.K1, rig.D1, rect.R1, rect.P1, rig.size)
    _ros_file(tmp_path / "right.yaml", rig.K2, rig.D2, rect.R2, rect.P2, rig.size)
    ros, source = read_rig(f"{tmp_path / 'left.yaml'},{tmp_path / 'right.yaml'}")
    assert "ROS" in source
    np.testing.assert_allclose(ros.R, rig.R, atol=1e-6)
    np.testing.assert_allclose(ros.T / np.linalg.norm(ros.T), rig.T / np.linalg.norm(rig.T), atol=1e-6)
    gl, gr = cv2.imread(str(folder / "left01.jpg"), 0), cv2.imread(str(folder / "right01.jpg"), 0)
    a, b = Rectifier(ros).rectify(gl, gr), rect.rectify(gl, gr)
    assert np.abs(a[0].astype(int) - b[0]).max() <= 1 and np.abs(a[1].astype(int) - b[1]).max() <= 1
    assert Rectifier(ros).calibration.baseline == pytest.approx(rect.calibration.baseline, rel=1e-6)
    with pytest.raises(StereoInputError, match="give both cameras"):
        read_rig(str(tmp_path / "left.yaml"))


def test_kalibr_camchain(chessboard, tmp_path):
    rig = chessboard[1]
    tr = np.eye(4)
    tr[:3, :3], tr[:3, 3] = rig.R, rig.T

    def cam(k, d):
        return (f"  camera_model: pinhole\n  intrinsics: {[float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])]}\n"
                f"  distortion_model: radtan\n  distortion_coeffs: {d[:4].tolist()}\n  resolution: [640, 480]\n")
    (tmp_path / "camchain.yaml").write_text("cam0:\n" + cam(rig.K1, rig.D1) + "cam1:\n" + cam(rig.K2, rig.D2)
                                            + f"  T_cn_cnm1: {tr.tolist()}\n")
    back, source = read_rig(str(tmp_path / "camchain.yaml"))
    assert "Kalibr" in source
    np.testing.assert_allclose(back.R, rig.R)
    np.testing.assert_allclose(back.T, rig.T)
    np.testing.assert_allclose(back.D1, rig.D1[:4])


def test_raw_and_rectified_calibrations_are_told_apart(chessboard, tmp_path, data_root):
    write_rig(tmp_path / "stereo.yaml", chessboard[1])
    with pytest.raises(StereoInputError, match="add --rectify"):
        rectified_or_raw(tmp_path / "stereo.yaml", rectify=False)
    rect, _ = rectified_or_raw(tmp_path / "stereo.yaml", rectify=True)
    assert isinstance(rect, Rectifier)
    middlebury = data_root / "middlebury" / "Motorcycle_MiddEval3Q" / "calib.txt"
    assert rectified_or_raw(middlebury, rectify=False)[0] is None
    with pytest.raises(StereoInputError, match="--rectify needs a raw stereo calibration"):
        rectified_or_raw(middlebury, rectify=True)


def test_images_of_another_size_are_refused(chessboard):
    rect = Rectifier(chessboard[1])
    with pytest.raises(StereoInputError, match=r"320x240 but the calibration is for 640x480"):
        rect.rectify(np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint8))


def test_to_original_inverts_the_rectifying_rotation(chessboard):
    rect = Rectifier(chessboard[1])
    raw_points = np.array([[0.1, -0.2, 2.0], [1.0, 0.5, 7.0]])
    np.testing.assert_allclose(rect.to_original(raw_points @ rect.R1.T), raw_points, atol=1e-12)


def test_simulated_raw_pair_rectifies_back_to_the_scene(data_root):
    """A KITTI pair made raw on purpose: stereojax's rectification puts the GT's points back on
    one row in both views, at the GT disparity scaled to the new focal length."""
    from stereojax.data.datasets import load_kitti2015

    s = load_kitti2015(data_root / "kitti2015" / "training", "000021", "noc")
    calib = Calibration(baseline=0.5372, focal=721.5377, cx=609.5593, cy=172.854)
    cam_l = RawCamera(710.0, 712.0, 615.0, 180.0, (-0.12, 0.05, 0.0008, -0.0005, 0.0), (0.6, -0.8, 0.3))
    cam_r = RawCamera(730.0, 728.0, 600.0, 168.0, (-0.09, 0.02, -0.0006, 0.0004, 0.0), (-0.4, 0.5, -0.2))
    raw_l, raw_r, rig, r_l = simulate_raw_pair(s.left, s.right, calib, cam_l, cam_r)
    rect = Rectifier(rig)
    c = rect.calibration
    assert c.baseline == pytest.approx(calib.baseline, rel=1e-9)
    # GT points -> raw left frame -> stereojax's rectified left and right views
    ys, xs = np.nonzero(s.gt_valid)
    z = calib.baseline * calib.focal / s.gt[ys, xs]
    pts = np.stack([(xs - calib.cx) * z / calib.focal, (ys - calib.cy) * z / calib.focal, z], -1) @ r_l
    left = (pts @ rect.R1.T) @ rect.P1[:, :3].T
    right = (pts @ rect.R1.T) @ rect.P2[:, :3].T + rect.P2[:, 3]
    ul, vl = left[:, 0] / left[:, 2], left[:, 1] / left[:, 2]
    ur, vr = right[:, 0] / right[:, 2], right[:, 1] / right[:, 2]
    assert np.abs(vl - vr).max() < 1e-6                       # one row in both views
    z_new = (pts @ rect.R1.T)[:, 2]
    np.testing.assert_allclose(ul - ur, c.focal * c.baseline / z_new, rtol=1e-6)    # depth = B f / d there
    # and the images agree with it: the rectified raw left image at the GT points equals the original's
    out_l, _ = rect.rectify(raw_l, raw_r)
    grey = cv2.cvtColor(out_l, cv2.COLOR_RGB2GRAY).astype(np.float32)
    orig = cv2.cvtColor(s.left, cv2.COLOR_RGB2GRAY).astype(np.float32)
    inside = (ul > 5) & (ul < grey.shape[1] - 6) & (vl > 5) & (vl < grey.shape[0] - 6)
    u, v = ul[inside], vl[inside]
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - u0, v - v0
    got = ((1 - fv) * ((1 - fu) * grey[v0, u0] + fu * grey[v0, u0 + 1])
           + fv * ((1 - fu) * grey[v0 + 1, u0] + fu * grey[v0 + 1, u0 + 1]))
    assert inside.mean() > 0.8
    assert np.median(np.abs(got - orig[ys[inside], xs[inside]])) < 6.0


def test_predictor_and_sequence_take_raw_pairs_with_a_rectifier(chessboard, tmp_path):
    """Predictor(rectifier=) and Sequence(rectifier=) equal rectifying first; log_rerun writes them."""
    import stereojax

    folder, rig, _ = chessboard
    rect = Rectifier(rig)
    raw_l, raw_r = cv2.imread(str(folder / "left02.jpg"), 0), cv2.imread(str(folder / "right02.jpg"), 0)
    cfg = stereojax.preset("census", max_disp=32)
    want = stereojax.Predictor(cfg)(*rect.rectify(raw_l, raw_r))
    np.testing.assert_array_equal(stereojax.Predictor(cfg, rectifier=rect)(raw_l, raw_r), want)
    frame = stereojax.Sequence(cfg, rectifier=rect).push(raw_l, raw_r)
    np.testing.assert_array_equal(frame.disparity, stereojax.Sequence(cfg).push(*rect.rectify(raw_l, raw_r)).disparity)
    pytest.importorskip("rerun", reason="rerun-sdk (the viewer extra) is not installed")
    from rerun.chunk import RrdReader

    path = stereojax.log_rerun(tmp_path / "py.rrd", [dict(name="chess", left=raw_l, disparity=want,
                                                          calib=rect.calibration)])
    assert {"/world/chess/disparity", "/world/chess/camera"} <= {c.entity_path for c in RrdReader(path).stream()}
