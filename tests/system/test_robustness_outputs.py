"""Outputs: an unwritable folder or a full disk ends in one line and no partial file; predict
killed with SIGKILL leaves complete files or none."""

from __future__ import annotations

import errno
import json
import os
import random
import subprocess
import time
from pathlib import Path

import pytest


from ..helpers import fake_kitti as _fake_kitti
from ..robustness_helpers import _ckpt_step, FAST, _check_complete, _cli, _kill_after, _one_line, _predict_cmd, _PREDICT_OUTPUTS, _subprocess_env, _write_pair


# ---- outputs: unwritable folder, full disk -----------------------------------------------------

def test_output_folder_is_a_file_or_not_writable(pair, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = _cli(["predict", *pair, "--out", blocker, *FAST], capsys, "output folder is a file")
    assert code == 5 and "output folder" in _one_line(err)
    assert blocker.read_text() == "x"
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            code, _, err = _cli(["predict", *pair, "--out", ro, *FAST], capsys, "output folder not writable")
            assert code == 5 and "is not writable" in _one_line(err)
        finally:
            ro.chmod(0o700)


def _full_disk(monkeypatch, fail_from: int):
    """Make the fail_from-th and later writes of an output (temp file) write half its data,
    then raise OSError(ENOSPC), as a full disk does."""
    calls = {"n": 0}
    orig_bytes, orig_text = Path.write_bytes, Path.write_text

    def fail(path, data, orig):
        if ".tmp-" not in path.name:
            return orig(path, data)
        calls["n"] += 1
        if calls["n"] < fail_from:
            return orig(path, data)
        orig(path, data[: len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(Path, "write_bytes", lambda self, data: fail(self, data, orig_bytes))
    monkeypatch.setattr(Path, "write_text", lambda self, data, *a, **k: fail(self, data, orig_text))
    return calls


@pytest.mark.parametrize("fail_from, survivors", [
    (1, set()),                                           # the first output already fails
    # config.json fails: the PNGs and the PFM (written through a file object, not counted) are complete
    (3, {"disparity.png", "disparity.pfm", "disparity_color.png"}),
])
def test_full_disk_one_line_exit_5_no_partial_file(pair, tmp_path, capsys, monkeypatch, fail_from, survivors):
    out = tmp_path / "out"
    calls = _full_disk(monkeypatch, fail_from)
    code, _, err = _cli(["predict", *pair, "--out", out, *FAST], capsys, f"full disk (ENOSPC) at write {fail_from}")
    monkeypatch.undo()
    assert calls["n"] == fail_from                        # stopped at the first failure
    assert code == 5 and "No space left on device" in _one_line(err) and "cannot write" in err
    state = _check_complete(out)
    assert set(state["complete"]) == survivors and state["temps"] == []


def test_full_disk_during_training_keeps_the_last_checkpoint(tmp_path, capsys, monkeypatch):
    root = tmp_path / "k" / "training"
    _fake_kitti(root, n=1)
    out = tmp_path / "run"
    orig = Path.write_bytes
    saves = []

    def write_bytes(self, data):
        if self.suffix == ".msgpack":
            saves.append(len(data))
            if len(saves) == 2:                           # the second checkpoint (step 8) fails
                orig(self, data[:100])
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return orig(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    code, _, err = _cli(["train", "--data", root, "--frames", "0", "--preset", "tiny", "--steps", "12",
                         "--out", out], capsys, "full disk (ENOSPC) while saving a checkpoint")
    monkeypatch.undo()
    assert code == 5 and "No space left on device" in _one_line(err) and "checkpoint.msgpack" in err
    step, _ = _ckpt_step(out / "checkpoint.msgpack")
    assert step == 4                        # the last good checkpoint, intact
    assert not [p.name for p in out.iterdir() if ".tmp-" in p.name]



# ---- SIGKILL: predict leaves complete files or none --------------------------------------------

@pytest.mark.slow
def test_sigkill_predict_leaves_no_partial_output(tmp_path):
    rng = random.Random(os.environ.get("ROBUSTNESS_SEED", "1234"))
    lp, rp = _write_pair(tmp_path / "in", h=64, w=96)
    env = _subprocess_env(tmp_path)
    subprocess.run(_predict_cmd(lp, rp, tmp_path / "full"), check=True, env=env, capture_output=True, timeout=300)
    full = _check_complete(tmp_path / "full")
    assert set(full["complete"]) == _PREDICT_OUTPUTS and full["temps"] == []
    reference = (tmp_path / "full" / "disparity.png").read_bytes()
    t0 = time.perf_counter()                                 # a full run, compilation cached
    subprocess.run(_predict_cmd(lp, rp, tmp_path / "full2"), check=True, env=env, capture_output=True, timeout=300)
    t_full = time.perf_counter() - t0

    out = tmp_path / "out"
    kills = []
    # 5 kills at uniformly random moments of a run (a child that already finished does not count) ...
    for _ in range(10):
        alive, delay = _kill_after(_predict_cmd(lp, rp, out), env, delay=rng.uniform(0.5, t_full))
        kills.append({"when": f"{delay:.2f} s", "alive": alive, **_check_complete(out, _PREDICT_OUTPUTS)})
        if sum(k["alive"] for k in kills) == 5:
            break
    # ... and 3 in the write phase: 0-3 ms after the first temp file appears
    for i in range(3):
        folder = tmp_path / f"w{i}"
        folder.mkdir()
        alive, delay = _kill_after(_predict_cmd(lp, rp, folder), env, folder=folder, rng=rng)
        kills.append({"when": f"write phase + {delay * 1000:.1f} ms", "alive": alive,
                      **_check_complete(folder, _PREDICT_OUTPUTS)})
    log = os.environ.get("ROBUSTNESS_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps({"case": "SIGKILL predict", "t_full_s": t_full, "kills": kills}) + "\n")
    assert sum(k["alive"] for k in kills) >= 8, kills
    # leftover temp files are hidden, never carry a final name, and the next run completes
    subprocess.run(_predict_cmd(lp, rp, out), check=True, env=env, capture_output=True, timeout=300)
    final = _check_complete(out, _PREDICT_OUTPUTS)
    assert set(final["complete"]) == _PREDICT_OUTPUTS
    assert (out / "disparity.png").read_bytes() == reference
