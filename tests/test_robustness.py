"""Reliability: every bad input gets a clear one-line error and its exit code, every fault
loses nothing (atomic outputs, SIGKILL-safe training), a memory guard refuses frames that
would not fit.

Cases already covered elsewhere are listed in experiments/results/robustness.md and not
repeated here unless the CLI's exit code / message needed checking. Set
``ROBUSTNESS_LOG=file.jsonl`` to record every observed message (used to write that table).
"""

from __future__ import annotations

import errno
import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import flax.serialization as ser
import numpy as np
import pytest

import stereojax
from stereojax import (CheckpointError, ConfigError, MemoryBudgetError, StereoError,
                       StereoInputError)
from stereojax import memory
from stereojax.cli import main
from stereojax.data import io

from .helpers import fake_kitti as _fake_kitti, shifted_pair as _shifted_pair

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--max-disp", "16", "--method", "census"]


# ---- helpers -----------------------------------------------------------------------------------

def _record(case: str, code, text: str) -> None:
    log = os.environ.get("ROBUSTNESS_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps({"case": case, "code": code, "message": text.strip()}) + "\n")


def _cli(argv, capsys, case=None):
    """Run the CLI in-process; (exit code, stdout, stderr). Usage errors exit via SystemExit."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    cap = capsys.readouterr()
    if case:
        _record(case, code, cap.err)
    return code, cap.out, cap.err


def _one_line(err: str) -> str:
    """The error line: the only "error:" line, and the last line of stderr (evaluate and train
    draw progress bars on stderr before it; predict writes nothing else)."""
    assert "Traceback" not in err
    lines = [ln for ln in err.replace("\r", "\n").strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if ": error: " in ln]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    return errors[0]


def _write_pair(folder: Path, h=48, w=80, d=4, left_dtype=np.uint8, colour_left=False):
    left, right = _shifted_pair(d, h=h, w=w)
    if left_dtype == np.uint16:
        left, right = left.astype(np.uint16) * 257, right.astype(np.uint16) * 257
    if colour_left:
        left = np.repeat(left[..., None], 3, -1)
    folder.mkdir(parents=True, exist_ok=True)
    lp, rp = folder / "left.png", folder / "right.png"
    io.write_png(lp, left)
    io.write_png(rp, right)
    return lp, rp


@pytest.fixture
def pair(tmp_path):
    return _write_pair(tmp_path / "in")


_TMP_NAME = re.compile(r"^\.(?P<stem>.+)\.tmp-(?P<pid>\d+)-[0-9a-f]{8}(?P<ext>\.\w+)$")


def _check_complete(folder: Path, expected: set[str] | None = None) -> dict:
    """Every file under its final name is complete and readable; temp files (only ever left by a
    SIGKILL) are hidden, follow atomic_output's pattern and never carry a final name."""
    seen, temps = {}, []
    for p in sorted(folder.iterdir()) if folder.exists() else []:
        if p.is_dir():
            continue
        m = _TMP_NAME.match(p.name)
        if m:
            temps.append(p.name)
            continue
        assert not p.name.startswith("."), f"unexpected hidden file {p.name}"
        ext = p.suffix
        if ext == ".png":
            img = io.read_image(p)                   # checks IEND and decodes
            assert img.size > 0
        elif ext == ".json":
            json.loads(p.read_text())
        elif ext == ".npy":
            assert np.load(p).ndim == 2
        elif ext == ".pfm":
            assert io.read_pfm(p).ndim == 2                # checks the header and the body size
        elif ext == ".ply":
            data = p.read_bytes()
            head_end = data.index(b"end_header\n") + len(b"end_header\n")
            n = int(re.search(rb"element vertex (\d+)", data[:head_end]).group(1))
            assert len(data) - head_end == n * 15, "PLY body is not complete"
        else:
            raise AssertionError(f"unexpected output {p.name}")
        seen[p.name] = p.stat().st_size
    if expected is not None:
        assert set(seen) <= expected, set(seen) - expected
    return {"complete": seen, "temps": temps}


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
    assert list(out.iterdir()) == []


def test_predict_size_mismatch(tmp_path, capsys):
    lp, _ = _write_pair(tmp_path / "a", h=48, w=80)
    _, rp = _write_pair(tmp_path / "b", h=40, w=80)
    code, _, err = _cli(["predict", lp, rp, "--out", tmp_path / "out", *FAST], capsys, "left/right size mismatch")
    assert code == 2 and "left is 48x80 but right is 40x80" in _one_line(err)


def test_colour_grey_mix_is_accepted_and_reported(tmp_path, capsys):
    lp, rp = _write_pair(tmp_path / "g")
    lc, _ = _write_pair(tmp_path / "c", colour_left=True)
    code, _, err = _cli(["predict", lc, rp, "--out", tmp_path / "mix", *FAST], capsys, "colour/grey mix")
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
    code, _, err = _cli(["predict", l16, r16, "--out", tmp_path / "o16", *FAST], capsys)
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
    assert code == 2 and "image is 8x80, smaller than the 11x11 window the configuration needs" in _one_line(err)
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
    assert code == 2 and "is not a KITTI disparity map: expected a uint16 single-channel PNG, found uint8 48x80" in line
    assert "000000_10.png" in line


def test_kitti_folder_without_gt_predict_works_evaluate_says_what_is_missing(tmp_path, capsys):
    root = tmp_path / "nogt" / "training"
    _fake_kitti(root, n=2, with_gt=False)
    code, _, _ = _cli(["predict", root / "image_2" / "000000_10.png", root / "image_3" / "000000_10.png",
                       "--out", tmp_path / "p", *FAST], capsys)
    assert code == 0
    assert set(_check_complete(tmp_path / "p")["complete"]) == {
        "disparity.png", "disparity.pfm", "disparity_color.png", "config.json", "timings.json"}
    code, _, err = _cli(["evaluate", "--data", root, "--dataset", "kitti2015", *FAST, "--out", tmp_path / "e"],
                        capsys, "KITTI folder with images but no GT (evaluate)")
    assert code == 2 and "no noc ground truth for 2 frame(s): 000000, 000001; nothing to evaluate" in _one_line(err)


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
    ("unknown key, nothing close", "predict", {"zzz": 1}, "unknown config key 'zzz'; valid keys: ['cbca', 'cost'"),
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
    assert list((tmp_path / "o").iterdir()) == []


# ---- checkpoints -------------------------------------------------------------------------------

def _shipped():
    from stereojax.models import shipped_weights

    try:
        return shipped_weights("kitti2015")
    except CheckpointError:
        pytest.skip("no shipped weights")


def test_truncated_and_foreign_checkpoints(pair, tmp_path, capsys):
    good = _shipped().read_bytes()
    trunc = tmp_path / "trunc.msgpack"
    trunc.write_bytes(good[: len(good) // 2])
    # another architecture: the arrays of the shipped network under a config that says 32 features
    payload = ser.msgpack_restore(good)
    cfg = json.loads(payload["config"])
    cfg["net"]["features"] = 32
    payload["config"] = json.dumps(cfg)
    other = tmp_path / "other.msgpack"
    other.write_bytes(ser.msgpack_serialize(payload))
    notckpt = tmp_path / "not.msgpack"
    notckpt.write_bytes(ser.msgpack_serialize({"weights": [1, 2, 3]}))
    for case, path, match in [
        ("truncated checkpoint", trunc, "is corrupt or truncated"),
        ("checkpoint from another architecture", other, "has a parameter of shape (64,) where the model has (32,)"),
        ("msgpack that is not a checkpoint", notckpt, "is not a stereojax checkpoint"),
        ("checkpoint path is a folder", tmp_path, "is not a file"),
    ]:
        code, _, err = _cli(["predict", *pair, "--out", tmp_path / "o", "--max-disp", "16", "--method", "learned",
                             "--weights", path], capsys, case)
        assert code == 4 and match in _one_line(err), (case, err)
    assert list((tmp_path / "o").iterdir()) == []


def test_resume_with_another_architecture(tmp_path, capsys):
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=1)
    base = ["train", "--data", root, "--frames", "0", "--preset", "tiny", "--steps", "4", "--out", tmp_path / "run"]
    code, _, _ = _cli(base, capsys)
    assert code == 0
    before = (tmp_path / "run" / "checkpoint.msgpack").read_bytes()
    code, _, err = _cli(base + ["--resume", "--head", "uniform"], capsys, "resume with another architecture")
    assert code == 3 and "cannot resume" in _one_line(err) and "another training config (net.head = 'downsize' there, 'uniform' here)" in err
    assert (tmp_path / "run" / "checkpoint.msgpack").read_bytes() == before     # untouched


# ---- outputs: unwritable folder, full disk -----------------------------------------------------

def test_output_folder_is_a_file_or_not_writable(pair, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = _cli(["predict", *pair, "--out", blocker, *FAST], capsys, "output folder is a file")
    assert code == 5 and "output folder" in _one_line(err)
    assert blocker.read_text() == "x"
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            code, _, err = _cli(["predict", *pair, "--out", ro, *FAST], capsys, "output folder not writable")
            assert code == 5 and "is not writable" in _one_line(err)
        finally:
            ro.chmod(0o700)


def _full_disk(monkeypatch, fail_from: int):
    """Make the fail_from-th and later writes of an output (temp file) write half its data,
    then raise OSError(ENOSPC), as a full disk does."""
    calls = {"n": 0}
    orig_bytes, orig_text = Path.write_bytes, Path.write_text

    def fail(path, data, orig):
        if ".tmp-" not in path.name:
            return orig(path, data)
        calls["n"] += 1
        if calls["n"] < fail_from:
            return orig(path, data)
        orig(path, data[: len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(Path, "write_bytes", lambda self, data: fail(self, data, orig_bytes))
    monkeypatch.setattr(Path, "write_text", lambda self, data, *a, **k: fail(self, data, orig_text))
    return calls


@pytest.mark.parametrize("fail_from, survivors", [
    (1, set()),                                           # the first output already fails
    # config.json fails: the PNGs and the PFM (written through a file object, not counted) are complete
    (3, {"disparity.png", "disparity.pfm", "disparity_color.png"}),
])
def test_full_disk_one_line_exit_5_no_partial_file(pair, tmp_path, capsys, monkeypatch, fail_from, survivors):
    out = tmp_path / "out"
    calls = _full_disk(monkeypatch, fail_from)
    code, _, err = _cli(["predict", *pair, "--out", out, *FAST], capsys, f"full disk (ENOSPC) at write {fail_from}")
    monkeypatch.undo()
    assert calls["n"] == fail_from                        # stopped at the first failure
    assert code == 5 and "No space left on device" in _one_line(err) and "cannot write" in err
    state = _check_complete(out)
    assert set(state["complete"]) == survivors and state["temps"] == []


def test_full_disk_during_training_keeps_the_last_checkpoint(tmp_path, capsys, monkeypatch):
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=1)
    out = tmp_path / "run"
    orig = Path.write_bytes
    saves = []

    def write_bytes(self, data):
        if self.suffix == ".msgpack":
            saves.append(len(data))
            if len(saves) == 2:                           # the second checkpoint (step 8) fails
                orig(self, data[:100])
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return orig(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    code, _, err = _cli(["train", "--data", root, "--frames", "0", "--preset", "tiny", "--steps", "12",
                         "--out", out], capsys, "full disk (ENOSPC) while saving a checkpoint")
    monkeypatch.undo()
    assert code == 5 and "No space left on device" in _one_line(err) and "checkpoint.msgpack" in err
    step, _ = _ckpt_step(out / "checkpoint.msgpack")
    assert step == 4                        # the last good checkpoint, intact
    assert not [p.name for p in out.iterdir() if ".tmp-" in p.name]


# ---- memory guard ------------------------------------------------------------------------------

def test_memory_estimate_is_calibrated_on_the_kitti_frame():
    # README / make bench: 1242x375, 228 disparities, census chain peaks at ~2.7 GiB
    est = memory.chain_peak_bytes(375, 1242, stereojax.preset("census", 228)) / memory.GIB
    assert 2.4 < est < 3.0, est


def test_memory_guard_refuses_a_4k_pair_before_allocating(monkeypatch):
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    monkeypatch.setattr(memory, "available_bytes", lambda: 16 * memory.GIB)
    from stereojax import pipeline

    def never(*a, **k):
        raise AssertionError("the jitted chain must not run")

    monkeypatch.setattr(pipeline, "compiled_chain", never)      # disparity() and the CLI compile through it
    monkeypatch.setattr(pipeline, "disparity_grey", never)      # disparity(bucket=False)
    monkeypatch.setattr(pipeline, "_stages_grey", never)        # stages()
    left = np.zeros((2160, 3840), np.uint8)
    cfg = stereojax.preset("census", 228)
    with pytest.raises(MemoryBudgetError) as exc:
        stereojax.disparity(left, left, cfg)
    msg = str(exc.value)
    _record("4K pair (3840x2160, 228 disparities), Python API", "MemoryBudgetError", msg)
    assert "a 2160x3840 frame with 228 disparities needs about 39.2 GiB" in msg
    assert "more than the limit of 11.2 GiB (70% of the 16.0 GiB available)" in msg
    assert "at most 62 fits" in msg and "downscale the pair by 2" in msg and memory.ENV_VAR in msg
    assert isinstance(exc.value, StereoError) and exc.value.exit_code == 6
    # the limit is read at call time: argument, then environment, then available memory
    with pytest.raises(MemoryBudgetError, match=r"limit of 8\.0 GiB \(memory_limit_gb=8\)"):
        stereojax.disparity(left, left, cfg, memory_limit_gb=8)
    monkeypatch.setenv(memory.ENV_VAR, "20")
    with pytest.raises(MemoryBudgetError, match=r"limit of 20\.0 GiB \(STEREOJAX_MEMORY_LIMIT_GB=20\)"):
        stereojax.stages(left, left, cfg)
    monkeypatch.setenv(memory.ENV_VAR, "lots")
    with pytest.raises(ConfigError, match="STEREOJAX_MEMORY_LIMIT_GB must be a positive number of GiB or 'off', got 'lots'"):
        stereojax.disparity(left, left, cfg)
    monkeypatch.setenv(memory.ENV_VAR, "off")
    with pytest.raises(AssertionError, match="must not run"):        # guard off: it would run
        stereojax.disparity(left, left, cfg)
    monkeypatch.delenv(memory.ENV_VAR)
    monkeypatch.setattr(memory, "available_bytes", lambda: 128 * memory.GIB)
    with pytest.raises(AssertionError, match="must not run"):        # a bigger machine: it fits
        stereojax.disparity(left, left, cfg)
    # stages() keeps every volume: its estimate is larger
    assert (memory.chain_peak_bytes(2160, 3840, cfg, keep=True) > memory.chain_peak_bytes(2160, 3840, cfg))


def test_memory_guard_cli_exit_6(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    monkeypatch.setattr(memory, "available_bytes", lambda: 16 * memory.GIB)
    from stereojax import pipeline

    # the CLI compiles its chain through compiled_chain: refused before that, nothing compiles or runs
    monkeypatch.setattr(pipeline, "compiled_chain", lambda *a, **k: pytest.fail("chain compiled"))
    img = np.zeros((2160, 3840), np.uint8)
    img[::7, ::5] = 255
    io.write_png(tmp_path / "l.png", img)
    io.write_png(tmp_path / "r.png", img)
    out = tmp_path / "out"
    code, _, err = _cli(["predict", tmp_path / "l.png", tmp_path / "r.png", "--out", out, "--method", "census",
                         "--max-disp", "228"], capsys, "4K pair (3840x2160, 228 disparities), CLI")
    line = _one_line(err)
    assert code == 6 and line.startswith("stereojax predict: error: a 2160x3840 frame with 228 disparities")
    assert list(out.iterdir()) == []


def test_available_memory_is_read(monkeypatch):
    """The default limit is the stated share of the memory available now (read from the
    system, at most the machine's total); the environment variable and the argument override it."""
    avail = memory.available_bytes()
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert avail is not None and 0 < avail <= total
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    limit, source = memory.memory_limit()
    assert limit == pytest.approx(memory.DEFAULT_SHARE * memory.available_bytes(), rel=0.05)
    assert source.endswith("GiB available") and f"{memory.DEFAULT_SHARE:.0%}" in source
    monkeypatch.setenv(memory.ENV_VAR, "1.5")
    assert memory.memory_limit() == (1.5 * memory.GIB, f"{memory.ENV_VAR}=1.5")
    assert memory.memory_limit(0.25) == (0.25 * memory.GIB, "memory_limit_gb=0.25")


# ---- SIGKILL: predict leaves complete files or none --------------------------------------------

_PREDICT_OUTPUTS = {"disparity.png", "disparity.pfm", "disparity_color.png", "depth.png", "depth.npy", "points.ply",
                    "config.json", "timings.json"}


def _predict_cmd(lp, rp, out):
    return [sys.executable, "-m", "stereojax.cli", "predict", str(lp), str(rp), "--out", str(out),
            "--max-disp", "16", "--method", "census", "--baseline", "0.54", "--focal", "721.5", "--ply"]


def _subprocess_env(tmp_path: Path) -> dict:
    """Environment of the CLI children: this checkout, and a persistent compilation cache (so a
    restarted child starts in ~3 s instead of ~11 s; the executables are the same)."""
    return {**os.environ, "PYTHONPATH": str(ROOT), "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax-cache"),
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0", "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"}


def _kill_after(cmd, env, delay=None, folder=None, rng=None):
    """Start cmd; SIGKILL it after ``delay`` s, or (folder) 0-3 ms after the first file appears
    in folder. Returns (whether it was still running when killed, the delay)."""
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if folder is not None:
        while proc.poll() is None and not any(folder.iterdir()):
            time.sleep(0.0005)
        delay = rng.uniform(0.0, 0.003)
    time.sleep(delay)
    alive = proc.poll() is None
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return alive, delay


@pytest.mark.slow
def test_sigkill_predict_leaves_no_partial_output(tmp_path):
    rng = random.Random(os.environ.get("ROBUSTNESS_SEED", "1234"))
    lp, rp = _write_pair(tmp_path / "in", h=64, w=96)
    env = _subprocess_env(tmp_path)
    subprocess.run(_predict_cmd(lp, rp, tmp_path / "full"), check=True, env=env, capture_output=True, timeout=300)
    full = _check_complete(tmp_path / "full")
    assert set(full["complete"]) == _PREDICT_OUTPUTS and full["temps"] == []
    reference = (tmp_path / "full" / "disparity.png").read_bytes()
    t0 = time.perf_counter()                                 # a full run, compilation cached
    subprocess.run(_predict_cmd(lp, rp, tmp_path / "full2"), check=True, env=env, capture_output=True, timeout=300)
    t_full = time.perf_counter() - t0

    out = tmp_path / "out"
    kills = []
    # 5 kills at uniformly random moments of a run (a child that already finished does not count) ...
    for _ in range(10):
        alive, delay = _kill_after(_predict_cmd(lp, rp, out), env, delay=rng.uniform(0.5, t_full))
        kills.append({"when": f"{delay:.2f} s", "alive": alive, **_check_complete(out, _PREDICT_OUTPUTS)})
        if sum(k["alive"] for k in kills) == 5:
            break
    # ... and 3 in the write phase: 0-3 ms after the first temp file appears
    for i in range(3):
        folder = tmp_path / f"w{i}"
        folder.mkdir()
        alive, delay = _kill_after(_predict_cmd(lp, rp, folder), env, folder=folder, rng=rng)
        kills.append({"when": f"write phase + {delay * 1000:.1f} ms", "alive": alive,
                      **_check_complete(folder, _PREDICT_OUTPUTS)})
    log = os.environ.get("ROBUSTNESS_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps({"case": "SIGKILL predict", "t_full_s": t_full, "kills": kills}) + "\n")
    assert sum(k["alive"] for k in kills) >= 8, kills
    # leftover temp files are hidden, never carry a final name, and the next run completes
    subprocess.run(_predict_cmd(lp, rp, out), check=True, env=env, capture_output=True, timeout=300)
    final = _check_complete(out, _PREDICT_OUTPUTS)
    assert set(final["complete"]) == _PREDICT_OUTPUTS
    assert (out / "disparity.png").read_bytes() == reference


# ---- SIGKILL: training resumes to the uninterrupted parameters ---------------------------------

def _ckpt_step(ckpt: Path):
    from stereojax import checkpoint
    from stereojax.train import TrainConfig, init_state

    if not ckpt.exists():
        return 0, None
    stored = checkpoint.read_config(ckpt)                  # the CLI adds a "data" section
    cfg = TrainConfig.from_stored(stored)
    state, _ = checkpoint.load(ckpt, init_state(cfg))      # raises on a damaged file
    return int(state["step"]), state


@pytest.mark.slow
def test_sigkill_training_repeatedly_then_resume_gives_the_uninterrupted_parameters(tmp_path, capsys):
    import jax

    rng = random.Random(os.environ.get("ROBUSTNESS_SEED", "1234"))
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=2)
    steps = 1500
    args = ["train", "--data", str(root), "--dataset", "kitti2015", "--frames", "0-1", "--preset", "tiny",
            "--steps", str(steps)]
    t0 = time.perf_counter()
    assert main(args + ["--out", str(tmp_path / "ref")]) == 0
    rate = steps / (time.perf_counter() - t0)              # steps/s, compilation included: a lower bound
    capsys.readouterr()
    ref_step, ref_state = _ckpt_step(tmp_path / "ref" / "checkpoint.msgpack")
    assert ref_step == steps

    out = tmp_path / "killed"
    ckpt = out / "checkpoint.msgpack"
    cmd = [sys.executable, "-m", "stereojax.cli", *args, "--resume", "--out", str(out)]
    env = _subprocess_env(tmp_path)
    kills, prev = [], 0
    for attempt in range(6):
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if attempt == 0:
            delay = rng.uniform(0.5, 2.5)                 # during start-up / compilation
            time.sleep(delay)
        else:
            # a random moment while training: after this run wrote its first checkpoint
            before = ckpt.stat().st_mtime_ns if ckpt.exists() else None
            while proc.poll() is None and (not ckpt.exists() or ckpt.stat().st_mtime_ns == before):
                time.sleep(0.005)
            # at most a quarter of the remaining steps (rate: a lower bound of the true rate)
            delay = rng.uniform(0.0, (steps - prev) / (2 * rate) / 4)
            time.sleep(delay)
        alive = proc.poll() is None
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        step, _ = _ckpt_step(ckpt)                          # never damaged
        assert step >= prev and (step % 4 == 0 or step == steps), (prev, step)
        if (out / "config.json").exists():
            json.loads((out / "config.json").read_text())
        assert not (out / "train_summary.json").exists() or step == steps
        assert not [p.name for p in (out.iterdir() if out.exists() else []) if p.is_file() and not p.name.startswith(".")
                    and p.name not in ("checkpoint.msgpack", "config.json", "train_summary.json")]
        kills.append({"attempt": attempt, "delay_s": round(delay, 3), "alive": alive,
                      "checkpoint_step_before": prev, "checkpoint_step_after": step})
        prev = step
    log = os.environ.get("ROBUSTNESS_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps({"case": "SIGKILL train", "steps": steps, "kills": kills}) + "\n")
    assert sum(k["alive"] and k["checkpoint_step_after"] < steps for k in kills) >= 5, kills
    subprocess.run(cmd, check=True, env=env, capture_output=True, timeout=300)
    step, state = _ckpt_step(ckpt)
    assert step == steps
    for x, y in zip(jax.tree_util.tree_leaves(ref_state), jax.tree_util.tree_leaves(state)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
