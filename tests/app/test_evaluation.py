"""The one evaluation loop (stereojax.app.evaluation.evaluate_frames), scoring the non-occluded and all
ground-truth pixels apart, and an evaluation that continues from its per-frame records."""

import dataclasses
import json
import sys

import cv2
import numpy as np
import pytest

import stereojax
from stereojax import metrics
from stereojax.app.evaluation import chain_method, evaluate_frames, format_table, sgbm_method
from stereojax.data import io
from stereojax.data.datasets import StereoSample

from ..helpers import fake_kitti, shifted_pair
from ..robustness_helpers import _cli

FAST = ["--max-disp", "16", "--method", "census"]


def _samples():
    out = []
    for i, d in enumerate((3, 5)):
        left, right = shifted_pair(d, h=48, w=96, seed=i)
        gt = np.full(left.shape, float(d), np.float32)
        valid = np.zeros(left.shape, bool)
        valid[8:40, 20:80] = True
        out.append(StereoSample(name=f"f{i}", left=left, right=right, gt=gt, gt_valid=valid))
    return out


def test_every_method_is_scored_on_every_frame_as_metrics_evaluate_scores_it():
    samples = _samples()
    disp = {"f0": np.full((48, 96), 3.0, np.float32), "f1": np.full((48, 96), 1.0, np.float32)}
    seen = []
    result = evaluate_frames(samples, {"const": lambda s, md: disp[s.name],
                                       "shifted": lambda s, md: disp[s.name] + 2.5},
                             max_disp=lambda s: 16 + len(s.name), on_frame=lambda r, s, d: seen.append(r["frame"]))
    assert [r["frame"] for r in result["frames"]] == ["f0", "f1"] == seen
    assert all(r["max_disp"] == 18 for r in result["frames"])
    for r, s in zip(result["frames"], samples):
        for name, offset in (("const", 0.0), ("shifted", 2.5)):
            want = metrics.evaluate(disp[s.name] + offset, s.gt, s.gt_valid)
            assert {k: r[name][k] for k in want} == want
    # const: f0 exact (0 %), f1 4 px off (100 %); shifted: f0 2.5 px off, f1 1.5 px off.
    # The mean is over frames.
    assert result["mean"]["const"]["bad3"] == pytest.approx(50.0)
    assert result["mean"]["shifted"]["bad2"] == pytest.approx(50.0)
    assert result["mean"]["shifted"]["bad3"] == pytest.approx(0.0)
    assert result["missing_gt"] == []


def test_est_valid_and_timings_returned_by_a_method_are_used():
    s = _samples()[0]
    disp = np.full(s.gt.shape, 3.0, np.float32)
    holes = np.ones(s.gt.shape, bool)
    holes[:, :50] = False                          # no estimate on the left half of the GT box
    r = evaluate_frames([s], {"m": lambda s_, md: (disp, {"est_valid": holes, "seconds": 7.0, "compile_s": 0.0})},
                        16, fill="error")["frames"][0]["m"]
    assert r["seconds"] == 7.0 and r["warm"] is True
    assert r["bad3"] == pytest.approx(100.0 * 30 / 60)        # columns 20..49 of 20..79 count as errors
    r2 = evaluate_frames([s], {"m": lambda s_, md: (disp, holes)}, 16, fill="error")["frames"][0]["m"]
    assert r2["bad3"] == pytest.approx(r["bad3"])


def test_first_frame_of_a_size_is_cold_unless_compilation_is_timed_apart():
    samples = _samples()
    result = evaluate_frames(samples + [dataclasses.replace(samples[0], name="again")],
                             {"m": lambda s, md: np.full(s.gt.shape, 3.0, np.float32)}, 16)
    assert [r["m"]["warm"] for r in result["frames"]] == [False, True, True]
    assert result["mean"]["m"]["seconds_warm"] == pytest.approx(
        np.mean([r["m"]["seconds"] for r in result["frames"][1:]]))


def test_frames_without_ground_truth_are_listed_and_lazy_items_load_in_turn():
    s = _samples()[0]
    loaded = []

    def loader(sample):
        def load():
            loaded.append(sample.name)
            return sample
        return load
    no_gt = dataclasses.replace(s, name="nogt", gt=None, gt_valid=None)
    result = evaluate_frames([("a", loader(s)), ("b", loader(no_gt))],
                             {"m": lambda s_, md: np.full(s.gt.shape, 3.0, np.float32)}, 16)
    assert loaded == ["f0", "nogt"] and result["missing_gt"] == ["b"]
    assert [r["frame"] for r in result["frames"]] == ["a"]


def test_chain_and_sgbm_methods_on_a_shifted_pair():
    s = _samples()[1]
    result = evaluate_frames([s], {"census": chain_method(stereojax.preset("census")), "sgbm": sgbm_method()}, 16)
    row = result["frames"][0]
    assert row["census"]["bad3"] < 5.0 and row["census"]["compile_s"] >= 0 and row["census"]["warm"]
    assert row["sgbm"]["bad3"] < 20.0
    table = format_table(result["mean"])
    assert "| census |" in table and "| OpenCV SGBM, left-padded |" in table


def test_gt_both_scores_non_occluded_and_all_pixels_apart(tmp_path, capsys):
    root = tmp_path / "training"
    fake_kitti(root, n=2)
    (root / "disp_occ_0").mkdir()
    for i in range(2):
        occ = np.zeros((48, 80), np.uint16)
        occ[5:45, 2:78] = 3 * 256                     # more pixels than the noc GT (rows 10-39, cols 20-69)
        cv2.imwrite(str(root / "disp_occ_0" / f"{i:06d}_10.png"), occ)
    base = ["evaluate", "--data", root, "--dataset", "kitti2015", *FAST]
    runs = {}
    for gt in ("noc", "occ", "both"):
        assert _cli(base + ["--gt", gt, "--out", tmp_path / gt], capsys)[0] == 0
        runs[gt] = json.loads((tmp_path / gt / "results.json").read_text())
    both = runs["both"]["mean"]
    assert set(both) == {"pipeline (noc)", "pipeline (all)"}
    for key in ("bad2", "bad3", "d1", "epe", "n_gt"):
        assert both["pipeline (noc)"][key] == runs["noc"]["mean"]["pipeline"][key]
        assert both["pipeline (all)"][key] == runs["occ"]["mean"]["pipeline"][key]
    assert both["pipeline (all)"]["n_gt"] > both["pipeline (noc)"]["n_gt"]
    md = (tmp_path / "both" / "results.md").read_text()
    assert "stereojax census, non-occluded" in md and "stereojax census, all pixels" in md


def test_gt_both_skips_frames_without_the_all_pixel_ground_truth(tmp_path, capsys):
    root = tmp_path / "training"
    fake_kitti(root, n=2)
    code, _, err = _cli(["evaluate", "--data", root, "--dataset", "kitti2015", *FAST, "--gt", "both",
                         "--out", tmp_path / "o"], capsys)
    assert code == 2 and "no non-occluded and all-pixel ground truth for 2 frame(s)" in err


def test_evaluate_continues_from_its_records_with_the_mean_of_an_uninterrupted_run(tmp_path, capsys):
    root = tmp_path / "training"
    fake_kitti(root, n=3)
    base = ["evaluate", "--data", root, "--dataset", "kitti2015", *FAST]
    assert _cli(base + ["--out", tmp_path / "whole"], capsys)[0] == 0
    whole = json.loads((tmp_path / "whole" / "results.json").read_text())
    part = tmp_path / "part"
    assert _cli(base + ["--frames", "000000,000001", "--out", part], capsys)[0] == 0     # "stopped" after 2
    code, _, err = _cli(base + ["--out", part], capsys)
    assert code == 0 and "2 of 3 frames from the records of an earlier run" in err
    resumed = json.loads((part / "results.json").read_text())
    assert resumed["reused"] == ["000000", "000001"]
    for key in ("bad2", "bad3", "d1", "epe", "n_gt"):
        assert resumed["mean"]["pipeline"][key] == whole["mean"]["pipeline"][key]
    code, _, err = _cli(base + ["--out", part, "--overwrite"], capsys)
    assert code == 0 and json.loads((part / "results.json").read_text())["reused"] == []
    # another setting: nothing reused
    _cli(["evaluate", "--data", root, "--dataset", "kitti2015", "--max-disp", "24", "--method", "census",
          "--out", part], capsys)
    assert json.loads((part / "results.json").read_text())["reused"] == []


# ---- which ground truth evaluate scores (issue 55, item 4) ---------------------------------------

def _fake_middlebury(root, masked=("withmask",), plain=("nomask",)):
    """Middlebury scenes of a shifted pair (d = 3): ``masked`` ones with mask0nocc.png (255 on a box
    of 30 x 50 px), ``plain`` ones with disp0GT.pfm only (no mask, no disp1GT.pfm: no non-occluded GT)."""
    for i, name in enumerate((*masked, *plain)):
        scene = root / name
        left, right = shifted_pair(3, h=48, w=80, seed=i)
        io.write_png(scene / "im0.png", left)
        io.write_png(scene / "im1.png", right)
        gt = np.full(left.shape, 3.0, np.float32)
        gt[:, :4] = np.inf                             # no ground truth on the left strip
        io.write_pfm(scene / "disp0GT.pfm", gt)
        if name in masked:
            mask = np.full(left.shape, 128, np.uint8)
            mask[10:40, 20:70] = 255
            io.write_png(scene / "mask0nocc.png", mask)
    return root


def _evaluate_with_default_gt(argv, capsys):
    """``stereojax evaluate ARGV`` without ``--gt`` (the default, auto): (exit code, stdout, stderr)."""
    from stereojax.app.parser import build_parser

    argv = [str(a) for a in argv]
    assert build_parser().parse_args(argv).gt == "auto"
    return _cli(argv, capsys)


def test_default_gt_scores_noc_where_the_data_has_it_else_all_pixels_and_says_so(tmp_path, capsys):
    root = _fake_middlebury(tmp_path / "mb")
    out = tmp_path / "o"
    code, stdout, err = _evaluate_with_default_gt(["evaluate", "--data", root, "--dataset", "middlebury", *FAST,
                                                   "--out", out], capsys)
    assert code == 0, err
    line = [s for s in stdout.splitlines() if s.startswith("stereojax: ground truth:")]
    assert len(line) == 1 and "non-occluded pixels on 1 frame(s)" in line[0], stdout
    assert "all pixels on the 1 without" in line[0] and "nomask" in line[0] and "--gt occ" in line[0]
    res = json.loads((out / "results.json").read_text())
    rows = {r["frame"]: r for r in res["frames"]}
    assert set(rows) == {"withmask", "nomask"}                    # nothing skipped
    assert rows["withmask"]["gt"] == "noc" and rows["withmask"]["pipeline"]["n_gt"] == 30 * 50
    assert rows["nomask"]["gt"] == "occ" and rows["nomask"]["pipeline"]["n_gt"] == 48 * (80 - 4)
    assert "all pixels on nomask" in (out / "results.md").read_text()
    assert (out / "error_legend.png").exists()


def test_default_gt_on_data_without_noc_masks_scores_all_pixels(tmp_path, capsys):
    root = _fake_middlebury(tmp_path / "mb", masked=(), plain=("a", "b"))
    code, stdout, err = _evaluate_with_default_gt(["evaluate", "--data", root, "--dataset", "middlebury", *FAST,
                                                   "--out", tmp_path / "o"], capsys)
    assert code == 0, err
    assert "stereojax: ground truth: all pixels, since no frame has non-occluded ground truth" in stdout
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert [r["gt"] for r in res["frames"]] == ["occ", "occ"]


def test_gt_noc_that_the_data_cannot_serve_names_gt_occ_and_leaves_no_folder(tmp_path, capsys):
    root = _fake_middlebury(tmp_path / "mb", masked=(), plain=("a",))
    out = tmp_path / "new" / "o"
    code, _, err = _cli(["evaluate", "--data", root, "--dataset", "middlebury", *FAST, "--gt", "noc",
                         "--out", out], capsys)
    assert code == 2
    last = err.strip().splitlines()[-1]
    assert last.startswith("stereojax evaluate: error: no noc ground truth for 1 frame(s): a") and "--gt occ" in last
    assert not (tmp_path / "new").exists()                        # what this run made is gone
    # a folder that already held the user's files keeps them, and gets nothing
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert _cli(["evaluate", "--data", root, "--dataset", "middlebury", *FAST, "--gt", "noc",
                 "--out", mine], capsys)[0] == 2
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_gt_noc_with_some_frames_unscorable_warns_with_the_way_to_score_them(tmp_path, capsys):
    root = _fake_middlebury(tmp_path / "mb")
    code, _, err = _cli(["evaluate", "--data", root, "--dataset", "middlebury", *FAST, "--gt", "noc",
                         "--out", tmp_path / "o"], capsys)
    assert code == 0
    assert "warning: no noc ground truth for 1 frame(s): nomask; skipped; --gt occ scores all pixels" in err


def test_default_gt_on_the_shared_middlebury_scenes(data_root, tmp_path, capsys):
    """The shared scenes: the 2005/2006 ones get their non-occluded mask from the left-right check of
    disp0GT/disp1GT, Tsukuba its mask0nocc.png; Aloe_opencv (disp0GT.pfm only) has none."""
    from stereojax.data.datasets import load_dataset

    scenes = ["Aloe_opencv", "Reindeer_2006H", "Tsukuba_2001"]
    items = load_dataset(data_root, "middlebury", scenes, gt="auto")
    assert items.gt_of == {"Aloe_opencv": "occ", "Reindeer_2006H": "noc", "Tsukuba_2001": "noc"}
    tsukuba = dict(items)["Tsukuba_2001"]()
    assert tsukuba.gt_noc_valid is not None and (tsukuba.gt_valid == tsukuba.gt_noc_valid).all()
    aloe = dict(items)["Aloe_opencv"]()
    assert aloe.gt is not None and aloe.gt_noc_valid is None
    out = tmp_path / "o"
    code, _, err = _cli(["evaluate", "--data", data_root, "--dataset", "middlebury", "--frames", "Aloe_opencv",
                         "--gt", "noc", *FAST, "--out", out], capsys)
    assert code == 2 and "--gt occ" in err.strip().splitlines()[-1] and not out.exists()
