"""``stereojax predict`` over many pairs (stereojax.app.batch): KITTI folders, two folders, a pair list; a bad
pair is reported and skipped; names without a partner are reported; memory stays flat over a long
sequence; the range warning's rule and its record per frame; stale staging folders."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereojax.app.batch import range_warning
from stereojax.data import io

from ..helpers import pair_folders as _folders, run_cli, shifted_pair, shifted_pair as _shifted_pair

CENSUS = ["--method", "census", "--check-rectified", "off"]


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


def test_range_warning_rule():
    conf = np.ones((10, 100), np.float32)
    inside = np.full((10, 100), 5.0, np.float32)
    assert range_warning(inside, conf, 0, 24, 100) is None
    pinned = inside.copy()
    pinned[:, :20] = 23.0                                       # 20 % at the top of 0 <= d < 24
    line = range_warning(pinned, conf, 0, 24, 100)
    assert line.startswith("20.0 % of the confident pixels sit at the top") and "--max-disp 48" in line
    low_conf = conf.copy()
    low_conf[:, :20] = 0.1                                       # pinned, but not confident: no warning
    assert range_warning(pinned, low_conf, 0, 24, 100) is None
    bottom = inside.copy()
    bottom[:, :30] = 10.0
    line = range_warning(bottom, conf, 10, 40, 100, pinned_low=True)
    assert "bottom of the disparity range" in line and "--disp-range -5 40" in line


def test_the_suggested_range_follows_the_auto_range_beyond_the_limit():
    conf = np.ones((10, 1242), np.float32)
    pinned = np.full((10, 1242), 10.0, np.float32)
    pinned[:, :300] = 31.0                                      # 24 % at the top of 0 <= d < 32
    line = range_warning(pinned, conf, 0, 32, 1242, matches=(0, 89))
    assert "try --max-disp 96 (the pair's --disp-range auto reaches d = 88)" in line
    assert "--max-disp 64" in range_warning(pinned, conf, 0, 32, 1242, matches=(0, 30))   # they show no more
    bottom = np.full((10, 1242), 10.0, np.float32)
    line = range_warning(bottom, conf, 10, 40, 1242, pinned_low=True, matches=(-30, 41))
    assert "--disp-range -30 40 (the pair's --disp-range auto reaches d = -30)" in line


@pytest.mark.slow
def test_a_real_frame_pinned_at_a_small_range_gets_a_range_that_holds_its_ground_truth(data_root, tmp_path, capsys):
    from stereojax.data.datasets import load_dataset

    sample = load_dataset(data_root, "kitti2015", ["000021"], gt="noc")[0][1]()
    reach = float(sample.gt[sample.gt_valid].max())                        # 86.2 px
    root = data_root / "kitti2015" / "training"
    code, _, err = _run(["predict", root / "image_2" / "000021_10.png", root / "image_3" / "000021_10.png",
                         "--out", tmp_path / "o", "--max-disp", "32", *CENSUS], capsys)
    assert code == 0, err
    suggested = int(re.search(r"try --max-disp (\d+)", err).group(1))
    assert suggested > reach, (suggested, reach)                           # twice the range (64) was not


def test_batch_records_warnings_per_frame_and_counts_them(tmp_path, capsys):
    for i, (name, d) in enumerate((("far", 20), ("near", 4))):
        left, right = shifted_pair(d, h=64, w=128, seed=i)
        io.write_png(tmp_path / "L" / f"{name}.png", left)
        io.write_png(tmp_path / "R" / f"{name}.png", right)
    code, out, err = _run(["predict", tmp_path / "L", tmp_path / "R", "--out", tmp_path / "o", "--max-disp", "12",
                           *CENSUS], capsys)
    assert code == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["warnings"] == 1 and summary["frames_with_warnings"] == ["far"]
    rows = {r["frame"]: r for r in summary["per_frame"]}
    assert rows["near"]["warnings"] == [] and "top of the disparity range" in rows["far"]["warnings"][0]
    assert "top of the disparity range" in json.loads((tmp_path / "o" / "far" / "frame.json").read_text())["warnings"][0]
    assert "1 warning(s) in 1 frame(s)" in out


def test_unmatched_names_are_reported(tmp_path, capsys):
    left_dir, right_dir = _folders(tmp_path, ["a", "b", "c", "d", "e"], right_names={"a", "b", "c", "d"})
    io.write_png(right_dir / "z.png", shifted_pair(4, h=48, w=80)[1])
    code, out, err = _run(["predict", left_dir, right_dir, "--out", tmp_path / "o", *FAST], capsys)
    assert code == 0, err
    assert ("2 image(s) without a partner of the same name (1 left, 1 right), not computed: left/e.png, "
            "right/z.png") in err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["unmatched"] == ["left/e.png", "right/z.png"] and summary["ok"] == 4
    assert "2 image(s) without a partner" in out


def test_stale_staging_of_a_live_process_is_kept(tmp_path):
    from stereojax.app.batch import remove_stale

    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    try:
        (tmp_path / f".a.partial-{live.pid}").mkdir()
        (tmp_path / f".b.partial-{dead.pid}").mkdir()
        (tmp_path / f".c.old-{dead.pid}").mkdir()
        remove_stale(tmp_path)
        assert sorted(p.name for p in tmp_path.iterdir()) == [f".a.partial-{live.pid}"]
    finally:
        live.kill()
        live.wait()
