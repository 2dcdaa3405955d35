"""``stereojax predict`` over many pairs: KITTI folders, two folders, a pair list; a bad pair
is reported and skipped; memory stays flat over a long sequence."""

import json
from pathlib import Path

import numpy as np
import pytest

from stereojax.data import io
from tests.helpers import shifted_pair as _shifted_pair, run_cli

FAST = ["--max-disp", "16", "--method", "census"]


_run = run_cli


def _pair(folder: Path, name: str, d: int = 4, h=48, w=80, seed=0):
    left, right = _shifted_pair(d, h=h, w=w, seed=seed)
    folder.mkdir(parents=True, exist_ok=True)
    io.write_png(folder / f"{name}_L.png", left)
    io.write_png(folder / f"{name}_R.png", right)
    return folder / f"{name}_L.png", folder / f"{name}_R.png"


def test_kitti_training_folder_in_one_call(tmp_path, capsys):
    root = tmp_path / "training"
    for i, d in enumerate((3, 5)):
        left, right = _shifted_pair(d, seed=i)
        io.write_png(root / "image_2" / f"00000{i}_10.png", left)
        io.write_png(root / "image_3" / f"00000{i}_10.png", right)
    code, out, err = _run(["predict", root, "--out", tmp_path / "o", *FAST], capsys)
    assert code == 0, err
    for i, d in enumerate((3, 5)):
        frame = tmp_path / "o" / f"00000{i}_10"
        disp = io.read_pfm(frame / "disparity.pfm")                       # float disparity, PFM
        np.testing.assert_allclose(np.median(disp[:, 20:]), d, atol=0.5)
        assert (frame / "disparity.png").exists() and (frame / "timings.json").exists()
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["ok"] == 2 and summary["failed"] == [] and summary["frames_per_s"] > 0
    assert "2 of 2 pairs" in out and "frames/s" in out
    assert "frame/s" in err or "it/s" in err or "s/frame" in err          # tqdm's progress bar


def test_two_folders_matched_by_name_and_a_bad_pair_is_skipped(tmp_path, capsys):
    for i in range(3):
        left, right = _shifted_pair(4, seed=i)
        io.write_png(tmp_path / "L" / f"f{i}.png", left)
        io.write_png(tmp_path / "R" / f"f{i}.png", right)
    (tmp_path / "R" / "f1.png").write_bytes(b"not a png")                  # damaged right image
    io.write_png(tmp_path / "L" / "only_left.png", left)                   # no partner: not a pair
    code, out, err = _run(["predict", tmp_path / "L", tmp_path / "R", "--out", tmp_path / "o", *FAST], capsys)
    assert code == 2
    errors = [ln for ln in err.replace("\r", "\n").splitlines() if ": error: " in ln]
    assert len(errors) == 1 and "f1" in errors[0] and "Traceback" not in err
    assert (tmp_path / "o" / "f0" / "disparity.png").exists() and (tmp_path / "o" / "f2" / "disparity.png").exists()
    assert not (tmp_path / "o" / "f1").exists()                            # nothing partial
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["ok"] == 2 and [f["frame"] for f in summary["failed"]] == ["f1"]
    assert "2 of 3 pairs" in out and "1 failed: f1" in out


def test_pair_list_with_mixed_sizes_and_a_missing_file(tmp_path, capsys):
    a = _pair(tmp_path, "a")
    b = _pair(tmp_path, "b", h=40, w=72, seed=1)                           # another size, same bucket
    c = _pair(tmp_path, "c", h=70, w=100, seed=2)                          # another bucket
    lst = tmp_path / "pairs.txt"
    lst.write_text(f"# left right\n{a[0].name} {a[1].name}\n\n{b[0]} {b[1]}\nmissing.png {a[1].name}\n"
                   f"{c[0].name} {c[1].name}\n")
    code, out, err = _run(["predict", "--pairs", lst, "--out", tmp_path / "o", *FAST], capsys)
    assert code == 2 and "missing.png" in err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    buckets = [tuple(r["bucket"]) for r in summary["per_frame"]]
    assert buckets == [(48, 96), (48, 96), (80, 128)]
    assert summary["per_frame"][1]["compile_s"] == 0.0                      # same bucket: no new compile
    assert io.read_pfm(tmp_path / "o" / "b_L" / "disparity.pfm").shape == (40, 72)   # cropped back


@pytest.mark.parametrize("argv, match", [
    (["predict", "--out", "o"], "predict takes LEFT RIGHT"),
    (["predict", "nowhere", "--out", "o"], "nowhere does not exist"),
    (["predict", "EMPTY", "--out", "o"], "is not a KITTI training/ or testing/ folder"),
    (["predict", "--pairs", "BADLIST", "--out", "o"], "expected 'LEFT RIGHT'"),
])
def test_batch_inputs_errors_are_one_line(tmp_path, capsys, argv, match, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "EMPTY").mkdir()
    (tmp_path / "BADLIST").write_text("only_one_path.png\n")
    code, _, err = _run(argv, capsys)
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and match in lines[0], err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.slow
def test_memory_stays_flat_over_100_frames(tmp_path, capsys):
    a = _pair(tmp_path, "a")
    lst = tmp_path / "pairs.txt"
    lst.write_text("".join(f"{a[0].name} {a[1].name}\n" for _ in range(100)))
    code, _, err = _run(["predict", "--pairs", lst, "--out", tmp_path / "o", *FAST], capsys)
    assert code == 0, err
    rss = [r["rss_mb"] for r in json.loads((tmp_path / "o" / "summary.json").read_text())["per_frame"]]
    assert len(rss) == 100 and rss[10] > 0
    # after warming up, 90 more frames add less than 25 MiB to the resident set
    assert rss[-1] - rss[10] < 25, (rss[10], rss[-1])
