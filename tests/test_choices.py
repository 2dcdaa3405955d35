"""No silent choices: the tool says what it chose and why, warns where a result is likely wrong
(a disparity range too small), keeps every warning in the outputs, refuses options that would be
ignored, and documents its output conventions (issue "No silent choices")."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from stereojax.app.batch import range_warning
from stereojax.data import io
from tests.helpers import shifted_pair, run_cli

ROOT = Path(__file__).resolve().parents[1]
CENSUS = ["--method", "census", "--check-rectified", "off"]


_run = run_cli


def _pair(folder: Path, d: int, name="p", h=64, w=128, seed=0):
    left, right = shifted_pair(d, h=h, w=w, seed=seed)
    folder.mkdir(parents=True, exist_ok=True)
    io.write_png(folder / f"{name}_L.png", left)
    io.write_png(folder / f"{name}_R.png", right)
    return folder / f"{name}_L.png", folder / f"{name}_R.png"


# ---- 1 + 5. a range too small is warned about, and the warning is kept -----------------------------

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


def test_pinned_range_warns_and_the_warning_is_recorded(tmp_path, capsys):
    lp, rp = _pair(tmp_path / "in", d=20)
    code, out, err = _run(["predict", lp, rp, "--out", tmp_path / "o", "--max-disp", "12", *CENSUS], capsys)
    assert code == 0, err
    assert "warning:" in err and "sit at the top of the disparity range (d >= 11 of 0 <= d < 12)" in err
    assert "try --max-disp 32" in err
    timings = json.loads((tmp_path / "o" / "timings.json").read_text())
    assert len(timings["warnings"]) == 1 and "top of the disparity range" in timings["warnings"][0]
    code, out, err = _run(["predict", lp, rp, "--out", tmp_path / "ok", "--max-disp", "32", *CENSUS], capsys)
    assert code == 0 and "warning" not in err
    assert json.loads((tmp_path / "ok" / "timings.json").read_text())["warnings"] == []


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


# ---- 2. --ply without a calibration is refused ------------------------------------------------------

def test_ply_without_calibration_is_refused(tmp_path, capsys):
    lp, rp = _pair(tmp_path / "in", d=4)
    code, out, err = _run(["predict", lp, rp, "--out", tmp_path / "o", "--max-disp", "16", "--ply", *CENSUS], capsys)
    assert code == 3 and err.strip().splitlines() == [
        "stereojax predict: error: --ply needs a calibration for depth: give --calib FILE, or --baseline and --focal"]
    assert not (tmp_path / "o").exists()


def test_max_depth_cuts_far_points(tmp_path, capsys):
    lp, rp = _pair(tmp_path / "in", d=4)
    calib = ["--baseline", "0.54", "--focal", "721.5"]                     # d = 4 px: Z = 97 m
    code, _, err = _run(["predict", lp, rp, "--out", tmp_path / "all", "--max-disp", "16", *calib, "--ply", *CENSUS],
                        capsys)
    assert code == 0, err
    code, _, err = _run(["predict", lp, rp, "--out", tmp_path / "near", "--max-disp", "16", *calib, "--ply",
                         "--max-depth", "50", *CENSUS], capsys)
    assert code == 0, err
    z_all, z_near = np.load(tmp_path / "all" / "depth.npy"), np.load(tmp_path / "near" / "depth.npy")
    assert np.mean(z_all > 50) > 0.5 and not np.any(z_near > 50)
    assert np.all((z_near == z_all) | (z_near == 0))
    assert (tmp_path / "near" / "points.ply").stat().st_size < (tmp_path / "all" / "points.ply").stat().st_size / 2
    code, _, err = _run(["predict", lp, rp, "--out", tmp_path / "x", "--max-disp", "16", "--max-depth", "50",
                         *CENSUS], capsys)
    assert code == 3 and "--max-depth needs a calibration" in err


# ---- 3. a config file's max_disp is not overridden by a default ------------------------------------------

def test_config_file_max_disp_is_kept_unless_max_disp_is_given(tmp_path, capsys):
    import stereojax

    lp, rp = _pair(tmp_path / "in", d=4)
    cfg_file = tmp_path / "cfg.json"
    cfg_file.write_text(json.dumps(stereojax.preset("census", 24).to_dict()))
    code, out, err = _run(["predict", lp, rp, "--out", tmp_path / "a", "--config", cfg_file, *CENSUS], capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "a" / "timings.json").read_text())["max_disp"] == 24
    assert f"24 disparities from {cfg_file}" in out
    code, out, err = _run(["predict", lp, rp, "--out", tmp_path / "b", "--config", cfg_file, "--max-disp", "32",
                           *CENSUS], capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "b" / "timings.json").read_text())["max_disp"] == 32
    assert f"--max-disp 32 overrides max_disp 24 of {cfg_file}" in out


# ---- 4. the first line says what runs, and why -------------------------------------------------------------

def test_first_line_names_method_model_and_reason(tmp_path, capsys):
    lp, rp = _pair(tmp_path / "in", d=4)
    code, out, err = _run(["predict", lp, rp, "--out", tmp_path / "o", "--max-disp", "16", *CENSUS], capsys)
    assert code == 0, err
    assert out.splitlines()[0] == "stereojax: method: census cost (--method census)"


def test_best_rule_and_scene_option():
    from stereojax.models.registry import BEST, SHIPPED, WEIGHTS_DIR, resolve

    if not all((WEIGHTS_DIR / f"{SHIPPED[BEST[k]]}.msgpack").is_file() for k in BEST):
        pytest.skip("the shipped models are not all there")
    crop = resolve("best", width=900, height=375)                  # a KITTI crop: not wide enough
    assert crop.weights.name.startswith("middlebury") and "less than 2.5 times as wide" in crop.reason
    road = resolve("best", width=900, height=375, scene="road")
    assert road.weights.name.startswith("kitti2015") and road.reason == "--method best: --scene road"
    assert "(--method best: --scene road)" in road.chosen_line
    wide = resolve("best", width=1242, height=375, scene="indoor")
    assert wide.weights.name.startswith("middlebury")
    kitti = resolve("best", width=1242, height=375)
    assert kitti.weights.name.startswith("kitti2015") and "road frame" in kitti.reason


# ---- 6. make evaluate never writes the project's results ----------------------------------------------------

def test_make_evaluate_writes_outside_the_project_results():
    make = (ROOT / "Makefile").read_text()
    block = make[make.index("\nevaluate:"):make.index("\n# the project's own scored runs")]
    assert "--out $(OUT)/evaluate_" in block and "experiments/results" not in block
    report = (ROOT / "experiments" / "report.py").read_text()
    for name in ("evaluate_kitti2015_best", "evaluate_kitti2012_best", "evaluate_middlebury_best"):
        assert name in report and f"experiments/results/{name}" in make     # fed by its own target only


# ---- 7. training stopped by a signal keeps its work ----------------------------------------------------------

@pytest.mark.slow
def test_training_stopped_by_sigint_writes_a_checkpoint_and_says_how_to_resume(tmp_path):
    from stereojax.models import checkpoint
    from tests.helpers import fake_kitti

    root = tmp_path / "training"
    fake_kitti(root, n=2)
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "stereojax.app.cli", "train", "--data", str(root), "--dataset", "kitti2015",
           "--frames", "0-1", "--preset", "tiny", "--steps", "6000", "--checkpoint-every", "100000", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err_file:
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err_file, text=True)
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None:       # until tqdm shows some steps done
            shown = [int(m) for m in re.findall(r"\| (\d+)/6000 ", log.read_text())]
            if shown and max(shown) >= 20:
                break
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    err = log.read_text()
    assert proc.returncode == 130, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("stereojax train: interrupted by SIGINT: stopped at step ") and "--resume" in last
    step = int(last.split("stopped at step ")[1].split()[0])
    assert 0 < step < 6000
    assert f"the checkpoint of step {step} is kept in {out / 'checkpoint.msgpack'}" in last
    assert checkpoint.read_config(out / "checkpoint.msgpack")                # a readable checkpoint
    from stereojax.models.checkpoint import _read

    assert int(np.asarray(_read(out / "checkpoint.msgpack")["state"]["step"])) == step
    again = subprocess.run([*cmd, "--resume"], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert f"| {step}/6000 " in again.stderr                              # it went on from the kept step
    assert json.loads(again.stdout[again.stdout.index("{"):])["steps"] == 6000


# ---- 8. output conventions ------------------------------------------------------------------------------

def test_metrics_count_a_zero_estimate_as_missing():
    from stereojax.metrics import evaluate

    gt = np.full((20, 40), 10.0, np.float32)
    disp = gt.copy()
    disp[:, :10] = 0.0                                               # 0 = "no value", as in KITTI PNGs
    with_zero = evaluate(disp, gt, None, fill="error")
    assert with_zero["density"] == pytest.approx(75.0) and with_zero["bad3"] == pytest.approx(25.0)
    disp[:, :10] = np.inf
    assert evaluate(disp, gt, None, fill="error") == with_zero
    assert evaluate(np.where(np.isinf(disp), 0, disp), gt, None)["density"] == pytest.approx(75.0)


# ---- 9. names ---------------------------------------------------------------------------------------------

def test_a_misspelt_model_lists_the_shipped_names(tmp_path, capsys):
    lp, rp = _pair(tmp_path / "in", d=4)
    code, _, err = _run(["predict", lp, rp, "--out", tmp_path / "o", "--weights", "kitti2015_compct"], capsys)
    assert code == 4
    assert ("weights kitti2015_compct does not exist: neither a file nor a shipped model (shipped: kitti2015, "
            "middlebury, kitti2015_compact); did you mean kitti2015_compact?") in err


def test_middlebury_scenes_are_named_by_their_folder(tmp_path, capsys):
    from stereojax.data.pairs import find_pairs

    for i, scene in enumerate(["Cones", "Teddy"]):
        left, right = shifted_pair(4, h=64, w=128, seed=i)
        io.write_png(tmp_path / "mb" / scene / "im0.png", left)
        io.write_png(tmp_path / "mb" / scene / "im1.png", right)
    pairs, batch = find_pairs([tmp_path / "mb"])
    assert batch and [p[0] for p in pairs] == ["Cones", "Teddy"]
    listing = tmp_path / "pairs.txt"
    listing.write_text("mb/Cones/im0.png mb/Cones/im1.png\nmb/Teddy/im0.png mb/Teddy/im1.png\n")
    pairs, _ = find_pairs([listing])
    assert [p[0] for p in pairs] == ["Cones", "Teddy"]


# ---- 11. licence -------------------------------------------------------------------------------------------

def test_licence_files_and_the_weights_terms():
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT" and "LICENSE" in project["license-files"]
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    terms = (ROOT / "stereojax" / "models" / "weights" / "LICENSE.md").read_text()
    assert "CC BY-NC-SA 3.0" in terms and "non-commercial" in terms.lower()
