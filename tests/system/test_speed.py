"""The fast paths of the chain: size buckets (pad, run, crop back exactly), the adaptive pruned head against
the exact head, the inference-only imports."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax.config import CostConfig, StereoConfig
from stereojax.data import load_kitti2015
from stereojax.inference.compile_cache import bucket_shape
from stereojax.matching_cost import learned as learned_cost
from stereojax.models.nets import init_params, net_preset

TINY = dataclasses.replace(net_preset("downsize", 8), widths=(6, 6, 6, 6))
ROOT = Path(__file__).resolve().parents[2]


def _tiny_variables(seed=0):
    v = init_params(TINY, jax.random.PRNGKey(seed))
    return {"params": v["params"], "batch_stats": jax.tree_util.tree_map(lambda x: x + 0.1, v["batch_stats"])}


def _crop(data_root, h, w, y0=120, x0=300):
    s = load_kitti2015(data_root / "kitti2015" / "training", "000021")
    return s.left[y0:y0 + h, x0:x0 + w], s.right[y0:y0 + h, x0:x0 + w]


@pytest.mark.parametrize("h,w", [(100, 300), (75, 261)])
def test_bucketed_census_chain_equals_unpadded_away_from_padding(data_root, h, w):
    left, right = _crop(data_root, h, w)
    cfg = stereojax.preset("census", 48)
    exact = stereojax.disparity(left, right, cfg, bucket=False)
    bucketed = stereojax.disparity(left, right, cfg)
    assert bucketed.shape == exact.shape == (h, w)
    assert bucket_shape(h, w) != (h, w)                   # there really is padding
    # SGM paths restart and cross arms stop at the edge of the real pixels, the right view
    # ignores matches in the padding: only the 5x5 median sees it, within 2 px of the edge
    np.testing.assert_allclose(bucketed[:-2, :-2], exact[:-2, :-2], atol=1e-4)


def test_bucketed_learned_chain_equals_unpadded_away_from_padding(data_root):
    left, right = _crop(data_root, 90, 250)
    model = stereojax.load_model(stereojax.models.registry.shipped_weights("kitti2015"))
    base = stereojax.preset("learned", 40)
    assert 0 < base.cost.unsure_share < 1 and base.cost.candidates > 0   # adaptive pruned mode by default
    exact = stereojax.disparity(left, right, base, params=model, bucket=False)
    bucketed = stereojax.disparity(left, right, base, params=model)
    np.testing.assert_allclose(bucketed[:-2, :-2], exact[:-2, :-2], atol=1e-3)


def test_adaptive_head_with_every_candidate_equals_exact():
    v = _tiny_variables()
    rng = np.random.default_rng(0)
    fl = jnp.asarray(rng.normal(size=(6, 12, TINY.features)).astype(np.float32))
    fr = jnp.asarray(rng.normal(size=(6, 12, TINY.features)).astype(np.float32))
    d = 5
    exact = np.asarray(learned_cost.dense_cost(TINY, v, fl, fr, d, rows_per_tile=4))
    cand_vol = jnp.asarray(rng.random((6, 12, d)).astype(np.float32))
    cfg = StereoConfig(max_disp=d, cost=CostConfig(method="learned", candidates=d))
    every = np.asarray(learned_cost.adaptive_dense_cost(TINY, v, fl, fr, cand_vol, cfg))
    np.testing.assert_allclose(every, exact, atol=1e-5)


def test_adaptive_head_evaluates_k_candidates_and_more_for_the_least_sure_share():
    v = _tiny_variables(1)
    rng = np.random.default_rng(1)
    h, w, d, k1, k2, share = 8, 10, 12, 2, 5, 0.25
    fl = jnp.asarray(rng.normal(size=(h, w, TINY.features)).astype(np.float32))
    fr = jnp.asarray(rng.normal(size=(h, w, TINY.features)).astype(np.float32))
    exact = np.asarray(learned_cost.dense_cost(TINY, v, fl, fr, d, rows_per_tile=4))
    cand_vol = rng.random((h, w, d)).astype(np.float32)                   # distinct values: no ties
    cfg = StereoConfig(max_disp=d, cost=CostConfig(method="learned", candidates=k1, unsure_share=share,
                                                   unsure_candidates=k2))
    vol = np.asarray(learned_cost.adaptive_dense_cost(TINY, v, fl, fr, jnp.asarray(cand_vol), cfg))
    seen = (vol != 1.0).reshape(h * w, d)
    np.testing.assert_allclose(vol[vol != 1.0], exact[vol != 1.0], atol=1e-5)   # evaluated = exact head
    order = np.argsort(cand_vol.reshape(h * w, d), axis=1)
    rows = np.arange(h * w)[:, None]
    assert seen[rows, order[:, :k1]].all()                                 # K best for every pixel
    # the least sure pixels (poorest best head cost among their K) get the K2 best
    best = exact.reshape(h * w, d)[rows, order[:, :k1]].min(1)
    chosen = np.argsort(-best, kind="stable")[:int(share * h * w)]
    assert seen[chosen[:, None], order[chosen, :k2]].all()
    assert seen.sum() == h * w * k1 + len(chosen) * (k2 - k1)              # and nothing else


@pytest.mark.slow
def test_fast_learned_chain_matches_exact_head_on_a_real_frame(data_root):
    """The default (adaptive pruned) learned chain against the exact head on a KITTI 2015
    crop: stated tolerance, >= 95 % of the pixels within 1 px of the exact chain's disparity
    and the > 3 px error against the GT within 1.5 points of it."""
    from stereojax.metrics import evaluate

    s = load_kitti2015(data_root / "kitti2015" / "training", "000022")
    crop = (slice(235, 375), slice(500, 800))
    left, right, gt, valid = s.left[crop], s.right[crop], s.gt[crop], s.gt_valid[crop]
    model = stereojax.load_model(stereojax.models.registry.shipped_weights("kitti2015"))
    fast_cfg = stereojax.preset("learned", 96)
    exact_cfg = dataclasses.replace(fast_cfg, cost=dataclasses.replace(fast_cfg.cost, candidates=0))
    fast = stereojax.disparity(left, right, fast_cfg, params=model)
    exact = stereojax.disparity(left, right, exact_cfg, params=model)
    agree = float((np.abs(fast - exact) <= 1.0).mean())
    e_fast, e_exact = evaluate(fast, gt, valid)["bad3"], evaluate(exact, gt, valid)["bad3"]
    assert agree >= 0.95, agree
    assert abs(e_fast - e_exact) <= 1.5, (e_fast, e_exact)


def test_inference_path_does_not_import_training(tmp_path):
    code = ("import sys, stereojax, stereojax.app.cli, stereojax.models.registry, stereojax.inference.predictor;"
            "m = stereojax.load_model(stereojax.models.registry.shipped_weights('kitti2015'));"
            "print('stereojax.learning.train' in sys.modules, 'optax' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.split() == ["False", "False"], out.stdout
