"""Batch prediction on a real local Ray cluster (``ray start --head`` on the loopback address,
started by the tests): the outputs equal a local batch's bit for bit, a worker killed mid-run is
retried, a killed driver resumes, an address where nothing listens is one line, and nothing
imports ray without --ray."""

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stereojax.data import io
from tests.helpers import shifted_pair

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--max-disp", "16", "--method", "census", "--check-rectified", "off"]
RAY_BIN = Path(sys.executable).parent / "ray"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A one-node Ray cluster on this machine with 2 CPUs (``ray start --head``); its address.
    (On the loopback address alone, ``--node-ip-address 127.0.0.1``, this Ray version rewrites
    the address to the machine's and then cannot connect: the head binds the machine's own
    interface here, which nothing outside reaches either.) ``ray start --block`` runs in its own
    process group, and the cluster is stopped by ending that group: ``ray stop`` would stop every
    Ray cluster of the machine, the one of the other ``pytest -n`` worker included."""
    import re

    port = _free_port()
    # a test cluster of this machine only: no token authentication (a real cluster's drivers need
    # its token, RAY_AUTH_TOKEN or ~/.ray/auth_token: docs/usage.md)
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}
    log = tmp_path_factory.mktemp("ray") / "head.log"
    with open(log, "w") as out:
        head = subprocess.Popen([str(RAY_BIN), "start", "--head", "--block", "--port", str(port), "--num-cpus", "2",
                                 "--include-dashboard", "false", "--disable-usage-stats"],
                                env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while not (found := re.search(r"ray start --address='([^']+)'", log.read_text())):
            assert head.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.5)
        yield found.group(1)
    finally:                                     # the group may be gone already (a failed start)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGTERM)
        try:
            head.wait(timeout=120)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(head.pid, signal.SIGKILL)
            head.wait()


def _inputs(root: Path, n: int, h=96, w=192):
    for i in range(n):
        left, right = shifted_pair(4 + i % 5, h=h, w=w, seed=i)
        io.write_png(root / "L" / f"f{i:02d}.png", left)
        io.write_png(root / "R" / f"f{i:02d}.png", right)
    return root / "L", root / "R"


def _cmd(left, right, out, *extra):
    return [sys.executable, "-m", "stereojax.app.cli", "predict", str(left), str(right), "--out", str(out), *FAST, *extra]


def _env(tmp_path):
    return {**os.environ, "PYTHONPATH": str(ROOT), "STEREOJAX_CACHE_DIR": str(tmp_path / "cache"),
            "RAY_USAGE_STATS_ENABLED": "0"}


def _same_outputs(a: Path, b: Path):
    frames = sorted(p.name for p in a.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert frames == sorted(p.name for p in b.iterdir() if p.is_dir() and not p.name.startswith("."))
    for f in frames:
        for name in ("disparity.png", "disparity.pfm", "disparity_color.png", "confidence.png", "confidence.npy",
                     "config.json"):
            assert (a / f / name).read_bytes() == (b / f / name).read_bytes(), (f, name)
        ra, rb = (json.loads((x / f / "frame.json").read_text()) for x in (a, b))
        for r in (ra, rb):
            r.pop("timings"), r["files"].pop("timings.json")
        assert ra == rb, f
    return frames


def test_outputs_equal_a_local_batch(cluster, tmp_path):
    left, right = _inputs(tmp_path, 5)
    env = _env(tmp_path)
    local = subprocess.run(_cmd(left, right, tmp_path / "local"), env=env, capture_output=True, text=True, timeout=600)
    assert local.returncode == 0, local.stderr
    remote = subprocess.run(_cmd(left, right, tmp_path / "ray", "--ray", cluster), env=env, capture_output=True,
                            text=True, timeout=600)
    assert remote.returncode == 0, remote.stderr
    assert len(_same_outputs(tmp_path / "local", tmp_path / "ray")) == 5
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert summary["ok"] == 5 and summary["workers"] == 1 and summary["ray"].startswith(f"Ray cluster {cluster}")
    assert "5 of 5 pairs" in remote.stdout and "frame/s" in remote.stderr           # progress bar on the driver
    again = subprocess.run(_cmd(left, right, tmp_path / "ray", "--ray", cluster), env=env, capture_output=True,
                           text=True, timeout=600)
    assert again.returncode == 0 and "5 of 5 frames already complete" in again.stderr   # resume, as locally


def _wait_for_frames(out: Path, n: int, proc, timeout=300):
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        if out.is_dir() and len([p for p in out.iterdir() if (p / "frame.json").is_file()]) >= n:
            return True
        time.sleep(0.05)
    return False


def test_a_killed_worker_is_retried_and_the_run_completes(cluster, tmp_path):
    left, right = _inputs(tmp_path, 8, h=256, w=512)
    env = _env(tmp_path)
    out = tmp_path / "ray"
    proc = subprocess.Popen(_cmd(left, right, out, "--ray", cluster, "--ray-workers", "1"), env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert _wait_for_frames(out, 1, proc)
    pids = subprocess.run(["pgrep", "-f", "ray::FrameWorker"], capture_output=True, text=True).stdout.split()
    assert pids, "no Ray worker process found"
    for pid in pids:
        os.kill(int(pid), signal.SIGKILL)                         # mid-run: frames remain to do
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ok"] == 8 and summary["failed"] == []
    assert [p.name for p in out.iterdir() if p.name.startswith(".") and p.name != ".stereojax.lock"] == []
    local = subprocess.run(_cmd(left, right, tmp_path / "local"), env=env, capture_output=True, text=True, timeout=600)
    assert local.returncode == 0
    assert len(_same_outputs(tmp_path / "local", out)) == 8


def test_a_killed_driver_resumes(cluster, tmp_path):
    left, right = _inputs(tmp_path, 8, h=256, w=512)
    env = _env(tmp_path)
    out = tmp_path / "ray"
    cmd = _cmd(left, right, out, "--ray", cluster, "--ray-workers", "1")
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    assert _wait_for_frames(out, 2, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = sorted(p.name for p in out.iterdir() if (p / "frame.json").is_file())
    assert 2 <= len(done) < 8
    again = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ok"] == 8 and set(summary["skipped_frames"]) >= set(done)
    local = subprocess.run(_cmd(left, right, tmp_path / "local"), env=env, capture_output=True, text=True, timeout=600)
    assert local.returncode == 0
    assert len(_same_outputs(tmp_path / "local", out)) == 8


def test_a_bad_pair_is_one_line_and_the_rest_completes(cluster, tmp_path):
    left, right = _inputs(tmp_path, 3)
    (right / "f01.png").write_bytes(b"not a png")
    r = subprocess.run(_cmd(left, right, tmp_path / "ray", "--ray", cluster), env=_env(tmp_path),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and errors[0].startswith("stereojax predict: error: f01: cannot read image"), errors
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert summary["ok"] == 2 and [f["frame"] for f in summary["failed"]] == ["f01"]
    assert not (tmp_path / "ray" / "f01").exists() and (tmp_path / "ray" / "f02" / "frame.json").is_file()


def test_worker_resources_always_fit_the_cluster():
    from stereojax.app.ray_batch import worker_resources

    assert worker_resources(1, 0, 2) == {"num_cpus": 2.0}
    assert worker_resources(2, 0, 2) == {"num_cpus": 1.0}             # 2 x 2 CPUs would never be placed
    assert worker_resources(3, 0, 16) == {"num_cpus": 2.0}
    assert worker_resources(4, 2, 16) == {"num_gpus": 0.5}
    assert worker_resources(2, 8, 16) == {"num_gpus": 1.0}


def test_two_workers_on_two_cpus_share_the_frames(cluster, tmp_path):
    left, right = _inputs(tmp_path, 4)
    env = _env(tmp_path)
    r = subprocess.run(_cmd(left, right, tmp_path / "ray", "--ray", cluster, "--ray-workers", "2"), env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert summary["ok"] == 4 and summary["workers"] == 2 and "2 worker(s), 1 CPUs each" in summary["ray"]


def test_an_address_where_nothing_listens_is_one_line(tmp_path):
    left, right = _inputs(tmp_path, 2)
    t0 = time.time()
    r = subprocess.run(_cmd(left, right, tmp_path / "o", "--ray", f"127.0.0.1:{_free_port()}"), env=_env(tmp_path),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 9 and time.time() - t0 < 60
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereojax predict: error: cannot reach the Ray cluster at 127.0.0.1:")
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_ray_is_not_imported_without_the_option(tmp_path):
    left, right = _inputs(tmp_path, 2)
    code = ("import sys; from stereojax.app.cli import main; "
            f"rc = main({[str(a) for a in _cmd(left, right, tmp_path / 'o')[3:]]!r}); "
            "print(rc, 'ray' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], env=_env(tmp_path), capture_output=True, text=True, timeout=300)
    assert r.stdout.split()[-2:] == ["0", "False"], r.stderr
