"""The fast paths of the chain: size buckets (pad, run, crop back exactly), the adaptive pruned
head against the exact head, the persistent compilation cache, the inference-only imports."""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax.matching_cost import learned as learned_cost
from stereojax.inference.compile_cache import bucket_shape
from stereojax.config import CostConfig, StereoConfig
from stereojax.data import load_kitti2015
from stereojax.models.nets import init_params, net_preset

TINY = dataclasses.replace(net_preset("downsize", 8), widths=(6, 6, 6, 6))
ROOT = Path(__file__).resolve().parents[1]


def _tiny_variables(seed=0):
    v = init_params(TINY, jax.random.PRNGKey(seed))
    return {"params": v["params"], "batch_stats": jax.tree_util.tree_map(lambda x: x + 0.1, v["batch_stats"])}


def test_kitti_sizes_share_one_bucket():
    sizes = [(375, 1242), (374, 1238), (370, 1224), (376, 1241)]
    assert {bucket_shape(h, w) for h, w in sizes} == {(384, 1248)}
    assert bucket_shape(384, 1248) == (384, 1248)          # already a bucket: no padding
    assert bucket_shape(1, 1) == (16, 32)


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
    crop = (slice(235, 375), slice(300, 800))
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


@pytest.mark.slow
def test_second_process_reads_the_compilation_cache(tmp_path):
    """A second process compiling the same chain finds it in STEREOJAX_CACHE_DIR."""
    code = ("import numpy as np, stereojax, time; from stereojax.inference import compile_cache, programs;"
            "compile_cache.enable(); cfg = stereojax.preset('census', 16);"
            "t = time.perf_counter(); programs.compiled_chain((48, 64), cfg); print(time.perf_counter() - t)")
    env = {**os.environ, "STEREOJAX_CACHE_DIR": str(tmp_path / "cache")}

    def run():
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                             cwd=ROOT, check=True)
        return float(out.stdout.strip().splitlines()[-1])

    first = run()
    files = list((tmp_path / "cache").rglob("*"))
    assert any(f.is_file() for f in files), "nothing was written to the cache folder"
    second = run()
    assert second < first, (first, second)


def test_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    from stereojax.inference import compile_cache

    monkeypatch.setenv("STEREOJAX_CACHE_DIR", str(tmp_path / "c"))
    assert compile_cache.cache_dir() == tmp_path / "c"
    monkeypatch.setenv("STEREOJAX_CACHE_DIR", "off")
    assert compile_cache.cache_dir() is None and compile_cache.enable() is None
    monkeypatch.delenv("STEREOJAX_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert compile_cache.cache_dir() == tmp_path / "x" / "stereojax" / "jax"


def test_inference_path_does_not_import_training(tmp_path):
    code = ("import sys, stereojax, stereojax.app.cli, stereojax.models.registry, stereojax.inference.predictor;"
            "m = stereojax.load_model(stereojax.models.registry.shipped_weights('kitti2015'));"
            "print('stereojax.learning.train' in sys.modules, 'optax' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.split() == ["False", "False"], out.stdout


def test_a_second_model_of_the_same_shapes_never_runs_the_first_ones_weights():
    """Compiled chains are shared by every model of one architecture and hold no weights: after
    a first model is dropped, a second one with the same shapes (even one that gets the first's
    address) computes its own disparity, on the default device and on an explicit one."""
    import gc

    import jax

    from stereojax.matching_cost.learned import LearnedModel
    from stereojax.models.nets import NetConfig, init_params
    from stereojax.inference.predictor import Predictor

    from .helpers import shifted_pair

    net = NetConfig(features=4, widths=(8, 4))
    cfg = stereojax.StereoConfig(max_disp=12, cost=stereojax.CostConfig(method="learned", candidates=4,
                                                                         rows_per_tile=8))
    left, right = shifted_pair(3, h=32, w=64)

    def model(seed):
        v = init_params(net, jax.random.PRNGKey(seed))
        return LearnedModel(net, jax.tree_util.tree_map(np.asarray, v))

    for device in (None, jax.devices()[0]):
        first = model(0)
        address = id(first.variables)
        out_first = Predictor(cfg, first, device)(left, right)
        del first
        gc.collect()
        for seed in range(1, 60):          # try to be given the first model's address
            second = model(seed)
            if id(second.variables) == address:
                break
        predict = Predictor(cfg, second, device)
        assert predict.is_compiled(*left.shape)              # the program is shared ...
        out_second = predict(left, right)
        expect = stereojax.disparity(left, right, cfg, params=second, bucket=False)
        np.testing.assert_allclose(out_second, expect, atol=1e-4)   # ... the weights are not
        assert np.abs(out_second - out_first).max() > 0.5


@pytest.mark.slow
def test_a_batch_of_many_sizes_keeps_its_memory_maps_bounded(tmp_path):
    """Frames of 8 size buckets in one process: the chains beyond the few kept are freed, with
    their machine code's memory maps (each census chain holds hundreds; a long batch of mixed
    sizes once grew without bound towards the kernel's vm.max_map_count and crashed in XLA).
    In a subprocess of its own, with the compile cache off, so that nothing else counts."""
    code = """
import os, numpy as np, stereojax
from stereojax.inference import programs
maps = lambda: sum(1 for _ in open(f"/proc/{os.getpid()}/maps"))
rng = np.random.default_rng(0)
seen = []
for i in range(8):
    left = rng.integers(0, 255, (48 + 16 * i, 96)).astype(np.uint8)
    stereojax.disparity(left, np.roll(left, -3, axis=1), stereojax.preset("census", 16))
    seen.append(maps())
print(programs._KEEP_PER_DEVICE, len(programs._COMPILED), *seen)
"""
    env = {**os.environ, "STEREOJAX_CACHE_DIR": "off", "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=ROOT,
                         check=True, timeout=600)
    keep, kept, *seen = map(int, out.stdout.split())
    assert kept == keep
    per_chain = (seen[keep - 1] - seen[0]) / (keep - 1)         # what one more compiled chain adds
    assert per_chain > 50                                        # the measure sees the chains at all
    # after the first evictions the count stays near that of `keep` chains, not 8
    assert max(seen[keep + 1:]) < seen[keep] + 2 * per_chain, seen
