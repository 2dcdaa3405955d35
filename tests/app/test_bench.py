"""stereojax.app.bench, the measurements of `make bench`: the machine's description, and the demo
timing runs what `make demo` runs."""

import numpy as np

from stereojax.app import bench


def test_cpu_description_names_the_model_and_vector_units():
    text = bench.cpu_description()
    assert text and "(" in text and text.endswith(")")


def test_demo_child_times_what_make_demo_runs(monkeypatch):
    """The demo timing is of `--method best` on the built-in pair, with the confidence map, as
    `make demo` runs it (the chain itself is replaced: make demo's own test runs it)."""
    from stereojax.models import registry as models

    seen = {}

    def fake_warm_chain(left, right, cfg, model=None, repeats=3, confidence=False):
        seen.update(shape=left.shape[:2], cfg=cfg, model=model, confidence=confidence)
        return {"warm_s": 1.5, "compile_s": 2.0}

    monkeypatch.setattr(bench, "warm_chain", fake_warm_chain)
    out = bench.demo_child(repeats=1)
    want = models.resolve("best", width=741, height=500, dataset="middlebury", max_disp=64)
    assert seen["shape"] == (500, 741) and seen["confidence"] is True
    assert seen["cfg"] == want.config and seen["model"].net == want.model().net
    assert out["model"] == want.description and "middlebury" in out["model"]
    assert out["warm_s"] == 1.5 and out["shape"] == [500, 741] and out["max_disp"] == 64


def test_chain_child_runs_the_kernels_it_is_given_and_records_them(monkeypatch):
    """Issue 51: the whole chain is timed with the kernels named (the native and the JAX kernels
    side by side in one bench), and the child's result says which ran."""
    from stereojax import kernels

    seen = []

    def fake_warm_chain(left, right, cfg, model=None, repeats=3):
        seen.append(cfg.kernels)
        return {"warm_s": 1.0, "compile_s": 2.0}

    monkeypatch.setattr(bench, "warm_chain", fake_warm_chain)
    xla = bench.chain_child(64, "census", repeats=1, kernels_setting="xla")
    default = bench.chain_child(64, "census", repeats=1)
    assert seen == ["xla", "auto"]
    assert xla["kernels"] == {"kernels": "xla", "setting": "xla", "reason": None}
    assert default["kernels"] == kernels.record("auto")


def test_chain_memory_passes_the_kernels_to_the_child(monkeypatch):
    codes = []

    def fake_child(code, env=None):
        codes.append(code)
        return {"warm_s": 1.0}, 0.0, ""

    monkeypatch.setattr(bench, "_child", fake_child)
    assert bench.chain_memory(64, "census", kernels_setting="xla") == {"warm_s": 1.0}
    assert "chain_child(64, 'census', data=None, kernels_setting='xla')" in codes[0]
    bench.chain_memory(64, "census")
    assert "kernels_setting=None" in codes[1]


def test_run_bench_times_census_and_compact_with_both_kernel_sets(monkeypatch, tmp_path):
    """Issue 51: with the native kernels loaded, one bench run times the census and compact chains
    (stage profile and whole chain) with the JAX kernels beside the default ones, `best` with the
    default only, and records the kernels (every measurement replaced: this checks the plumbing)."""
    from stereojax import kernels

    monkeypatch.setattr(kernels, "native", lambda setting="auto": setting != "xla")
    calls = {"stages": [], "chains": [], "profiles": []}
    row = {"warm_s": 0.1, "compile_s": 0.2, "entries": 0}

    def fake_stage_timings(left, right, cfg, model=None, repeats=3):
        calls["stages"].append(cfg.kernels)
        return {"SGM": dict(row)}

    def fake_learned_profile(left, right, max_disp, repeats=2, exact_disps=8, which="best", xla=False):
        calls["profiles"].append((which, xla))
        out = {"stages": {"SGM": dict(row)}, "exact": {}}
        if xla:
            out["stages_xla"] = {"SGM": dict(row)}
        return out

    def fake_chain_memory(max_disp, method, data=None, kernels_setting=None):
        calls["chains"].append((method, kernels_setting))
        return {"warm_s": 1.0, "compile_s": 2.0}

    monkeypatch.setattr(bench, "_bench_pair", lambda data=None: (np.zeros((8, 8, 3), np.uint8),) * 2 + ("x",))
    monkeypatch.setattr(bench, "stage_timings", fake_stage_timings)
    monkeypatch.setattr(bench, "learned_profile", fake_learned_profile)
    monkeypatch.setattr(bench, "chain_memory", fake_chain_memory)
    monkeypatch.setattr(bench, "cascade_profile", lambda *a, **k: {"stages": {}})
    monkeypatch.setattr(bench, "demo_memory", lambda repeats=3: {})
    monkeypatch.setattr(bench, "process_timings", lambda *a, **k: {})
    monkeypatch.setattr(bench, "sgbm_timings", lambda *a, **k: {"padded": 0.1, "unpadded": 0.1})
    monkeypatch.setattr(bench, "matmul_rate", lambda: 1.0)
    monkeypatch.setattr(bench, "learned_setup", lambda name, max_disp: (None, None, "kitti2015"))
    monkeypatch.setattr(bench, "_kitti_files", lambda *a, **k: (tmp_path / "l.png", tmp_path / "r.png"))
    r = bench.run_bench(tmp_path, repeats=1, max_disp=64)
    assert calls["stages"] == ["auto", "xla"]
    assert calls["profiles"] == [("kitti2015", False), ("kitti2015_compact", True)]
    assert sorted(c for c in calls["chains"] if c[1] == "xla") == [("census", "xla"), ("kitti2015_compact", "xla")]
    assert ("kitti2015", None) in calls["chains"] and ("kitti2015", "xla") not in calls["chains"]
    assert set(r["chains_xla"]) == {"census", "kitti2015_compact"} and "census_stages_xla" in r
    assert r["kernels"]["setting"] == "auto" and set(r["kernels_status"]) == {"loaded", "path", "reason"}
    assert (tmp_path / "bench.json").is_file()
