"""Long runs a user can trust: a batch prediction killed (SIGKILL) or stopped (SIGTERM) and run
again computes only what is missing, and ends with the outputs of an uninterrupted run; other settings
are computed again. Real subprocesses and signals, small images, the census chain."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from stereojax.data import io

from ..helpers import shifted_pair
from ..robustness_helpers import _cli, _subprocess_env

FAST = ["--max-disp", "16", "--method", "census"]


N_FRAMES = 12


def _pairs(folder: Path, n=N_FRAMES, h=96, w=160):
    for sub in ("left", "right"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    for i in range(n):
        left, right = shifted_pair(3 + i % 4, h=h, w=w, seed=i)
        io.write_png(folder / "left" / f"f{i:02d}.png", left)
        io.write_png(folder / "right" / f"f{i:02d}.png", right)
    return folder / "left", folder / "right"


def _cmd(left, right, out, *extra):
    return [sys.executable, "-m", "stereojax.app.cli", "predict", str(left), str(right), "--out", str(out), *FAST, *extra]


def _complete(out: Path) -> list[str]:
    return sorted(p.parent.name for p in out.glob("*/frame.json"))


def _start_and_wait(cmd, out, env, frames: int):
    """Start the batch and return (process, frames complete) once at least ``frames`` frames are
    complete (or the process has ended)."""
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and len(_complete(out)) < frames:
        time.sleep(0.01)
    return proc


def _outputs(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name in ("disparity.pfm", "disparity.png", "config.json")}


def _stop_after(data, name: str, frames: int, sig):
    """Start the batch into ``base/name``, send ``sig`` once ``frames`` frames are complete;
    (output folder, exit code, stderr)."""
    out = data["base"] / name
    proc = _start_and_wait(_cmd(data["left"], data["right"], out), out, data["env"], frames=frames)
    assert proc.poll() is None, "the batch ended before it could be stopped"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    return out, proc.returncode, err


def _again(data, out):
    """The same command, run again to the end."""
    return subprocess.run(_cmd(data["left"], data["right"], out), env=data["env"], capture_output=True,
                          text=True, timeout=600)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    base = tmp_path_factory.mktemp("resume")
    left, right = _pairs(base)
    env = _subprocess_env(base)
    full = base / "uninterrupted"
    proc = subprocess.run(_cmd(left, right, full), env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return {"base": base, "left": left, "right": right, "env": env, "full": full}


@pytest.mark.slow
def test_sigkill_then_the_same_command_computes_only_the_missing_frames(data):
    out, _, _ = _stop_after(data, "killed", 3, signal.SIGKILL)
    before = _complete(out)
    assert 3 <= len(before) < N_FRAMES
    # every frame folder is complete (nothing half-written under a frame's name)
    assert sorted(p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")) == before
    stamps = {f: (out / f / "frame.json").stat().st_mtime_ns for f in before}
    again = _again(data, out)
    assert again.returncode == 0, again.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["skipped"] == len(before) and summary["computed"] == N_FRAMES - len(before)
    assert sorted(summary["skipped_frames"]) == before
    assert {f: (out / f / "frame.json").stat().st_mtime_ns for f in before} == stamps      # not rewritten
    assert f"{len(before)} of {N_FRAMES} frames already complete" in again.stderr
    assert [p.name for p in out.glob(".*")] == []   # the killed frame's staging is gone, and the lock file
    assert _outputs(out) == _outputs(data["full"])                  # identical to an uninterrupted run


@pytest.mark.slow
def test_sigterm_finishes_or_drops_the_frame_writes_the_summary_and_exits_143(data):
    out, code, err = _stop_after(data, "terminated", 2, signal.SIGTERM)
    assert code == 143, err
    summary = json.loads((out / "summary.json").read_text())
    done = _complete(out)
    assert summary["interrupted"] == "SIGTERM" and summary["computed"] == len(done) < N_FRAMES
    assert summary["not_done"] == N_FRAMES - len(done)
    last = err.strip().splitlines()[-1]
    assert "interrupted by SIGTERM" in last and "run the same command to continue" in last
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == done       # no half-written frame
    again = _again(data, out)
    assert again.returncode == 0 and json.loads((out / "summary.json").read_text())["skipped"] == len(done)
    assert _outputs(out) == _outputs(data["full"])


def test_other_settings_are_computed_again_and_overwrite_recomputes_all(tmp_path, capsys):
    left, right = _pairs(tmp_path, n=3, h=48, w=80)
    out = tmp_path / "out"
    argv = ["predict", left, right, "--out", out, *FAST]
    assert _cli(argv, capsys)[0] == 0
    assert _cli(argv, capsys)[0] == 0
    assert json.loads((out / "summary.json").read_text())["skipped"] == 3
    # another search range: another config, every frame again
    assert _cli(["predict", left, right, "--out", out, "--max-disp", "24", "--method", "census"], capsys)[0] == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["skipped"] == 0 and s["computed"] == 3
    assert json.loads((out / "f00" / "config.json").read_text())["max_disp"] == 24
    # a changed input file: that frame again
    img = io.read_image(left / "f01.png")
    io.write_png(left / "f01.png", np.ascontiguousarray(img[:, ::-1]))
    assert _cli(["predict", left, right, "--out", out, "--max-disp", "24", "--method", "census"], capsys)[0] == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["skipped_frames"] == ["f00", "f02"] and [r["frame"] for r in s["per_frame"]] == ["f01"]
    # a frame folder with a missing file is incomplete
    (out / "f02" / "disparity.pfm").unlink()
    assert _cli(["predict", left, right, "--out", out, "--max-disp", "24", "--method", "census"], capsys)[0] == 0
    assert [r["frame"] for r in json.loads((out / "summary.json").read_text())["per_frame"]] == ["f02"]
    assert _cli(["predict", left, right, "--out", out, "--max-disp", "24", "--method", "census", "--overwrite"],
                capsys)[0] == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["skipped"] == 0 and s["computed"] == 3
