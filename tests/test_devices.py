"""Data-parallel training over several devices (issue "scale out"): 2 forced host devices on
the CPU, in a subprocess (XLA_FLAGS must be set before jax starts). Run with ``-k devices``."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_devices_two_equals_one_and_resume_is_exact(tmp_path):
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
           "STEREOJAX_CACHE_DIR": "off"}
    proc = subprocess.run([sys.executable, "-m", "tests.devices_worker", str(tmp_path)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    assert r["devices"] == 2 and r["summary_devices"] == [1, 2]
    # the same global batch and the same batch-norm statistics: the same parameters up to
    # float rounding of the sharded reductions
    assert r["max_diff_n1_n2"] <= 1e-4 * max(1.0, r["max_param"]), r
    assert abs(r["val_n1_n2"][0] - r["val_n1_n2"][1]) < 1e-4
    assert r["resume_exact"], "resume on 2 devices is not bit-identical"
    assert "batch 15 does not divide evenly over 2 devices" in r["odd_batch"]


@pytest.mark.slow
def test_devices_two_processes_train_together_and_only_process_0_writes(tmp_path):
    import socket

    with socket.socket() as sock:                    # a free port for the coordinator
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    procs = []
    for pid in (0, 1):
        env = {**os.environ, "JAX_COORDINATOR_ADDRESS": f"127.0.0.1:{port}", "JAX_NUM_PROCESSES": "2",
               "JAX_PROCESS_ID": str(pid), "STEREOJAX_CACHE_DIR": "off"}
        env.pop("XLA_FLAGS", None)
        procs.append(subprocess.Popen([sys.executable, "-m", "tests.devices_worker", "multihost",
                                       str(tmp_path / f"p{pid}")], cwd=ROOT, env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err[-2000:]
    res = [json.loads(out.strip().splitlines()[-1]) for out, _ in outs]
    assert [r["process"] for r in res] == [0, 1] and all(r["devices"] == 2 for r in res)
    assert res[0]["val"] == res[1]["val"]                 # one model, trained together
    assert (tmp_path / "p0" / "checkpoint.msgpack").exists()
    assert not (tmp_path / "p1").exists() or not any((tmp_path / "p1").rglob("*.*"))
