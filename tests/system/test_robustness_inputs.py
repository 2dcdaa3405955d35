"""Bad inputs through the CLI and the Python API: every bad image, data folder, disparity range
and configuration key gets one clear line and its exit code, and nothing is written."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

import stereojax
from stereojax import ConfigError, StereoInputError
from stereojax.data import io

from ..helpers import fake_kitti as _fake_kitti, shifted_pair as _shifted_pair
from ..robustness_helpers import FAST, _check_complete, _cli, _one_line, _record, _write_pair


# ---- bad files, through the CLI ----------------------------------------------------------------

@pytest.mark.parametrize("case, make, match", [
    ("missing file", lambda p: p, "no such file"),
    ("directory instead of file", lambda p: p.mkdir() or p, "expected a file, found a folder"),
    ("zero-byte .png", lambda p: p.write_bytes(b"") or p, "the file is empty (0 bytes)"),
    ("truncated .png", "truncate", "truncated PNG (no IEND chunk)"),
    ("text file named .png", lambda p: p.write_text("not an image\n") or p, "not a decodable image"),
    ("JPEG data named .png, truncated", "jpeg", "truncated JPEG"),
])
def test_predict_bad_image_files(pair, tmp_path, capsys, case, make, match):
    lp, rp = pair
    bad = tmp_path / "bad.png"
    if make == "truncate":
        bad.write_bytes(lp.read_bytes()[: len(lp.read_bytes()) * 2 // 3])
    elif make == "jpeg":
        ok, buf = cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 256, (48, 80), dtype=np.uint8))
        bad.write_bytes(buf.tobytes()[: len(buf) // 2])
    else:
        make(bad)
    out = tmp_path / "out"
    code, _, err = _cli(["predict", bad, rp, "--out", out, *FAST], capsys, case)
    line = _one_line(err)
    assert err.count("\n") == 1                            # predict: nothing else on stderr
    assert code == 2 and match in line and "bad.png" in line, line
    assert not out.exists()                                # the failed run made no empty folder


def test_predict_size_mismatch(tmp_path, capsys):
    lp, _ = _write_pair(tmp_path / "a", h=48, w=80)
    _, rp = _write_pair(tmp_path / "b", h=40, w=80)
    code, _, err = _cli(["predict", lp, rp, "--out", tmp_path / "out", *FAST], capsys, "left/right size mismatch")
    assert code == 2 and "left is 80x48 but right is 80x40" in _one_line(err)


def test_colour_grey_mix_is_accepted_and_reported(tmp_path, capsys):
    lp, rp = _write_pair(tmp_path / "g")
    lc, _ = _write_pair(tmp_path / "c", colour_left=True)
    code, _, err = _cli(["predict", lc, rp, "--out", tmp_path / "mix", *FAST, "--check-rectified", "off"], capsys,
                        "colour/grey mix")
    assert code == 0
    assert err.count("\n") == 1 and "Traceback" not in err     # one line
    line = err.strip()
    assert "warning: left is colour uint8 but right is grey uint8; both converted to grey" in line
    code, _, _ = _cli(["predict", lp, rp, "--out", tmp_path / "grey", *FAST], capsys)
    assert code == 0
    # the colour image is grey repeated: converted, it is the same grey image
    assert (tmp_path / "mix" / "disparity.png").read_bytes() == (tmp_path / "grey" / "disparity.png").read_bytes()
    # Python API: an InputWarning says so
    left, right = _shifted_pair(4, h=48, w=80)
    with pytest.warns(stereojax.InputWarning, match="colour uint8 but right is grey"):
        stereojax.disparity(np.repeat(left[..., None], 3, -1), right, stereojax.preset("census", 16))


def test_16bit_and_float_inputs(tmp_path, capsys):
    lp, rp = _write_pair(tmp_path / "u8")
    l16, r16 = _write_pair(tmp_path / "u16", left_dtype=np.uint16)
    assert io.read_image(l16).dtype == np.uint16
    code, _, err = _cli(["predict", l16, r16, "--out", tmp_path / "o16", *FAST, "--check-rectified", "off"], capsys)
    assert code == 0 and err.strip() == ""
    code, _, _ = _cli(["predict", lp, rp, "--out", tmp_path / "o8", *FAST], capsys)
    assert code == 0
    # v16 = 257 * v8 is the same grey level: the same disparity map
    assert (tmp_path / "o16" / "disparity.png").read_bytes() == (tmp_path / "o8" / "disparity.png").read_bytes()
    left, right = _shifted_pair(4, h=48, w=80)
    cfg = stereojax.preset("census", 16)
    ref = stereojax.disparity(left, right, cfg)
    for dtype in (np.float32, np.float64):
        for scale in (1 / 255, 1.0):                 # 0..1 and 0..255 float images
            got = stereojax.disparity(left.astype(dtype) * scale, right.astype(dtype) * scale, cfg)
            assert got.shape == ref.shape
            assert np.mean(np.abs(got - ref) < 0.5) > 0.99, (dtype, scale)


@pytest.mark.parametrize("value, match", [
    (np.nan, r"contains 1 NaN or infinite value\(s\) \(first at row 5, column 7\)"),
    (np.inf, r"contains 1 NaN or infinite value\(s\)"),
    (-np.inf, r"contains 1 NaN or infinite value\(s\)"),
    (300.0, r"float image must have intensities in \[0, 1\] or \[0, 255\], found \[0, 300\]"),
    (-1.0, r"found \[-1, 1\]"),
])
def test_float_images_with_nan_inf_or_out_of_range(value, match):
    left = np.random.default_rng(0).random((48, 80)).astype(np.float32)
    left[0, 0], left[1, 1] = 0.0, 1.0
    bad = left.copy()
    bad[5, 7] = value
    with pytest.raises(StereoInputError, match=match) as exc:
        stereojax.disparity(left, bad, stereojax.preset("census", 16))
    assert str(exc.value).startswith("right ")
    _record(f"float image with {value}", "StereoInputError", str(exc.value))


def test_image_smaller_than_the_windows(tmp_path, capsys):
    lp, rp = _write_pair(tmp_path / "s", h=8, w=80)
    code, _, err = _cli(["predict", lp, rp, "--out", tmp_path / "o", *FAST], capsys,
                        "image smaller than the aggregation window")
    assert code == 2 and "image is 80x8, smaller than the 11x11 window the configuration needs" in _one_line(err)
    # smaller than the learned network's 9x9 patch (and every window)
    tiny = np.zeros((6, 6), np.uint8)
    with pytest.raises(StereoInputError, match="smaller than the 11x11 window"):
        stereojax.disparity(tiny, tiny, stereojax.preset("census", 2))


def test_training_images_too_small_for_the_patch(tmp_path, capsys):
    root = tmp_path / "k" / "training"
    for sub in ("image_2", "image_3", "disp_noc_0"):
        (root / sub).mkdir(parents=True)
    io.write_png(root / "image_2" / "000000_10.png", np.zeros((6, 8), np.uint8))
    io.write_png(root / "image_3" / "000000_10.png", np.zeros((6, 8), np.uint8))
    io.write_kitti_disparity(root / "disp_noc_0" / "000000_10.png", np.full((6, 8), 2.0, np.float32))
    code, _, err = _cli(["train", "--data", root, "--frames", "0", "--preset", "tiny", "--out", tmp_path / "run"],
                        capsys, "training images smaller than the patch")
    assert code == 2 and "no ground-truth pixel leaves room for a 9x9 patch" in _one_line(err)
    assert not (tmp_path / "run" / "checkpoint.msgpack").exists()


@pytest.mark.parametrize("case, value, code, match", [
    ("max disparity 0", "0", 3, "max_disp must be a positive integer, got 0"),
    ("max disparity negative", "-5", 3, "max_disp must be a positive integer, got -5"),
    ("max disparity non-integer", "1.5", 2, "argument --max-disp: invalid int value: '1.5'"),
    ("max disparity >= width", "80", 2, "max_disp must be smaller than the image width 80, got 80"),
])
def test_max_disparity_out_of_range(pair, tmp_path, capsys, case, value, code, match):
    lp, rp = pair
    out = tmp_path / "out"
    got, _, err = _cli(["predict", lp, rp, "--out", out, "--method", "census", "--max-disp", value],
                       capsys, case)
    assert got == code and match in _one_line(err), err
    assert not out.exists() or list(out.iterdir()) == []


def test_max_disparity_non_integer_python_api():
    left, right = _shifted_pair(4, h=48, w=80)
    for bad in (1.5, "16", True):
        with pytest.raises(ConfigError, match="max_disp must be a positive integer"):
            stereojax.disparity(left, right, stereojax.StereoConfig(max_disp=bad))


# ---- data folders ------------------------------------------------------------------------------

def test_gt_png_of_the_wrong_dtype(tmp_path, capsys):
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=1)
    io.write_png(root / "disp_noc_0" / "000000_10.png", np.full((48, 80), 3, np.uint8))  # 8-bit GT
    code, _, err = _cli(["evaluate", "--data", root, "--dataset", "kitti2015", *FAST, "--out", tmp_path / "e"],
                        capsys, "GT PNG of the wrong dtype (uint8)")
    line = _one_line(err)
    assert code == 2 and "is not a KITTI disparity map: expected a uint16 single-channel PNG, found uint8 80x48" in line
    assert "000000_10.png" in line


def test_kitti_folder_without_gt_predict_works_evaluate_says_what_is_missing(tmp_path, capsys):
    root = tmp_path / "nogt" / "training"
    _fake_kitti(root, n=2, with_gt=False)
    code, _, _ = _cli(["predict", root / "image_2" / "000000_10.png", root / "image_3" / "000000_10.png",
                       "--out", tmp_path / "p", *FAST], capsys)
    assert code == 0
    assert set(_check_complete(tmp_path / "p")["complete"]) == {
        "disparity.png", "disparity.pfm", "disparity_color.png", "disparity_color.json", "confidence.png", "confidence.npy", "config.json",
        "timings.json"}
    code, _, err = _cli(["evaluate", "--data", root, "--dataset", "kitti2015", *FAST, "--out", tmp_path / "e"],
                        capsys, "KITTI folder with images but no GT (evaluate)")
    assert code == 2 and "no ground truth for 2 frame(s): 000000, 000001; nothing to evaluate" in _one_line(err)


def test_empty_data_folder(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    for cmd in ("evaluate", "train"):
        argv = [cmd, "--data", tmp_path / "empty", "--dataset", "kitti2015", "--out", tmp_path / cmd]
        code, _, err = _cli(argv + (["--preset", "tiny"] if cmd == "train" else []), capsys,
                            f"empty data folder ({cmd})")
        assert code == 2 and "no kitti2015 stereo pairs in" in _one_line(err)


# ---- configuration -----------------------------------------------------------------------------

@pytest.mark.parametrize("case, cmd, text, match", [
    ("mistyped top-level key", "predict", {"max_disparity": 16}, "unknown config key 'max_disparity'; did you mean 'max_disp'?"),
    ("mistyped nested key", "predict", {"cbca": {"arm_lenght": 5}}, "did you mean 'cbca.arm_length'?"),
    ("unknown key, nothing close", "predict", {"zzz": 1}, "unknown config key 'zzz'; valid keys: ['band', 'cbca', 'cost'"),
    ("wrong value type", "predict", {"sgm": {"p1": "high"}}, "config key 'sgm.p1' must be a number, got 'high'"),
    ("mistyped training key", "train", {"bacth": 16}, "did you mean 'batch'?"),
    ("config file is not JSON", "predict", "{max_disp: 3", "config is not valid JSON"),
    ("config file is a folder", "predict", None, "cannot read config file"),
])
def test_config_keys(pair, tmp_path, capsys, case, cmd, text, match):
    cfg = tmp_path / "cfg.json"
    if text is None:
        cfg.mkdir()
    else:
        cfg.write_text(text if isinstance(text, str) else json.dumps(text))
    if cmd == "predict":
        argv = ["predict", *pair, "--out", tmp_path / "o", "--method", "census", "--max-disp", "16"]
    else:
        root = tmp_path / "k" / "training"
        _fake_kitti(root, n=1)
        argv = ["train", "--data", root, "--frames", "0", "--out", tmp_path / "o"]
    code, _, err = _cli(argv + ["--config", cfg], capsys, case)
    assert code == 3 and match in _one_line(err), err
    assert not (tmp_path / "o").exists()
