"""Your own camera from the command line (issue 54): `stereojax calibrate`, `predict --calib RAW
--rectify [--frame original]`, and `--rerun FILE.rrd`, read back with Rerun's own API."""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pytest

from stereojax.data import io
from stereojax.data.stereo_rig import Rectifier, read_rig

from ..robustness_helpers import _cli, _one_line

CENSUS = ["--method", "census", "--max-disp", "32", "--check-rectified", "off"]


@pytest.fixture
def chess(data_root):
    return data_root / "calibration" / "opencv_stereo_chessboard"


@pytest.fixture
def stereo_yaml(chess, tmp_path_factory):
    """The chessboard rig's calibration file, made by `stereojax calibrate` once per test."""
    out = tmp_path_factory.mktemp("cal") / "stereo.yaml"
    from stereojax.app.cli import main
    assert main(["calibrate", f"{chess}/left*.jpg", f"{chess}/right*.jpg", "--square", "0.025", "--out", str(out)]) == 0
    return out


def test_calibrate_writes_the_rig_and_says_what_it_used(chess, tmp_path, capsys):
    out = tmp_path / "rig.yaml"
    code, stdout, err = _cli(["calibrate", f"{chess}/left*.jpg", f"{chess}/right*.jpg", "--board", "9x6",
                              "--square", "0.025", "--out", out], capsys)
    assert code == 0, err
    assert "13 of 13 pairs" in stdout and "RMS 0.4" in stdout and str(out) in stdout
    rig, _ = read_rig(str(out))
    assert rig.rms <= 0.5 and rig.size == (640, 480)


def test_calibrate_names_the_dropped_pairs_and_warns_below_eight(chess, tmp_path, capsys):
    """Five pairs of the rig plus one whose left view has no board (a right view in its place)."""
    left, right = tmp_path / "L", tmp_path / "R"
    left.mkdir(), right.mkdir()
    for i in ("01", "02", "03", "04", "05"):
        shutil.copy(chess / f"left{i}.jpg", left / f"{i}.jpg")
        shutil.copy(chess / f"right{i}.jpg", right / f"{i}.jpg")
    blank = np.full((480, 640), 128, np.uint8)
    io.write_png(left / "06.png", blank)
    shutil.copy(chess / "right06.jpg", right / "06.jpg")
    code, stdout, err = _cli(["calibrate", left, right, "--square", "0.025", "--out", tmp_path / "s.yaml"], capsys)
    assert code == 0, err
    assert "dropped 06.png / 06.jpg: no 9x6 board in the left view" in err
    assert "only 5 usable pairs (fewer than 8)" in err
    assert "5 of 6 pairs" in stdout


@pytest.mark.parametrize("argv, expected", [
    (["--board", "9"], "--board takes the inner corners as COLSxROWS"),
    (["--board", "7x5"], "found in both views of only 0 of 13 pairs"),
    (["--square", "-1"], "--square must be a positive length"),
    (["--out", "rig.txt"], "--out must end in .yaml"),
])
def test_calibrate_bad_input_is_one_line_and_writes_nothing(chess, tmp_path, capsys, monkeypatch, argv, expected):
    monkeypatch.chdir(tmp_path)
    base = ["calibrate", f"{chess}/left*.jpg", f"{chess}/right*.jpg"]
    if "--out" not in argv:
        argv = argv + ["--out", "stereo.yaml"]
    code, _, err = _cli(base + argv, capsys)
    assert code != 0
    assert expected in _one_line(err)
    assert list(tmp_path.iterdir()) == []


def test_a_raw_calibration_without_rectify_and_a_rectified_one_with_it_are_refused(chess, stereo_yaml, tmp_path,
                                                                                    capsys, data_root):
    pair = [chess / "left01.jpg", chess / "right01.jpg"]
    code, _, err = _cli(["predict", *pair, "--calib", stereo_yaml, "--out", tmp_path / "a", *CENSUS], capsys)
    assert code != 0 and "add --rectify" in _one_line(err)
    midd = data_root / "middlebury" / "Motorcycle_MiddEval3Q" / "calib.txt"
    code, _, err = _cli(["predict", *pair, "--calib", midd, "--rectify", "--out", tmp_path / "b", *CENSUS], capsys)
    assert code != 0 and "--rectify needs a raw stereo calibration" in _one_line(err)
    code, _, err = _cli(["predict", *pair, "--rectify", "--out", tmp_path / "c", *CENSUS], capsys)
    assert code != 0 and "--rectify needs --calib" in _one_line(err)
    assert not any((tmp_path / n).exists() for n in "abc")


def test_a_pair_of_another_size_is_refused_in_one_line(stereo_yaml, tmp_path, capsys):
    img = np.zeros((240, 320), np.uint8)
    io.write_png(tmp_path / "l.png", img)
    io.write_png(tmp_path / "r.png", img)
    code, _, err = _cli(["predict", tmp_path / "l.png", tmp_path / "r.png", "--calib", stereo_yaml, "--rectify",
                         "--out", tmp_path / "o", *CENSUS], capsys)
    assert code != 0 and "320x240 but the calibration is for 640x480" in _one_line(err)
    assert not (tmp_path / "o").exists()


def test_rectify_writes_the_rectified_pair_and_points_in_either_frame(chess, stereo_yaml, tmp_path, capsys):
    pair = [chess / "left03.jpg", chess / "right03.jpg"]
    outs = {}
    for frame in ("rectified", "original"):
        out = tmp_path / frame
        code, stdout, err = _cli(["predict", *pair, "--calib", stereo_yaml, "--rectify", "--frame", frame, "--ply",
                                  "--out", out, *CENSUS], capsys)
        assert code == 0, err
        outs[frame] = out
    out = outs["rectified"]
    for name in ("left_rectified.png", "right_rectified.png", "rectification.json", "depth.npy", "points.ply"):
        assert (out / name).is_file(), name
    rect = Rectifier(read_rig(str(stereo_yaml))[0])
    want_l, want_r = rect.rectify(io.read_image(pair[0]), io.read_image(pair[1]))
    assert np.array_equal(io.read_image(out / "left_rectified.png"), want_l)
    assert np.array_equal(io.read_image(out / "right_rectified.png"), want_r)
    info = json.loads((out / "rectification.json").read_text())
    np.testing.assert_allclose(info["P1"], rect.P1)
    assert info["points_frame"] == "rectified"
    a, b = _ply_points(outs["rectified"] / "points.ply"), _ply_points(outs["original"] / "points.ply")
    assert a.shape == b.shape and len(a) > 1000
    np.testing.assert_allclose(b, a @ rect.R1, atol=1e-4)          # R1^T x: the raw left camera's frame
    assert np.abs(b - a).max() > 1e-3                              # and not the same points


def _ply_points(path):
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    n = int([ln for ln in head.decode().splitlines() if ln.startswith("element vertex")][0].split()[-1])
    rec = np.dtype([("xyz", "<f4", 3), ("rgb", "u1", 3)])
    return np.frombuffer(body, rec, count=n)["xyz"].astype(np.float64)


def test_rerun_log_reads_back_with_rerun(chess, stereo_yaml, tmp_path, capsys):
    pytest.importorskip("rerun", reason="rerun-sdk (the viewer extra) is not installed")
    from rerun.chunk import RrdReader

    left, right = tmp_path / "L", tmp_path / "R"
    left.mkdir(), right.mkdir()
    for i in ("01", "02", "03"):
        shutil.copy(chess / f"left{i}.jpg", left / f"f{i}.jpg")
        shutil.copy(chess / f"right{i}.jpg", right / f"f{i}.jpg")
    rrd = tmp_path / "seq.rrd"
    code, stdout, err = _cli(["predict", left, right, "--calib", stereo_yaml, "--rectify", "--sequence",
                              "--out", tmp_path / "out", "--rerun", rrd, *CENSUS], capsys)
    assert code == 0, err
    assert f"-> {rrd}" in stdout
    chunks = list(RrdReader(rrd).stream())
    entities = {c.entity_path for c in chunks}
    assert {"/world/camera", "/world/camera/image", "/world/camera/depth", "/world/disparity", "/world/confidence",
            "/world/points", "/events"} <= entities
    depth_rows = []
    for c in chunks:
        if c.entity_path == "/world/camera/depth":
            rb = c.to_record_batch()
            frames = rb.column("frame").to_pylist()
            for f, buf in zip(frames, rb.column("DepthImage:buffer").to_pylist()):
                depth_rows.append((f, np.frombuffer(bytes(buf[0]), np.float32)))
    assert sorted(f for f, _ in depth_rows) == [0, 1, 2]
    for f, values in depth_rows:
        want = np.load(tmp_path / "out" / f"f0{f + 1}" / "depth.npy")
        np.testing.assert_array_equal(values.reshape(want.shape), want)
    texts = [t for c in chunks if c.entity_path == "/events"
             for t in c.to_record_batch().column("TextLog:text").to_pylist()]
    assert len(texts) == 3 and "no prior (first frame)" in str(texts[0])


def test_rerun_without_the_package_is_one_line_with_the_install_command(chess, stereo_yaml, tmp_path, capsys,
                                                                         monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)           # import rerun -> ImportError
    code, _, err = _cli(["predict", chess / "left01.jpg", chess / "right01.jpg", "--calib", stereo_yaml, "--rectify",
                         "--out", tmp_path / "o", "--rerun", tmp_path / "x.rrd", *CENSUS], capsys)
    line = _one_line(err)
    assert code != 0 and "rerun-sdk" in line and 'pip install "stereojax[viewer]"' in line
    assert not (tmp_path / "o").exists()


def test_a_calibration_that_does_not_rectify_the_images_is_warned_about(chess, stereo_yaml, tmp_path, capsys):
    """The rig's R turned by 1.5 degrees about x: the rows of the 'rectified' pair stay apart."""
    import cv2

    from stereojax.data.stereo_rig import StereoRig, write_rig

    rig = read_rig(str(stereo_yaml))[0]
    turn, _ = cv2.Rodrigues(np.radians([1.5, 0.0, 0.0]))
    write_rig(tmp_path / "off.yaml", StereoRig(rig.K1, rig.D1, rig.K2, rig.D2, turn @ rig.R, rig.T, rig.size))
    code, _, err = _cli(["predict", chess / "left01.jpg", chess / "right01.jpg", "--calib", tmp_path / "off.yaml",
                         "--rectify", "--out", tmp_path / "o", "--method", "census", "--max-disp", "32"], capsys)
    assert code == 0, err
    assert "warning: the calibration does not rectify these images" in err
    code, _, err = _cli(["predict", chess / "left01.jpg", chess / "right01.jpg", "--calib", stereo_yaml,
                         "--rectify", "--out", tmp_path / "p", "--method", "census", "--max-disp", "32"], capsys)
    assert code == 0 and "does not rectify" not in err and "does not look rectified" not in err


def test_rerun_log_of_one_pair_holds_its_image_under_world(chess, stereo_yaml, tmp_path, capsys):
    """One pair logs under world/ (not a frame name), with the image it matched (not a blank)."""
    pytest.importorskip("rerun", reason="rerun-sdk (the viewer extra) is not installed")
    from rerun.chunk import RrdReader

    rrd = tmp_path / "one.rrd"
    code, _, err = _cli(["predict", chess / "left02.jpg", chess / "right02.jpg", "--calib", stereo_yaml, "--rectify",
                         "--out", tmp_path / "o", "--rerun", rrd, *CENSUS], capsys)
    assert code == 0, err
    chunks = {c.entity_path: c.to_record_batch() for c in RrdReader(rrd).stream()}
    buf = chunks["/world/camera/image"].column("Image:buffer").to_pylist()[0]
    want = io.read_image(tmp_path / "o" / "left_rectified.png")
    assert np.array_equal(np.frombuffer(bytes(buf[0]), np.uint8), want.reshape(-1))
