"""Outputs that can be trusted after anything: the rectification check never ends a run, resume
checks each file's size (and digest with --verify), unmatched names are reported, one writer per
output folder, a compile cache that heals and is read when read-only, one cache entry for the
same program. (The progress bar over the bands of a large pair: tests/test_tiling.py.)"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereojax.data import io
from stereojax.data.rectification import check_rectified
from tests.helpers import fake_kitti, shifted_pair, run_cli

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--max-disp", "16", "--method", "census"]


_run = run_cli


def _folders(root: Path, names, right_names=None, h=48, w=80):
    for i, n in enumerate(names):
        left, right = shifted_pair(4, h=h, w=w, seed=i)
        io.write_png(root / "L" / f"{n}.png", left)
        if right_names is None or n in right_names:
            io.write_png(root / "R" / f"{n}.png", right)
    return root / "L", root / "R"


# ---- 1. the rectification check never crashes ----------------------------------------------------

@pytest.mark.parametrize("shape", [(1, 150), (10, 10), (40, 150), (63, 300)])
def test_rectification_check_skips_tiny_images(shape):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, shape).astype(np.uint8)
    check = check_rectified(img, img)
    assert check.problem is None and "too small" in check.skipped


def test_rectification_check_skips_flat_images():
    flat = np.full((120, 200), 7, np.uint8)
    assert "flat" in check_rectified(flat, flat).skipped
    left, right = shifted_pair(4, h=120, w=200)
    assert check_rectified(left, right).skipped is None


def test_one_row_pair_is_one_line_not_a_traceback(tmp_path, capsys):
    rng = np.random.default_rng(1)
    io.write_png(tmp_path / "l.png", rng.integers(0, 256, (1, 150)).astype(np.uint8))
    io.write_png(tmp_path / "r.png", rng.integers(0, 256, (1, 150)).astype(np.uint8))
    code, out, err = _run(["predict", tmp_path / "l.png", tmp_path / "r.png", "--out", tmp_path / "o", *FAST],
                          capsys)
    assert code == 2 and "Traceback" not in err
    assert err.strip().splitlines() == [err.strip()]                      # one line: the refusal
    assert err.startswith("stereojax predict: error: image is 150x1")


# ---- 2. resume checks what it keeps ------------------------------------------------------------------

def test_resume_recomputes_a_frame_whose_file_was_cut(tmp_path, capsys):
    left_dir, right_dir = _folders(tmp_path, ["a", "b"])
    out = tmp_path / "o"
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)
    assert code == 0, err
    record = json.loads((out / "a" / "frame.json").read_text())
    assert set(record["files"]) == set(record["outputs"])
    assert record["files"]["disparity.png"]["size"] == (out / "a" / "disparity.png").stat().st_size
    good = (out / "a" / "disparity.png").read_bytes()
    (out / "a" / "disparity.png").write_bytes(good[:len(good) // 2])        # cut to half, frame.json untouched
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)
    assert code == 0, err
    assert "a: recorded as complete but disparity.png is" in err and "computing it again" in err
    assert "1 of 2 frames already complete" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["computed"] == 1 and summary["skipped_frames"] == ["b"]
    assert summary["damaged"][0]["frame"] == "a"
    assert (out / "a" / "disparity.png").read_bytes() == good


def test_verify_reads_the_digests(tmp_path, capsys):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    out = tmp_path / "o"
    assert _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)[0] == 0
    path = out / "a" / "confidence.npy"
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF                                                          # same size, other bytes
    path.write_bytes(bytes(data))
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, *FAST], capsys)
    assert code == 0 and "1 of 1 frames already complete" in err            # sizes only: kept
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, "--verify", *FAST], capsys)
    assert code == 0 and "confidence.npy does not match its recorded SHA-256" in err
    assert json.loads((out / "summary.json").read_text())["computed"] == 1
    code, _, err = _run(["predict", left_dir, right_dir, "--out", out, "--verify", *FAST], capsys)
    assert code == 0 and "1 of 1 frames already complete" in err and "SHA-256 checked" in err


def test_evaluate_records_are_checked_on_resume(tmp_path, capsys):
    root = tmp_path / "training"
    fake_kitti(root, n=2)
    out = tmp_path / "ev"
    argv = ["evaluate", "--data", root, "--dataset", "kitti2015", "--max-disp", "16", "--method", "census",
            "--out", out]
    assert _run(argv, capsys)[0] == 0
    record = json.loads((out / "frames" / "000000.json").read_text())
    assert "000000_error.png" in record["files"] and "000000_disparity.png" in record["files"]
    err_png = out / "000000_error.png"
    err_png.write_bytes(err_png.read_bytes()[:100])
    code, _, err = _run(argv, capsys)
    assert code == 0 and "000000: recorded as scored but 000000_error.png is 100 bytes" in err
    assert json.loads((out / "results.json").read_text())["reused"] == ["000001"]
    assert err_png.stat().st_size == record["files"]["000000_error.png"]["size"]


# ---- 3. names without a partner -------------------------------------------------------------------------

def test_unmatched_names_are_reported(tmp_path, capsys):
    left_dir, right_dir = _folders(tmp_path, ["a", "b", "c", "d", "e"], right_names={"a", "b", "c", "d"})
    io.write_png(right_dir / "z.png", shifted_pair(4, h=48, w=80)[1])
    code, out, err = _run(["predict", left_dir, right_dir, "--out", tmp_path / "o", *FAST], capsys)
    assert code == 0, err
    assert ("2 image(s) without a partner of the same name (1 left, 1 right), not computed: left/e.png, "
            "right/z.png") in err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["unmatched"] == ["left/e.png", "right/z.png"] and summary["ok"] == 4
    assert "2 image(s) without a partner" in out


# ---- 4. one writer per output folder -----------------------------------------------------------------

def _env(cache: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT), "STEREOJAX_CACHE_DIR": str(cache)}


def test_a_second_batch_on_a_held_folder_is_refused(tmp_path):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    out = tmp_path / "o"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from pathlib import Path;"
                               "from stereojax.app.outputs import folder_lock\n"
                               f"with folder_lock(Path({str(out)!r})):\n    print('held', flush=True); time.sleep(60)"],
                              env=_env(tmp_path / "c"), stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        r = subprocess.run([sys.executable, "-m", "stereojax.app.cli", "predict", str(left_dir), str(right_dir),
                            "--out", str(out), *FAST], env=_env(tmp_path / "c"), capture_output=True, text=True,
                           timeout=300)
    finally:
        holder.kill()
        holder.wait()
    assert r.returncode == 8, r.stderr
    assert r.stderr.strip().splitlines()[-1] == (f"stereojax predict: error: output folder {out} is in use by PID "
                                                 f"{holder.pid} (another stereojax predict); wait for it to finish "
                                                 "or choose another --out")
    assert not (out / "a").exists()
    assert r.stdout == "", r.stdout               # refused before it says what it would run


def test_the_lock_is_reentrant_and_its_file_goes_when_the_run_ends(tmp_path):
    from stereojax.app.outputs import LOCK_NAME, folder_lock
    from stereojax.errors import OutputBusyError

    with folder_lock(tmp_path) as path:
        with folder_lock(tmp_path):                   # the CLI's block, then the batch's
            assert path.read_text().strip() == str(os.getpid())
        assert path.exists()                          # the outer block still holds it
        other = subprocess.run([sys.executable, "-c", "from pathlib import Path; from stereojax.app.outputs import "
                                f"folder_lock\nwith folder_lock(Path({str(tmp_path)!r})): pass"],
                               capture_output=True, text=True)
        assert other.returncode != 0 and OutputBusyError.__name__ in other.stderr
    assert not (tmp_path / LOCK_NAME).exists()
    with pytest.raises(RuntimeError):                 # a failed block removes it too
        with folder_lock(tmp_path):
            raise RuntimeError
    assert list(tmp_path.iterdir()) == []
    (tmp_path / LOCK_NAME).write_text("12345\n")    # a killed run's file: taken over
    with folder_lock(tmp_path) as path:
        assert path.read_text().strip() == str(os.getpid())
    assert list(tmp_path.iterdir()) == []


def test_a_failed_single_pair_leaves_no_empty_output_folder(tmp_path, capsys):
    from stereojax.app.cli import main

    left, right = _folders(tmp_path, ["a"])
    out = tmp_path / "new" / "o"
    code = main(["predict", str(left / "a.png"), str(tmp_path / "missing.png"), "--out", str(out), *FAST])
    assert code == 2 and "missing.png" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "new").exists()
    kept = tmp_path / "kept"
    kept.mkdir()                                      # a folder the user made stays
    assert main(["predict", str(left / "a.png"), str(tmp_path / "missing.png"), "--out", str(kept), *FAST]) == 2
    assert kept.is_dir()


def test_stale_staging_of_a_live_process_is_kept(tmp_path):
    from stereojax.app.batch import remove_stale

    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    try:
        (tmp_path / f".a.partial-{live.pid}").mkdir()
        (tmp_path / f".b.partial-{dead.pid}").mkdir()
        (tmp_path / f".c.old-{dead.pid}").mkdir()
        remove_stale(tmp_path)
        assert sorted(p.name for p in tmp_path.iterdir()) == [f".a.partial-{live.pid}"]
    finally:
        live.kill()
        live.wait()


@pytest.mark.slow
def test_two_identical_batches_started_together(tmp_path):
    """Two processes on one --out: one computes, the other refuses (exit 8) or, if it starts
    after the first finished, finds every frame complete; no frame fails or is lost."""
    left_dir, right_dir = _folders(tmp_path, ["a", "b", "c"])
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "stereojax.app.cli", "predict", str(left_dir), str(right_dir), "--out", str(out), *FAST]
    procs = [subprocess.Popen(cmd, env=_env(tmp_path / "c"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    results = [(p.wait(timeout=600), p.stderr.read()) for p in procs]
    codes = sorted(c for c, _ in results)
    assert codes in ([0, 0], [0, 8]), results
    if codes == [0, 8]:
        assert any("is in use by PID" in e for c, e in results if c == 8)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == [] and summary["ok"] == 3
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".") and p.name != ".stereojax.lock") == []
    for n in "abc":
        assert (out / n / "frame.json").is_file()


# ---- 5-7. the compile cache --------------------------------------------------------------------------

_PROBE = """
import json, sys, jax
hits = []
jax.monitoring.register_event_listener(lambda name, **kw: hits.append(name))
from stereojax.inference import compile_cache
if sys.argv[1] == "readonly":
    compile_cache._writable = lambda folder: False
from stereojax.app.cli import main
code = main(sys.argv[2:])
print(json.dumps({"code": code, "hits": hits.count("/jax/compilation_cache/cache_hits"),
                  "misses": hits.count("/jax/compilation_cache/cache_misses")}))
"""


def _probe(tmp_path, cache, argv, mode="rw"):
    r = subprocess.run([sys.executable, "-c", _PROBE, mode, *map(str, argv)], env=_env(cache),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr


def _entries(cache: Path):
    return sorted(p.name for p in cache.glob("*-cache"))


@pytest.mark.slow
def test_a_damaged_cache_entry_is_replaced(tmp_path):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    cache = tmp_path / "cache"
    single = ["predict", left_dir / "a.png", right_dir / "a.png", *FAST, "--check-rectified", "off"]
    first, _ = _probe(tmp_path, cache, [*single, "--out", tmp_path / "o1"])
    entries = _entries(cache)
    assert first["misses"] >= 1 and entries
    rng = np.random.default_rng(0)
    for i, name in enumerate(entries):        # random bytes; the last one cut short, as by a killed write
        path = cache / name
        path.write_bytes(rng.bytes(5000) if i % 2 == 0 else path.read_bytes()[:path.stat().st_size // 3])
    second, err2 = _probe(tmp_path, cache, [*single, "--out", tmp_path / "o2"])
    assert "damaged compile-cache entry" in err2 and second["hits"] == 0
    third, err3 = _probe(tmp_path, cache, [*single, "--out", tmp_path / "o3"])
    assert "damaged" not in err3 and "Error reading" not in err3 and "warning" not in err3
    assert third["hits"] >= 1 and third["misses"] == 0
    assert _entries(cache) == entries
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "o3" / "disparity.pfm"),
                                  io.read_pfm(tmp_path / "o1" / "disparity.pfm"))


@pytest.mark.slow
def test_a_read_only_cache_is_read_not_switched_off(tmp_path):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    cache = tmp_path / "cache"
    single = ["predict", left_dir / "a.png", right_dir / "a.png", *FAST, "--check-rectified", "off"]
    _probe(tmp_path, cache, [*single, "--out", tmp_path / "o1"])
    before = {p.name: p.stat().st_mtime_ns for p in cache.iterdir()}
    got, err = _probe(tmp_path, cache, [*single, "--out", tmp_path / "o2"], mode="readonly")
    assert got["hits"] >= 1 and got["misses"] == 0
    assert err.count("is read-only: reading it, writing nothing new") == 1
    other, _ = _probe(tmp_path, cache, ["predict", left_dir / "a.png", right_dir / "a.png", "--max-disp", "24",
                                        "--method", "census", "--check-rectified", "off", "--out", tmp_path / "o3"],
                      mode="readonly")
    assert other["misses"] >= 1                                              # compiled, and not written:
    assert {p.name: p.stat().st_mtime_ns for p in cache.iterdir()} == before


@pytest.mark.slow
def test_single_pair_reuses_the_program_a_batch_compiled(tmp_path):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    cache = tmp_path / "cache"
    batch, _ = _probe(tmp_path, cache, ["predict", left_dir, right_dir, "--out", tmp_path / "b", *FAST,
                                        "--check-rectified", "off"])
    entries = _entries(cache)
    single, _ = _probe(tmp_path, cache, ["predict", left_dir / "a.png", right_dir / "a.png", "--out",
                                         tmp_path / "s", *FAST, "--check-rectified", "off"])
    assert single["misses"] == 0 and single["hits"] >= 1
    assert _entries(cache) == entries


def test_python_api_uses_the_persistent_cache(tmp_path):
    code = ("import numpy as np, stereojax, jax; from stereojax.inference import compile_cache;"
            "p = stereojax.Predictor(stereojax.preset('census', 16));"
            "print(compile_cache._enabled.get('dir'), jax.config.jax_compilation_cache_dir)")
    r = subprocess.run([sys.executable, "-c", code], env=_env(tmp_path / "pc"), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == [str(tmp_path / "pc")] * 2
    off = subprocess.run([sys.executable, "-c", code], env={**_env(tmp_path / "pc"), "STEREOJAX_CACHE_DIR": "off"},
                         capture_output=True, text=True, timeout=300)
    assert off.stdout.split() == ["None", "None"]
