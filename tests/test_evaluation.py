"""The one evaluation loop (stereojax.app.evaluation.evaluate_frames) and the cached-volume path
of the Predictor (volume -> from_volume), which the chain search scores with."""

import dataclasses

import numpy as np
import pytest

import stereojax
from stereojax import metrics
from stereojax.data.datasets import StereoSample
from stereojax.app.evaluation import chain_method, evaluate_frames, format_table, sgbm_method

from .helpers import shifted_pair, training_samples


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


def test_volume_then_from_volume_equals_the_whole_chain():
    """What the chain search scores (cached volume, then the rest) is what the chain computes,
    for a classical and a learned cost and for changed back-end settings."""
    from stereojax.models.nets import init_params, net_preset
    from stereojax.matching_cost.learned import LearnedModel
    import jax

    left, right = training_samples(1, h=40, w=72, d=4)[0].left, training_samples(1, h=40, w=72, d=4)[0].right
    net = net_preset("downsize", 4)
    net = dataclasses.replace(net, widths=(8, 4)).validate()
    model = LearnedModel(net, init_params(net, jax.random.PRNGKey(1)))
    learned = stereojax.preset("learned", 12)
    learned = dataclasses.replace(learned, cost=dataclasses.replace(learned.cost, candidates=4, unsure_share=0.0,
                                                                     unsure_candidates=0)).validate()
    for cfg, m in ((stereojax.preset("census", 12), None), (learned, model)):
        predictor = stereojax.Predictor(cfg, m)
        vol = predictor.volume(left, right)
        np.testing.assert_allclose(predictor.from_volume(vol), predictor(left, right), atol=1e-5)
        other = dataclasses.replace(cfg, sgm=dataclasses.replace(cfg.sgm, p2=cfg.sgm.p2 * 3)).validate()
        np.testing.assert_allclose(stereojax.Predictor(other, m).from_volume(vol),
                                   stereojax.Predictor(other, m)(left, right), atol=1e-5)
