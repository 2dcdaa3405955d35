"""Helpers of the robustness tests (system/test_robustness_*.py, inference/test_memory.py and others):
the CLI run in-process with its one error line, pair files, the completeness check of an output
folder, and SIGKILL of a child process. ``ROBUSTNESS_LOG=file.jsonl`` records every observed message."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from stereojax.app.cli import main
from stereojax.data import io

from .helpers import shifted_pair as _shifted_pair

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--max-disp", "16", "--method", "census"]


# ---- helpers -----------------------------------------------------------------------------------

def _record(case: str, code, text: str) -> None:
    log = os.environ.get("ROBUSTNESS_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps({"case": case, "code": code, "message": text.strip()}) + "\n")


def _cli(argv, capsys, case=None):
    """Run the CLI in-process; (exit code, stdout, stderr). Usage errors exit via SystemExit."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    cap = capsys.readouterr()
    if case:
        _record(case, code, cap.err)
    return code, cap.out, cap.err


def _one_line(err: str) -> str:
    """The error line: the only "error:" line, and the last line of stderr (evaluate and train
    draw progress bars on stderr before it; predict writes nothing else)."""
    assert "Traceback" not in err
    lines = [ln for ln in err.replace("\r", "\n").strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if ": error: " in ln]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    return errors[0]


def _write_pair(folder: Path, h=48, w=80, d=4, left_dtype=np.uint8, colour_left=False):
    left, right = _shifted_pair(d, h=h, w=w)
    if left_dtype == np.uint16:
        left, right = left.astype(np.uint16) * 257, right.astype(np.uint16) * 257
    if colour_left:
        left = np.repeat(left[..., None], 3, -1)
    folder.mkdir(parents=True, exist_ok=True)
    lp, rp = folder / "left.png", folder / "right.png"
    io.write_png(lp, left)
    io.write_png(rp, right)
    return lp, rp


_TMP_NAME = re.compile(r"^\.(?P<stem>.+)\.tmp-(?P<pid>\d+)-[0-9a-f]{8}(?P<ext>\.\w+)$")


def _check_complete(folder: Path, expected: set[str] | None = None) -> dict:
    """Every file under its final name is complete and readable; temp files (only ever left by a
    SIGKILL) are hidden, follow atomic_output's pattern and never carry a final name."""
    seen, temps = {}, []
    for p in sorted(folder.iterdir()) if folder.exists() else []:
        if p.is_dir():
            continue
        m = _TMP_NAME.match(p.name)
        if m:
            temps.append(p.name)
            continue
        assert not p.name.startswith("."), f"unexpected hidden file {p.name}"
        ext = p.suffix
        if ext == ".png":
            img = io.read_image(p)                   # checks IEND and decodes
            assert img.size > 0
        elif ext == ".json":
            json.loads(p.read_text())
        elif ext == ".npy":
            assert np.load(p).ndim == 2
        elif ext == ".pfm":
            assert io.read_pfm(p).ndim == 2                # checks the header and the body size
        elif ext == ".ply":
            data = p.read_bytes()
            head_end = data.index(b"end_header\n") + len(b"end_header\n")
            n = int(re.search(rb"element vertex (\d+)", data[:head_end]).group(1))
            assert len(data) - head_end == n * 15, "PLY body is not complete"
        else:
            raise AssertionError(f"unexpected output {p.name}")
        seen[p.name] = p.stat().st_size
    if expected is not None:
        assert set(seen) <= expected, set(seen) - expected
    return {"complete": seen, "temps": temps}


_PREDICT_OUTPUTS = {"disparity.png", "disparity.pfm", "disparity_color.png", "disparity_color.json", "confidence.png", "confidence.npy",
                    "depth.png", "depth.npy", "depth_color.png", "depth_color.json", "depth_reliable.png", "points.ply",
                    "config.json", "timings.json"}


def _predict_cmd(lp, rp, out):
    return [sys.executable, "-m", "stereojax.app.cli", "predict", str(lp), str(rp), "--out", str(out),
            "--max-disp", "16", "--method", "census", "--baseline", "0.54", "--focal", "721.5", "--ply"]


def _subprocess_env(tmp_path: Path) -> dict:
    """Environment of the CLI children: this checkout, and a persistent compilation cache (so a
    restarted child starts in ~3 s instead of ~11 s; the executables are the same)."""
    return {**os.environ, "PYTHONPATH": str(ROOT), "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax-cache"),
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0", "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"}


def _kill_after(cmd, env, delay=None, folder=None, rng=None):
    """Start cmd; SIGKILL it after ``delay`` s, or (folder) 0-3 ms after the first file appears
    in folder. Returns (whether it was still running when killed, the delay)."""
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if folder is not None:
        while proc.poll() is None and not any(folder.iterdir()):
            time.sleep(0.0005)
        delay = rng.uniform(0.0, 0.003)
    time.sleep(delay)
    alive = proc.poll() is None
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return alive, delay


def _ckpt_step(ckpt: Path):
    from stereojax.models import checkpoint
    from stereojax.learning.train import TrainConfig, init_state

    if not ckpt.exists():
        return 0, None
    stored = checkpoint.read_config(ckpt)                  # the CLI adds a "data" section
    cfg = TrainConfig.from_stored(stored)
    state, _ = checkpoint.load(ckpt, init_state(cfg))      # raises on a damaged file
    return int(state["step"]), state
