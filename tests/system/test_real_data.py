"""End-to-end runs on the real frames of ../shared/data, with error bounds."""

import numpy as np
import pytest

import stereojax
from stereojax.app.baselines import sgbm_disparity
from stereojax.data import load_kitti2012, load_kitti2015, load_middlebury
from stereojax.metrics import evaluate


@pytest.mark.slow
def test_kitti2015_validation_frame_beats_sgbm(data_root):
    s = load_kitti2015(data_root / "kitti2015" / "training", "000021")
    disp = stereojax.disparity(s.left, s.right, stereojax.preset("census", 228))
    ours = evaluate(disp, s.gt, s.gt_valid)
    d_cv, v_cv = sgbm_disparity(s.left, s.right, 228, pad=True)
    cv = evaluate(d_cv, s.gt, s.gt_valid, est_valid=v_cv)
    assert ours["density"] == 100.0
    # measured: census pipeline ~5.6 % > 3 px on this frame, padded SGBM ~7.5 %
    assert ours["bad3"] < 8.0
    assert ours["bad3"] < cv["bad3"]


@pytest.mark.slow
def test_kitti2012_frame(data_root):
    s = load_kitti2012(data_root / "kitti2012" / "training", "000000", gt="occ")
    disp = stereojax.disparity(s.left, s.right, stereojax.preset("census", 228))
    m = evaluate(disp, s.gt, s.gt_valid)
    assert m["bad3"] < 10.0, m


def test_middlebury_tsukuba_small(data_root):
    s = load_middlebury(data_root / "middlebury" / "Tsukuba_2001", gt="noc")
    disp = stereojax.disparity(s.left, s.right, stereojax.preset("census", 16))
    m = evaluate(disp, s.gt, s.gt_valid)
    assert disp.shape == s.gt.shape
    assert np.all((disp >= 0) & (disp <= 15))
    assert m["bad3"] < 8.0, m


def test_sgbm_baseline_left_padding_helps(data_root):
    # over 000021-000030 this setting measured 6.2 % > 3 px padded and 11.1 % unpadded (the
    # issue's reference: about 6.0 % and 11 %); on frame 000022 6.3 % and 6.5 %
    s = load_kitti2015(data_root / "kitti2015" / "training", "000022")
    scores = {}
    for pad in (True, False):
        d, v = sgbm_disparity(s.left, s.right, 228, pad=pad)
        scores[pad] = evaluate(d, s.gt, s.gt_valid, est_valid=v)
    assert scores[True]["bad3"] < scores[False]["bad3"]
    assert scores[True]["density"] > scores[False]["density"]
    assert scores[True]["bad3"] < 8.0


def test_shipped_kitti_model_classifies_validation_patches(data_root):
    import dataclasses

    from stereojax.models import checkpoint
    from stereojax.learning.sampling import build_patch_data
    from stereojax.models.registry import shipped_weights
    from stereojax.learning.train import TrainConfig, eval_step

    path = shipped_weights("kitti2015")
    model = stereojax.load_model(path)
    stored = checkpoint.read_config(path)
    cfg = TrainConfig.from_stored(stored)   # the stored config also names its data and init
    s = load_kitti2015(data_root / "kitti2015" / "training", "000021")
    data = build_patch_data([s], cfg.net.patch_size, cfg.sampler)
    _, err = eval_step(dict(model.variables), data, dataclasses.replace(cfg, seed=3), 2000)
    # measured: 7.2 % of 3000 pairs misclassified over frames 000021-000030 (chance: 50 %)
    assert float(err) < 0.15


@pytest.mark.slow
def test_learned_predict_with_shipped_weights(data_root, tmp_path):
    from stereojax.app.cli import main

    s = load_kitti2015(data_root / "kitti2015" / "training", "000021")
    import cv2
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(lp), np.ascontiguousarray(s.left[-96:, 300:620, ::-1]))
    cv2.imwrite(str(rp), np.ascontiguousarray(s.right[-96:, 300:620, ::-1]))
    assert main(["predict", str(lp), str(rp), "--out", str(tmp_path / "o"), "--max-disp", "48",
                 "--method", "learned"]) == 0
    assert (tmp_path / "o" / "disparity.png").exists()
