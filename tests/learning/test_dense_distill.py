"""Dense distillation on the band chain: the teacher's targets equal its full-range cost at the
band disparities, the student's strip scores equal its per-patch scores, the target cache
resumes, and a training run with the dense term learns the teacher's band costs."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax.learning.dense_distill import (DenseTargets, band_scores, cache_targets,
                                              dense_batch, load_targets, sample_weights,
                                              teacher_targets)
from stereojax.matching_cost.learned import LearnedModel, naive_dense_cost, tower_features
from stereojax.models.nets import MatchNet, NetConfig, init_params
from tests.helpers import shifted_pair

NET = NetConfig(features=8, widths=(16, 8))


def _teacher(seed=0, sharpen=1.0):
    """A random teacher; ``sharpen`` scales its output layer, so its similarities spread over [0, 1]."""
    variables = init_params(NET, jax.random.PRNGKey(seed))
    if sharpen != 1.0:
        variables = jax.tree_util.tree_map_with_path(
            lambda path, x: x * sharpen if "out" in jax.tree_util.keystr(path) else x, variables)
    return LearnedModel(NET, variables)


def _config(max_disp=24, width=8):
    cfg = stereojax.preset("learned", max_disp)
    return dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=width)).validate()


def test_teacher_targets_equal_its_full_range_cost_in_the_band():
    left, right = (a.astype(np.float32) for a in shifted_pair(5, h=48, w=96))
    teacher, cfg = _teacher(), _config()
    t = teacher_targets(teacher, cfg, left, right, n_pixels=200, seed=1)
    assert t["target"].shape == (200, cfg.band.width)
    fl, fr = tower_features(NET, teacher.variables, jnp.asarray(left), jnp.asarray(right))
    full = 1.0 - np.asarray(naive_dense_cost(NET, teacher.variables, fl, fr, cfg.max_disp))     # similarity
    ys, xs, off = (t[k].astype(int) for k in ("y", "x", "offset"))
    d = off[:, None] + np.arange(cfg.band.width)[None, :]
    want = full[ys[:, None], xs[:, None], np.clip(d, 0, cfg.max_disp - 1)]
    inside = xs[:, None] - d >= NET.layers
    got = t["target"].astype(np.float32)
    assert np.array_equal(np.isfinite(got), inside)
    np.testing.assert_allclose(got[inside], want[inside], atol=2e-3)          # float16 storage
    assert 0 <= off.min() and off.max() <= cfg.max_disp - cfg.band.width


def test_sample_weights_favour_edges_and_flat_regions():
    grey = np.tile(np.linspace(0, 255, 64, dtype=np.float32), (32, 1))
    grey[:, 32:] = 100.0                                             # flat right half
    grey += np.random.default_rng(0).normal(0, 10, grey.shape).astype(np.float32) * (np.arange(64) < 32)
    offset = np.zeros((32, 64), np.int32)
    offset[:, 16:] = 10                                              # a depth edge at column 16
    w = sample_weights(grey, offset, margin=5)
    assert w[:5].max() == 0 and w[:, -5:].max() == 0
    assert w[16, 16] > w[16, 8] and w[16, 45] > w[16, 8]


def _targets(n=40, k=6, seed=0):
    rng = np.random.default_rng(seed)
    left, right = (a.astype(np.float32) for a in shifted_pair(4, h=40, w=80, seed=seed))
    y = rng.integers(4, 36, n)
    off = rng.integers(0, 10, n)
    x = rng.integers(4 + 10 + k, 76, n)
    return DenseTargets(jnp.asarray(left[None]), jnp.asarray(right[None]), jnp.zeros(n, jnp.int32),
                        jnp.asarray(y, jnp.int32), jnp.asarray(x, jnp.int32), jnp.asarray(off, jnp.int32),
                        jnp.asarray(rng.random((n, k)), jnp.float32))


def test_student_strip_scores_equal_its_patch_scores():
    data = _targets()
    variables = init_params(NET, jax.random.PRNGKey(3))
    ref, strip, target, valid = dense_batch(jax.random.PRNGKey(0), data, 16, NET.patch_size)
    assert strip.shape == (16, 9, data.width + 8, 1) and bool(valid.all())
    scores, _ = band_scores(MatchNet(NET), variables, ref, strip, train=False)
    i = jax.random.randint(jax.random.PRNGKey(0), (16,), 0, data.size)        # the pixels dense_batch drew
    right = np.asarray(data.right[0])
    for b in range(3):
        y, x, off = int(data.y[i[b]]), int(data.x[i[b]]), int(data.offset[i[b]])
        for k in range(data.width):
            xr = x - off - k
            patch = jnp.asarray(right[y - 4:y + 5, xr - 4:xr + 5])[None, ..., None]
            want = MatchNet(NET).apply(variables, ref[b:b + 1], patch, False)
            np.testing.assert_allclose(float(scores[b, k]), float(want[0]), rtol=1e-4, atol=1e-5)


def test_target_cache_resumes_and_notices_other_settings(tmp_path):
    left, right = (a.astype(np.float32) for a in shifted_pair(5, h=48, w=96))
    frames = [("a", lambda: (left, right)), ("b", lambda: (right, left))]
    teacher, cfg = _teacher(), _config()
    files = cache_targets(frames, teacher, cfg, tmp_path, n_pixels=50, progress=False)
    stamps = [f.stat().st_mtime_ns for f in files]
    assert cache_targets(frames, teacher, cfg, tmp_path, n_pixels=50, progress=False) == files
    assert [f.stat().st_mtime_ns for f in files] == stamps                   # kept, not recomputed
    files[1].write_bytes(b"damaged")
    cache_targets(frames, teacher, cfg, tmp_path, n_pixels=50, progress=False)
    assert files[0].stat().st_mtime_ns == stamps[0] and files[1].stat().st_size > 100
    cache_targets(frames, teacher, cfg, tmp_path, n_pixels=60, progress=False)
    assert files[0].stat().st_mtime_ns != stamps[0]                          # other settings: recomputed
    data = load_targets(files)
    assert data.size == 120 and data.width == cfg.band.width and data.left.shape == (2, 48, 96)


@pytest.mark.slow
def test_dense_term_teaches_the_students_band_costs(tmp_path):
    """A student trained on the dense term alone gets closer to the teacher's band costs."""
    from stereojax.learning.train import fit
    from tests.helpers import tiny_train_config, training_samples

    left, right = (a.astype(np.float32) for a in shifted_pair(5, h=48, w=96))
    teacher, cfg = _teacher(seed=7, sharpen=30.0), _config()
    files = cache_targets([("a", lambda: (left, right))], teacher, cfg, tmp_path / "t", n_pixels=300,
                          progress=False)
    data = load_targets(files)
    student_net = NetConfig(features=8, widths=(16, 8))
    tcfg = dataclasses.replace(tiny_train_config(steps=300, checkpoint_every=300, log_every=50, val_every=300),
                               net=student_net, dense=20.0, dense_batch=64, lr=0.05).validate()

    def band_error(variables):
        ref, strip, target, valid = dense_batch(jax.random.PRNGKey(99), data, 256, 9)
        s, _ = band_scores(MatchNet(student_net), variables, ref, strip, train=False)
        return float(jnp.mean(jnp.abs(jax.nn.sigmoid(s) - target)[valid]))

    before = band_error(init_params(student_net, jax.random.PRNGKey(tcfg.seed)))
    assert float(jnp.nanstd(data.target)) > 0.2                              # targets worth learning
    with pytest.raises(stereojax.errors.ConfigError, match="dense distillation targets"):
        fit(tcfg, training_samples(), None, tmp_path / "x", progress=False)
    fit(tcfg, training_samples(), None, tmp_path / "s", progress=False, dense=data)
    from stereojax.models.registry import load_model

    after = band_error(load_model(tmp_path / "s" / "checkpoint.msgpack").variables)
    assert after < 0.6 * before, (before, after)
