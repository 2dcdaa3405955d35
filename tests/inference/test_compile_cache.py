"""stereojax.inference.compile_cache: size buckets, the cache folder, a second process that reads the cache,
a damaged entry replaced, a read-only cache read, one entry for the same program, the Python API's cache."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereojax.data import io
from stereojax.inference.compile_cache import bucket_shape

from ..helpers import cache_env as _env, pair_folders as _folders

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--max-disp", "16", "--method", "census"]
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


def test_kitti_sizes_share_one_bucket():
    sizes = [(375, 1242), (374, 1238), (370, 1224), (376, 1241)]
    assert {bucket_shape(h, w) for h, w in sizes} == {(384, 1248)}
    assert bucket_shape(384, 1248) == (384, 1248)          # already a bucket: no padding
    assert bucket_shape(1, 1) == (16, 32)


@pytest.mark.slow
def test_second_process_reads_the_compilation_cache(tmp_path):
    """A second process compiling the same chain finds it in STEREOJAX_CACHE_DIR."""
    code = ("import numpy as np, stereojax, time; from stereojax.inference import compile_cache, programs;"
            "compile_cache.enable(); cfg = stereojax.preset('census', 16);"
            "t = time.perf_counter(); programs.compiled_chain((48, 64), cfg); print(time.perf_counter() - t)")
    env = {**os.environ, "STEREOJAX_CACHE_DIR": str(tmp_path / "cache")}

    def run():
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                             cwd=ROOT, check=True)
        return float(out.stdout.strip().splitlines()[-1])

    first = run()
    files = list((tmp_path / "cache").rglob("*"))
    assert any(f.is_file() for f in files), "nothing was written to the cache folder"
    second = run()
    assert second < first, (first, second)


def test_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    from stereojax.inference import compile_cache

    monkeypatch.setenv("STEREOJAX_CACHE_DIR", str(tmp_path / "c"))
    assert compile_cache.cache_dir() == tmp_path / "c"
    monkeypatch.setenv("STEREOJAX_CACHE_DIR", "off")
    assert compile_cache.cache_dir() is None and compile_cache.enable() is None
    monkeypatch.delenv("STEREOJAX_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert compile_cache.cache_dir() == tmp_path / "x" / "stereojax" / "jax"


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
