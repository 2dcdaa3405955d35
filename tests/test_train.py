"""Training loop: learning happens, checkpoints round-trip, resume is exact, bad input is caught."""

import dataclasses
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

import stereojax
from stereojax import CheckpointError, ConfigError
from stereojax.errors import TrainingError
from stereojax.learning.train import TrainConfig, fit, train_preset

from .helpers import tiny_sampler as stereojax_sampler, tiny_train_config as _tiny, training_samples as _samples


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
    root = str(Path(__file__).resolve().parents[1])
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
