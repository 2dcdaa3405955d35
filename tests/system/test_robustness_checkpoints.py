"""Checkpoints: truncated or foreign files are refused in one line; training killed with SIGKILL
resumes to the parameters of an uninterrupted run."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time

import flax.serialization as ser
import numpy as np
import pytest

from stereojax import CheckpointError
from stereojax.app.cli import main

from ..helpers import fake_kitti as _fake_kitti
from ..robustness_helpers import _ckpt_step, _cli, _one_line, _subprocess_env


# ---- checkpoints -------------------------------------------------------------------------------

def _shipped():
    from stereojax.models.registry import shipped_weights

    try:
        return shipped_weights("kitti2015")
    except CheckpointError:
        pytest.skip("no shipped weights")


def test_truncated_and_foreign_checkpoints(pair, tmp_path, capsys):
    good = _shipped().read_bytes()
    trunc = tmp_path / "trunc.msgpack"
    trunc.write_bytes(good[: len(good) // 2])
    # another architecture: the arrays of the shipped network under a config that says 32 features
    payload = ser.msgpack_restore(good)
    cfg = json.loads(payload["config"])
    cfg["net"]["features"] = 32
    payload["config"] = json.dumps(cfg)
    other = tmp_path / "other.msgpack"
    other.write_bytes(ser.msgpack_serialize(payload))
    notckpt = tmp_path / "not.msgpack"
    notckpt.write_bytes(ser.msgpack_serialize({"weights": [1, 2, 3]}))
    for case, path, match in [
        ("truncated checkpoint", trunc, "is corrupt or truncated"),
        ("checkpoint from another architecture", other, "has a parameter of shape (64,) where the model has (32,)"),
        ("msgpack that is not a checkpoint", notckpt, "is not a stereojax checkpoint"),
        ("checkpoint path is a folder", tmp_path, "is not a file"),
    ]:
        code, _, err = _cli(["predict", *pair, "--out", tmp_path / "o", "--max-disp", "16", "--method", "learned",
                             "--weights", path], capsys, case)
        assert code == 4 and match in _one_line(err), (case, err)
    assert not (tmp_path / "o").exists()                 # the failed runs made no empty folder


def test_resume_with_another_architecture(tmp_path, capsys):
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=1)
    base = ["train", "--data", root, "--frames", "0", "--preset", "tiny", "--steps", "4", "--out", tmp_path / "run"]
    code, _, _ = _cli(base, capsys)
    assert code == 0
    before = (tmp_path / "run" / "checkpoint.msgpack").read_bytes()
    code, _, err = _cli(base + ["--resume", "--head", "uniform"], capsys, "resume with another architecture")
    assert code == 3 and "cannot resume" in _one_line(err) and "another training config (net.head = 'downsize' there, 'uniform' here)" in err
    assert (tmp_path / "run" / "checkpoint.msgpack").read_bytes() == before     # untouched



# ---- SIGKILL: training resumes to the uninterrupted parameters ---------------------------------

@pytest.mark.slow
def test_sigkill_training_repeatedly_then_resume_gives_the_uninterrupted_parameters(tmp_path, capsys):
    import jax

    rng = random.Random(os.environ.get("ROBUSTNESS_SEED", "1234"))
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=2)
    steps = 1500
    args = ["train", "--data", str(root), "--dataset", "kitti2015", "--frames", "0-1", "--preset", "tiny",
            "--steps", str(steps)]
    t0 = time.perf_counter()
    assert main(args + ["--out", str(tmp_path / "ref")]) == 0
    rate = steps / (time.perf_counter() - t0)              # steps/s, compilation included: a lower bound
    capsys.readouterr()
    ref_step, ref_state = _ckpt_step(tmp_path / "ref" / "checkpoint.msgpack")
    assert ref_step == steps

    out = tmp_path / "killed"
    ckpt = out / "checkpoint.msgpack"
    cmd = [sys.executable, "-m", "stereojax.app.cli", *args, "--resume", "--out", str(out)]
    env = _subprocess_env(tmp_path)
    kills, prev = [], 0
    for attempt in range(6):
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if attempt == 0:
            delay = rng.uniform(0.5, 2.5)                 # during start-up / compilation
            time.sleep(delay)
        else:
            # a random moment while training: after this run wrote its first checkpoint
            before = ckpt.stat().st_mtime_ns if ckpt.exists() else None
            while proc.poll() is None and (not ckpt.exists() or ckpt.stat().st_mtime_ns == before):
                time.sleep(0.005)
            # at most a quarter of the remaining steps (rate: a lower bound of the true rate)
            delay = rng.uniform(0.0, (steps - prev) / (2 * rate) / 4)
            time.sleep(delay)
        alive = proc.poll() is None
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        step, _ = _ckpt_step(ckpt)                          # never damaged
        assert step >= prev and (step % 4 == 0 or step == steps), (prev, step)
        if (out / "config.json").exists():
            json.loads((out / "config.json").read_text())
        assert not (out / "train_summary.json").exists() or step == steps
        assert not [p.name for p in (out.iterdir() if out.exists() else []) if p.is_file() and not p.name.startswith(".")
                    and p.name not in ("checkpoint.msgpack", "config.json", "train_summary.json")]
        kills.append({"attempt": attempt, "delay_s": round(delay, 3), "alive": alive,
                      "checkpoint_step_before": prev, "checkpoint_step_after": step})
        prev = step
    log = os.environ.get("ROBUSTNESS_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps({"case": "SIGKILL train", "steps": steps, "kills": kills}) + "\n")
    assert sum(k["alive"] and k["checkpoint_step_after"] < steps for k in kills) >= 5, kills
    subprocess.run(cmd, check=True, env=env, capture_output=True, timeout=300)
    step, state = _ckpt_step(ckpt)
    assert step == steps
    for x, y in zip(jax.tree_util.tree_leaves(ref_state), jax.tree_util.tree_leaves(state)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
