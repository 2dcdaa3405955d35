"""Training loop (stereojax.learning.train): learning happens, checkpoints round-trip, resume is exact, bad
input is caught, a stopped run keeps its work; augmentation settings and distillation from a teacher."""

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax import CheckpointError, ConfigError
from stereojax.errors import TrainingError
from stereojax.learning import losses
from stereojax.learning.sampling import AUGMENT_MCCNN, SamplerConfig, sample_distill_batch
from stereojax.learning.train import TrainConfig, _pair_losses, fit, init_state, train_preset, train_step
from stereojax.models.nets import MatchNet, init_params

from ..helpers import (tiny_sampler as stereojax_sampler, tiny_train_config as _tiny,
                       training_samples as _samples)

P = 9
ROOT = Path(__file__).resolve().parents[2]


def _leaves(path):
    from stereojax.models import checkpoint
    from stereojax.learning.train import init_state
    cfg = TrainConfig.from_dict(checkpoint.read_config(path))
    state, _ = checkpoint.load(path, init_state(cfg))
    return jax.tree_util.tree_leaves(state)


def test_training_learns_on_a_shifted_pair(tmp_path):
    cfg = train_preset("tiny", sampler=stereojax_sampler(), steps=150, lr=0.05, log_every=10,
                       val_every=150, val_pairs=256, checkpoint_every=150)
    s = fit(cfg, _samples(), _samples(1), tmp_path, progress=False)
    assert s["steps"] == 150
    assert s["validation"]["error"] < 0.25          # chance is 0.5
    model = stereojax.load_model(tmp_path / "checkpoint.msgpack")
    assert model.net == cfg.net
    assert (tmp_path / "tb").is_dir() and (tmp_path / "config.json").exists()


def test_resume_in_process_is_exact(tmp_path):
    cfg = _tiny(steps=12)
    fit(cfg, _samples(), None, tmp_path / "a", progress=False)
    fit(cfg, _samples(), None, tmp_path / "b", progress=False, stop_after=5)
    fit(cfg, _samples(), None, tmp_path / "b", progress=False, resume=True)
    for x, y in zip(_leaves(tmp_path / "a" / "checkpoint.msgpack"), _leaves(tmp_path / "b" / "checkpoint.msgpack")):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


_CHILD = """
import sys, time, numpy as np
sys.path.insert(0, {root!r})
from tests.helpers import tiny_train_config as _tiny, training_samples as _samples
from stereojax.learning.train import fit
cfg = _tiny(steps=3000, checkpoint_every=50, log_every=50)
fit(cfg, _samples(), None, {out!r}, progress=False, resume=True)
"""


@pytest.mark.slow
def test_sigkill_mid_run_then_resume_gives_the_uninterrupted_parameters(tmp_path):
    root = str(Path(__file__).resolve().parents[2])
    ref = tmp_path / "ref"
    fit(_tiny(steps=3000, checkpoint_every=50, log_every=50), _samples(), None, ref, progress=False)
    out = tmp_path / "killed"
    code = _CHILD.format(root=root, out=str(out))
    proc = subprocess.Popen([sys.executable, "-c", code])
    ckpt = out / "checkpoint.msgpack"
    deadline = time.time() + 120
    while not ckpt.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    from stereojax.models import checkpoint
    from stereojax.learning.train import TrainConfig, init_state
    killed_at = 0
    if ckpt.exists():
        cfg = TrainConfig.from_dict(checkpoint.read_config(ckpt))
        state, _ = checkpoint.load(ckpt, init_state(cfg))
        killed_at = int(state["step"])
    assert killed_at < 3000, "the child finished before it was killed"
    # no partial files next to the checkpoint
    assert not [p for p in out.iterdir() if ".tmp-" in p.name]
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    for x, y in zip(_leaves(ref / "checkpoint.msgpack"), _leaves(ckpt)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(tmp_path):
    cfg = _tiny(steps=12, lr=1e30, checkpoint_every=1)
    with pytest.raises(TrainingError, match="loss became"):
        fit(cfg, _samples(), None, tmp_path, progress=False)
    model = stereojax.load_model(tmp_path / "checkpoint.msgpack")
    leaves = jax.tree_util.tree_leaves(model.variables)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in leaves)


@pytest.mark.parametrize("over, match", [
    (dict(sampler=dict(z_low=5.0, z_high=4.0)), "z_low < z_high"),
    (dict(delta=0.4), "delta"),
    (dict(delta=-0.1), "delta"),
    (dict(loss="hinge"), "does not fit"),
    (dict(bacth=3), "did you mean 'batch'"),
])
def test_contradictory_training_configs(over, match):
    base = _tiny().to_dict()
    for k, v in over.items():
        base[k] = {**base[k], **v} if isinstance(v, dict) else v
    with pytest.raises(ConfigError, match=match):
        TrainConfig.from_dict(base)


def test_bad_checkpoints(tmp_path):
    cfg = _tiny(steps=2, checkpoint_every=2)
    fit(cfg, _samples(1), None, tmp_path, progress=False)
    good = tmp_path / "checkpoint.msgpack"
    trunc = tmp_path / "trunc.msgpack"
    trunc.write_bytes(good.read_bytes()[:100])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        stereojax.load_model(trunc)
    with pytest.raises(CheckpointError, match="does not exist"):
        stereojax.load_model(tmp_path / "nope.msgpack")
    other = dataclasses.replace(cfg.net, features=cfg.net.features + 1)
    with pytest.raises(CheckpointError, match="is for network"):
        stereojax.load_model(good, expect_net=other)
    text = tmp_path / "text.msgpack"
    text.write_text("hello")
    with pytest.raises(CheckpointError):
        stereojax.load_model(text)


def test_learned_pipeline_runs_end_to_end(tmp_path):
    cfg = _tiny(steps=2, checkpoint_every=2)
    fit(cfg, _samples(1), None, tmp_path, progress=False)
    model = stereojax.load_model(tmp_path / "checkpoint.msgpack")
    left, right = _samples(1, h=24, w=48)[0].left, _samples(1, h=24, w=48)[0].right
    conf = stereojax.StereoConfig(max_disp=8, cost=stereojax.CostConfig(method="learned", rows_per_tile=8))
    disp = stereojax.disparity(left, right, conf, params=model)
    assert disp.shape == left.shape and np.all((disp >= 0) & (disp <= 7))
    with pytest.raises(ConfigError, match="needs params"):
        stereojax.disparity(left, right, conf)


def test_fit_from_init_starts_at_those_weights_and_refuses_another_network(tmp_path):
    first = _tiny(steps=12, lr=0.05)
    fit(first, _samples(), None, tmp_path / "a", progress=False)
    a = stereojax.load_model(tmp_path / "a" / "checkpoint.msgpack")
    # from a's weights with a vanishing learning rate: the parameters stay a's, not seed 1's
    cfg = _tiny(steps=4, seed=1, lr=1e-12)
    fit(cfg, _samples(), None, tmp_path / "b", progress=False, init=a)
    b = stereojax.load_model(tmp_path / "b" / "checkpoint.msgpack")
    fresh = stereojax.models.nets.init_params(cfg.net, jax.random.PRNGKey(1))
    pa, pb = (jax.tree_util.tree_leaves(m.variables["params"]) for m in (a, b))
    assert max(float(np.abs(x - y).max()) for x, y in zip(pa, pb)) < 1e-6
    assert max(float(np.abs(x - y).max()) for x, y in zip(pa, jax.tree_util.tree_leaves(fresh["params"]))) > 1e-3
    other = dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, features=4))
    with pytest.raises(ConfigError, match="--init model has network"):
        fit(other, _samples(), None, tmp_path / "c", progress=False, init=a)


def test_config_from_stored_drops_run_facts():
    """A fine-tune's stored config names its data and init weights: from_stored reads the
    settings back, from_dict refuses the unknown keys."""
    from stereojax.errors import ConfigError
    cfg = train_preset("tiny", steps=7, lr=0.003)
    stored = {**cfg.to_dict(), "data": {"dataset": "kitti2015", "frames": ["000001"]}, "init": "kitti2015"}
    assert TrainConfig.from_stored(stored) == cfg
    with pytest.raises(ConfigError, match="unknown config key"):
        TrainConfig.from_dict(stored)


def test_train_config_round_trips_augmentation_and_old_configs_still_load():
    from stereojax.learning.train import TrainConfig, train_preset

    cfg = train_preset("tiny", sampler=SamplerConfig(augment=AUGMENT_MCCNN))
    again = TrainConfig.from_dict(cfg.to_dict())
    assert again.sampler.augment == AUGMENT_MCCNN
    old = cfg.to_dict()
    old["sampler"].pop("augment")                                 # a checkpoint from before the option
    assert not TrainConfig.from_dict(old).sampler.augment.enabled


def test_train_augment_flag_turns_on_the_mccnn_augmentation():
    from stereojax.learning.train import train_preset, with_augmentation

    cfg = train_preset("tiny")
    assert with_augmentation(cfg).sampler.augment == AUGMENT_MCCNN
    assert with_augmentation(cfg).sampler.v_pos == cfg.sampler.v_pos          # the rest untouched
    assert not cfg.sampler.augment.enabled


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
