"""Distillation of a compressed network (issue 16): the near-miss patches lie where they should,
the loss is the label loss plus the weighted cross-entropy to the teacher's similarities, the
student moves towards its teacher, and the compressed network's FLOP count is what it says."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax import ConfigError
from stereojax.learning import losses
from stereojax.models.nets import MatchNet, NetConfig, init_params, network_flops
from stereojax.learning.sampling import PatchData, SamplerConfig, sample_batch, sample_distill_batch
from stereojax.learning.train import (TrainConfig, _pair_losses, fit, init_state, train_preset,
                                      train_step)

from .helpers import tiny_sampler as stereojax_sampler, training_samples as _samples

P = 9


def _ramp():
    """One pair whose right image's value is its column index: a patch's centre tells where it
    was cut."""
    h, w = 40, 120
    right = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))[None]
    ys, xs = np.mgrid[10:30, 40:100]
    n = ys.size
    return PatchData(left=jnp.asarray(right), right=jnp.asarray(right), index=jnp.zeros(n, jnp.int32),
                     y=jnp.asarray(ys.ravel(), jnp.int32), x=jnp.asarray(xs.ravel(), jnp.int32),
                     d=jnp.full(n, 12.0, jnp.float32))


def test_near_miss_patches_lie_within_their_range_of_the_true_match():
    data, cfg = _ramp(), SamplerConfig(v_pos=1.0, z_low=4.0, z_high=18.0)
    key = jax.random.PRNGKey(3)
    ref, pos, neg, soft = sample_distill_batch(key, data, 400, P, cfg, soft_range=6.0)
    for a, b in zip((ref, pos, neg), sample_batch(key, data, 400, P, cfg)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))    # the labelled batch is unchanged
    offset = np.asarray(soft[:, P // 2, P // 2, 0]) - (np.asarray(ref[:, P // 2, P // 2, 0]) - 12.0)
    assert np.abs(offset).max() <= 6.0 + 1e-4
    assert offset.min() < -4.0 and offset.max() > 4.0                 # the whole range is drawn
    assert 0.3 < (offset > 0).mean() < 0.7


def test_distilled_loss_is_label_loss_plus_weighted_cross_entropy_to_the_teacher():
    samples = _samples(1)
    from stereojax.learning.sampling import build_patch_data

    cfg = train_preset("tiny", sampler=stereojax_sampler(), distill=0.7, distill_range=3.0, lr=1e-12)
    teacher_cfg = dataclasses.replace(cfg.net, widths=(16, 8), features=6)
    teacher = init_params(teacher_cfg, jax.random.PRNGKey(5))
    data = build_patch_data(samples, P, cfg.sampler)
    state = init_state(cfg)
    _, m = train_step(state, data, cfg, None, teacher, teacher_cfg)

    key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), 0)
    ref, pos, neg, soft = sample_distill_batch(key, data, cfg.batch, P, cfg.sampler, 3.0)
    student = MatchNet(cfg.net)
    svars = {"params": state["params"], "batch_stats": state["batch_stats"]}
    feats = student.apply(svars, jnp.concatenate([ref, pos, neg, soft]), True,
                          method=MatchNet.features, mutable=["batch_stats"])[0][:, 0, 0]
    b = cfg.batch
    s = [student.apply(svars, feats[:b], feats[(i + 1) * b:(i + 2) * b], method=MatchNet.compare)
         for i in range(3)]
    t = [jax.nn.sigmoid(MatchNet(teacher_cfg).apply(teacher, ref, x)) for x in (pos, neg, soft)]
    want = float(_pair_losses(cfg, s[0], s[1]).mean()) + 0.7 * float(
        np.mean([losses.bce(a, c).mean() for a, c in zip(s, t)]))
    assert float(m["loss"]) == pytest.approx(want, rel=1e-5)


@pytest.mark.slow
def test_distillation_pulls_the_student_to_its_teacher(tmp_path):
    """A student distilled (heavily weighted) from a teacher ends closer to the teacher's
    similarities on unseen pairs than the same student trained on the labels alone."""
    samples = _samples(2)
    base = train_preset("tiny", sampler=stereojax_sampler(), steps=150, lr=0.05, val_every=150,
                        checkpoint_every=150)
    fit(base, samples, None, tmp_path / "teacher", progress=False)
    teacher = stereojax.load_model(tmp_path / "teacher" / "checkpoint.msgpack")
    small = dataclasses.replace(base.net, features=4, widths=(8, 4))
    plain = dataclasses.replace(base, net=small, seed=1, steps=200, val_every=200, checkpoint_every=200)
    distilled = dataclasses.replace(plain, distill=3.0)
    fit(plain, samples, None, tmp_path / "plain", progress=False)
    fit(distilled, samples, None, tmp_path / "distilled", progress=False, teacher=teacher)

    from stereojax.learning.sampling import build_patch_data

    data = build_patch_data(_samples(1, h=48, w=100), P, stereojax_sampler())
    patches = sample_distill_batch(jax.random.PRNGKey(99), data, 512, P, stereojax_sampler(), 6.0)

    def sims(model):
        ref, *rights = patches
        return np.concatenate([np.asarray(jax.nn.sigmoid(MatchNet(model.net).apply(model.variables, ref, r)))
                               for r in rights])

    t = sims(teacher)
    gap = {n: float(np.abs(sims(stereojax.load_model(tmp_path / n / "checkpoint.msgpack")) - t).mean())
           for n in ("plain", "distilled")}
    assert gap["distilled"] < 0.8 * gap["plain"], gap


def test_distillation_needs_a_teacher_and_a_dense_unaugmented_student(tmp_path):
    cfg = train_preset("tiny", sampler=stereojax_sampler(), distill=1.0, steps=2)
    with pytest.raises(ConfigError, match="teacher"):
        fit(cfg, _samples(1), None, tmp_path, progress=False)
    with pytest.raises(ConfigError, match="teacher"):
        fit(dataclasses.replace(cfg, distill=0.0), _samples(1), None, tmp_path, progress=False,
            teacher=stereojax.load_model(stereojax.models.registry.shipped_weights("kitti2015")))
    from stereojax.learning.train import with_augmentation
    with pytest.raises(ConfigError, match="without patch augmentation"):
        with_augmentation(cfg)
    with pytest.raises(ConfigError, match="distill_range"):
        TrainConfig.from_dict({**cfg.to_dict(), "distill_range": 50.0})


def test_network_flops_by_hand():
    net = NetConfig(features=16, layers=4, widths=(64, 32))
    per_pixel = 2 * (9 * 16 + 3 * 9 * 16 * 16) + 2 * 16 * 64 + 16 * (64 * 32 + 32 * 1)
    assert network_flops(net, 10, 20, 16) == 2 * 200 * per_pixel
    paper = NetConfig()   # the paper's head: 512-384-256-128
    per_eval = 512 * 384 + 384 * 256 + 256 * 128 + 128
    assert network_flops(paper, 1, 1, 3) - network_flops(paper, 1, 1, 2) == 2 * per_eval


def test_train_cli_builds_a_compressed_network_and_records_its_teacher(tmp_path, data_root):
    import json

    from stereojax.app.cli import main

    teacher = tmp_path / "t"
    assert main(["train", "--data", str(data_root), "--frames", "000001", "--preset", "tiny",
                 "--steps", "2", "--out", str(teacher)]) == 0
    out = tmp_path / "s"
    assert main(["train", "--data", str(data_root), "--frames", "000001", "--preset", "tiny",
                 "--steps", "2", "--features", "4", "--widths", "8,4", "--distill",
                 str(teacher / "checkpoint.msgpack"), "--distill-weight", "0.5", "--out", str(out)]) == 0
    stored = json.loads((out / "config.json").read_text())
    assert stored["net"]["features"] == 4 and stored["net"]["widths"] == [8, 4]
    assert stored["distill"] == 0.5 and stored["distill_from"].endswith("checkpoint.msgpack")
    assert main(["train", "--data", str(data_root), "--frames", "000001", "--preset", "tiny",
                 "--widths", "8,x", "--out", str(tmp_path / "bad")]) == 3   # a config error
