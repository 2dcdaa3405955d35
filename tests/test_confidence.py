"""The confidence map (margin of the aggregated cost x left-right agreement), the "neutral"
out-of-view border, and scoring the non-occluded and all ground-truth pixels apart."""

import json

import cv2
import jax.numpy as jnp
import numpy as np

import stereojax
from stereojax.matching_cost import classical as cost_mod
from stereojax.validation import confidence_measure
from stereojax.data import io

from .helpers import fake_kitti, shifted_pair
from .robustness_helpers import _cli

FAST = ["--max-disp", "16", "--method", "census"]


def test_confidence_terms_by_hand():
    cost = np.array([[[0.2, 0.8, 0.5, 0.6], [0.3, 0.31, 0.9, 0.3]]], np.float32)    # [1, 2, 4]
    wta = np.argmin(cost, -1)                                                        # [[0, 0]]
    margin = np.asarray(confidence_measure.confidence(jnp.asarray(cost), jnp.asarray(wta), None))
    # pixel 0: best 0.2 at d 0, best at |d - 0| >= 2 is 0.5 -> (0.5 - 0.2) / 0.5; pixel 1: 0.3 vs 0.3 -> 0
    np.testing.assert_allclose(margin, [[0.6, 0.0]], atol=1e-6)
    # left-right: pixel 1 (d 0) sees D_R(1) = 3: off by 3, tolerance 1 -> exp(-2)
    disp_right = np.array([[0, 3]], np.int32)
    full = np.asarray(confidence_measure.confidence(jnp.asarray(cost), jnp.asarray(wta), jnp.asarray(disp_right), 1.0))
    np.testing.assert_allclose(full, margin * np.array([[1.0, np.exp(-2.0)]]), atol=1e-6)


def test_neutral_border_sets_only_the_out_of_view_entries():
    rng = np.random.default_rng(0)
    vol = rng.random((3, 6, 4)).astype(np.float32)
    out = np.asarray(cost_mod.neutral_border(jnp.asarray(vol), 0.5))
    for x in range(6):
        inside = vol[:, x, :x + 1]
        want = inside.min(-1) + 0.5 * (inside.mean(-1) - inside.min(-1))
        np.testing.assert_allclose(out[:, x, :x + 1], inside)
        for d in range(x + 1, 4):
            np.testing.assert_allclose(out[:, x, d], want, rtol=1e-6)


def test_predictor_confidence_is_low_where_the_match_is_wrong():
    left, right = shifted_pair(5, h=64, w=128, seed=3)
    rng = np.random.default_rng(9)
    right = right.copy()
    right[16:48, 40:80] = rng.integers(0, 256, (32, 40))        # no true match for left x 45..84
    cfg = stereojax.preset("census", 24)
    disp, conf = stereojax.Predictor(cfg, confidence=True)(left, right)
    np.testing.assert_array_equal(disp, stereojax.Predictor(cfg)(left, right))
    assert conf.shape == disp.shape and conf.dtype == np.float32
    assert 0.0 <= conf.min() and conf.max() <= 1.0
    good = np.zeros(disp.shape, bool)
    good[8:56, 30:40] = good[8:56, 95:120] = True
    bad = np.zeros(disp.shape, bool)
    bad[20:44, 50:80] = True
    assert conf[good].mean() > 2 * conf[bad].mean()
    # the most confident half is more often right than all pixels (a sparsification step)
    wrong = np.abs(disp - 5) > 1
    top = conf >= np.median(conf)
    assert wrong[top].mean() < 0.5 * wrong.mean()
    d2, c2 = stereojax.disparity(left, right, cfg, confidence=True)
    np.testing.assert_array_equal(c2, conf)


def test_predict_writes_the_confidence_and_blanks_below_min_confidence(tmp_path, capsys):
    left, right = shifted_pair(4, h=48, w=96, seed=1)
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    io.write_png(lp, left)
    io.write_png(rp, right)
    assert _cli(["predict", lp, rp, "--out", tmp_path / "a", *FAST], capsys)[0] == 0
    conf = np.load(tmp_path / "a" / "confidence.npy")
    png = cv2.imread(str(tmp_path / "a" / "confidence.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(png, np.round(conf * 255).astype(np.uint8))
    full = io.read_kitti_disparity(tmp_path / "a" / "disparity.png")[1]
    assert full.all()
    t = float(np.median(conf))
    assert _cli(["predict", lp, rp, "--out", tmp_path / "b", *FAST, "--min-confidence", str(t),
                 "--baseline", "0.5", "--focal", "100"], capsys)[0] == 0
    kept = io.read_kitti_disparity(tmp_path / "b" / "disparity.png")[1]
    np.testing.assert_array_equal(kept, conf >= t)
    depth = np.load(tmp_path / "b" / "depth.npy")
    assert (depth[~kept] == 0).all() and (depth[kept] > 0).all()
    code, _, err = _cli(["predict", lp, rp, "--out", tmp_path / "c", *FAST, "--min-confidence", "1.5"], capsys)
    assert code == 2 and "[0, 1]" in err


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
