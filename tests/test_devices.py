"""Data-parallel training over several devices (issue "scale out"): 2 forced host devices on
the CPU, in a subprocess (XLA_FLAGS must be set before jax starts). Run with ``-k devices``."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _flags(devices: int | None) -> str:
    """The suite's XLA flags (tests/conftest.py) without any device count, plus ``devices``."""
    kept = [f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f]
    return " ".join(kept + ([f"--xla_force_host_platform_device_count={devices}"] if devices else []))


@pytest.mark.slow
def test_devices_two_equals_one_and_resume_is_exact(tmp_path):
    env = {**os.environ, "XLA_FLAGS": _flags(2)}
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
               "JAX_PROCESS_ID": str(pid)}
        env["XLA_FLAGS"] = _flags(None)
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


def _forced(n: int) -> dict:
    return {**os.environ, "XLA_FLAGS": _flags(n), "PYTHONPATH": str(ROOT)}


def _cli(args, env, timeout=600):
    return subprocess.run([sys.executable, "-m", "stereojax.app.cli", *map(str, args)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


def _textured_pairs(folder: Path, sizes, shift: int = 5, seed: int = 0) -> None:
    """Left/right PNG folders of random texture shifted by ``shift`` pixels, one pair per size."""
    import cv2

    rng = np.random.default_rng(seed)
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for i, (h, w) in enumerate(sizes):
        tex = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + shift)).astype(np.float32), (3, 3), 0)
        cv2.imwrite(str(folder / "left" / f"p{i}.png"), tex[:, shift:].astype(np.uint8))
        cv2.imwrite(str(folder / "right" / f"p{i}.png"), tex[:, :w].astype(np.uint8))


@pytest.mark.slow
def test_devices_batch_predict_over_two_devices_equals_one(tmp_path):
    from stereojax.data.io import read_pfm

    sizes = [(64, 96), (64, 90), (70, 100), (60, 96), (64, 96)]      # two size buckets, mixed
    _textured_pairs(tmp_path, sizes)
    outs = {}
    for n in (1, 2):
        out = tmp_path / f"d{n}"
        proc = _cli(["predict", tmp_path / "left", tmp_path / "right", "--method", "census",
                     "--max-disp", 16, "--devices", n, "--out", out], _forced(2))
        assert proc.returncode == 0, proc.stderr[-2000:]
        outs[n] = out
    s1, s2 = (json.loads((outs[n] / "summary.json").read_text()) for n in (1, 2))
    assert (s1["devices"], s2["devices"]) == (1, 2) and s1["ok"] == s2["ok"] == len(sizes)
    assert {r["device"] for r in s1["per_frame"]} == {"cpu:0"}
    assert {r["device"] for r in s2["per_frame"]} == {"cpu:0", "cpu:1"}  # both did work
    for i in range(len(sizes)):
        a = read_pfm(outs[1] / f"p{i}" / "disparity.pfm")
        b = read_pfm(outs[2] / f"p{i}" / "disparity.pfm")
        assert a.shape == sizes[i] and np.array_equal(a, b), f"pair p{i} differs between 1 and 2 devices"
    bad = _cli(["predict", tmp_path / "left", tmp_path / "right", "--method", "census", "--devices", 3,
                "--out", tmp_path / "d3"], _forced(2))
    assert bad.returncode != 0 and bad.stderr.strip().splitlines()[-1].endswith(
        "--devices 3 asks for more devices than the 2 cpu device(s) there are")


@pytest.mark.slow
def test_devices_sharded_evaluation_gives_identical_numbers(tmp_path, data_root):
    results = {}
    for n in (1, 2):
        out = tmp_path / f"d{n}"
        proc = _cli(["evaluate", "--data", data_root / "kitti2015" / "training", "--dataset", "kitti2015",
                     "--frames", "000021-000022", "--method", "census", "--devices", n, "--out", out],
                    _forced(2), timeout=900)
        assert proc.returncode == 0, proc.stderr[-2000:]
        results[n] = json.loads((out / "results.json").read_text())
    one, two = results[1], results[2]
    assert [f["frame"] for f in one["frames"]] == [f["frame"] for f in two["frames"]] == \
        ["000021", "000022"]
    assert {f["pipeline"]["device"] for f in two["frames"]} == {"cpu:0", "cpu:1"}
    keys = ("bad2", "bad3", "bad4", "bad5", "d1", "epe", "density")
    for a, b in zip(one["frames"], two["frames"]):
        assert {k: a["pipeline"][k] for k in keys} == {k: b["pipeline"][k] for k in keys}, a["frame"]
    assert {k: one["mean"]["pipeline"][k] for k in keys} == {k: two["mean"]["pipeline"][k] for k in keys}
