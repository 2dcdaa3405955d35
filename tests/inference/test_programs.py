"""stereojax.inference.programs: compiled chains are shared by the models of one architecture and hold no
weights, and a batch of many sizes keeps only a few of them (and their memory maps)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import stereojax

ROOT = Path(__file__).resolve().parents[2]


def test_a_second_model_of_the_same_shapes_never_runs_the_first_ones_weights():
    """Compiled chains are shared by every model of one architecture and hold no weights: after
    a first model is dropped, a second one with the same shapes (even one that gets the first's
    address) computes its own disparity, on the default device and on an explicit one."""
    import gc

    import jax

    from stereojax.matching_cost.learned import LearnedModel
    from stereojax.models.nets import NetConfig, init_params
    from stereojax.inference.predictor import Predictor

    from ..helpers import shifted_pair

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
