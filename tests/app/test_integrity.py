"""stereojax.app.integrity: resume checks each file's size (and digest with --verify), for predict and for
evaluate's records."""

import json

from ..helpers import fake_kitti, pair_folders as _folders, run_cli

FAST = ["--max-disp", "16", "--method", "census"]
_run = run_cli


def test_resume_recomputes_a_frame_whose_file_was_cut(tmp_path, capsys):
    left_dir, right_dir = _folders(tmp_path, ["a", "b"])
    out = tmp_path / "o"
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)
    assert code == 0, err
    record = json.loads((out / "a" / "frame.json").read_text())
    assert set(record["files"]) == set(record["outputs"])
    assert record["files"]["disparity.png"]["size"] == (out / "a" / "disparity.png").stat().st_size
    good = (out / "a" / "disparity.png").read_bytes()
    (out / "a" / "disparity.png").write_bytes(good[:len(good) // 2])        # cut to half, frame.json untouched
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)
    assert code == 0, err
    assert "a: recorded as complete but disparity.png is" in err and "computing it again" in err
    assert "1 of 2 frames already complete" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["computed"] == 1 and summary["skipped_frames"] == ["b"]
    assert summary["damaged"][0]["frame"] == "a"
    assert (out / "a" / "disparity.png").read_bytes() == good


def test_verify_reads_the_digests(tmp_path, capsys):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    out = tmp_path / "o"
    assert _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)[0] == 0
    path = out / "a" / "confidence.npy"
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF                                                          # same size, other bytes
    path.write_bytes(bytes(data))
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)
    assert code == 0 and "1 of 1 frames already complete" in err            # sizes only: kept
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, "--verify", *FAST], capsys)
    assert code == 0 and "confidence.npy does not match its recorded SHA-256" in err
    assert json.loads((out / "summary.json").read_text())["computed"] == 1
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, "--verify", *FAST], capsys)
    assert code == 0 and "1 of 1 frames already complete" in err and "SHA-256 checked" in err


def test_evaluate_records_are_checked_on_resume(tmp_path, capsys):
    root = tmp_path / "training"
    fake_kitti(root, n=2)
    out = tmp_path / "ev"
    argv = ["evaluate", "--data", root, "--dataset", "kitti2015", "--max-disp", "16", "--method", "census",
            "--out", out]
    assert _run(argv, capsys)[0] == 0
    record = json.loads((out / "frames" / "000000.json").read_text())
    assert "000000_error.png" in record["files"] and "000000_disparity.png" in record["files"]
    err_png = out / "000000_error.png"
    err_png.write_bytes(err_png.read_bytes()[:100])
    code, _, err = _run(argv, capsys)
    assert code == 0 and "000000: recorded as scored but 000000_error.png is 100 bytes" in err
    assert json.loads((out / "results.json").read_text())["reused"] == ["000001"]
    assert err_png.stat().st_size == record["files"]["000000_error.png"]["size"]
