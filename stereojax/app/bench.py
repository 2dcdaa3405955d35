"""Benchmark: every stage of the chain on a KITTI-sized frame, the whole chain, and OpenCV SGBM.

Times are warm (after compilation), the median of ``repeats`` runs; compilation is timed
separately. The whole chain's peak memory is the peak resident set size of a fresh child
process that compiles and runs it once (so nothing else in this process inflates it), and
XLA's own buffer estimate of the compiled chain is reported beside it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from stereojax import chain
from stereojax.app.baselines import sgbm_disparity
from stereojax.chain import STAGES
from stereojax.config import preset
from stereojax.data.datasets import DEFAULT_DATA, load_builtin_sample
from stereojax.data.io import atomic_output, write_json
from stereojax.inference.prepare import prepare_pair
from stereojax.inference.memory import peak_rss_bytes
from stereojax.inference.predictor import Predictor
from stereojax.matching_cost import learned as lc
from stereojax.models.nets import network_flops
from stereojax.models.registry import (learned_config, load_model, resolve, shipped_name,
                                       shipped_weights, weights_for_input)

KITTI_SHAPE = (375, 1242)


def _kitti_bench_paths(data=None) -> tuple[Path, Path]:
    root = Path(data or DEFAULT_DATA) / "kitti2015" / "training"
    return root / "image_2" / "000021_10.png", root / "image_3" / "000021_10.png"


def _bench_pair(shape=KITTI_SHAPE, data=None):
    """A real KITTI-sized pair: the built-in Motorcycle sample resized to 1242x375 would not have
    KITTI's statistics, so use a KITTI frame when ../shared/data is present, else the sample."""

    left_p, right_p = _kitti_bench_paths(data)
    if left_p.exists() and right_p.exists():
        left, right = cv2.imread(str(left_p)), cv2.imread(str(right_p))
        src = "KITTI 2015 000021"
    else:
        from stereojax.data.datasets import load_builtin_sample

        s = load_builtin_sample()
        left, right = s.left, s.right
        src = "built-in Motorcycle, resized"
    h, w = shape
    left = cv2.resize(left, (w, h), interpolation=cv2.INTER_AREA)
    right = cv2.resize(right, (w, h), interpolation=cv2.INTER_AREA)
    return left, right, src


def _time(fn, *args, repeats=3):

    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t0)
    warm = float(np.median(runs))
    return out, {"warm_s": warm, "compile_s": max(first - warm, 0.0)}


def stage_timings(left, right, cfg, model=None, repeats=3) -> dict:
    """Warm and compile time of every stage of the chain's own list
    (:data:`stereojax.chain.STAGES`) that does something for ``cfg``, each stage jitted on its own
    (returning only the fields it makes, so that passing the state through is not timed); each
    row also has ``entries``, the cost entries of the volume it works on (0: none)."""


    variables, net = chain.model_args(cfg, model)
    gl, gr = (jnp.asarray(a) for a in prepare_pair(left, right, cfg))
    st = chain.initial(gl, gr, variables=variables, net=net)
    rows = {}
    for stage in chain.STAGES:
        def made(x, fn=stage.fn):
            out = fn(x, cfg)
            return {f: getattr(out, f) for f in chain.FIELDS if getattr(out, f) is not getattr(x, f)}
        changed = jax.eval_shape(made, st)
        if not changed:          # nothing to do for this config
            continue
        new, rows[stage.name] = _time(jax.jit(made), st, repeats=repeats)
        st = st.replace(**new)
        rows[stage.name]["entries"] = stage_entries(stage.name, st, cfg)
    return rows


def stage_entries(name: str, st, cfg) -> int:
    """The cost entries a stage works on: the coarse pass's full-range volume at its scale, the
    candidate chain's and the chain's volume (H x W x K); 0 for the stages without a volume."""
    if name.startswith("coarse"):
        s = cfg.band.scale
        h, w = st.left.shape
        return -(-h // s) * -(-w // s) * -(-cfg.max_disp // s)
    if st.vol is None and not name.startswith("candidate"):
        return 0
    if name in ("cross arms", "sub-pixel", "median", "bilateral", "left-right check + filling"):
        return 0
    h, w = st.left.shape
    return h * w * (cfg.band.width if cfg.banded else cfg.max_disp)


def peak_rss_gib() -> float:
    """This process's peak resident set size, GiB (:func:`stereojax.inference.memory.peak_rss_bytes`)."""

    return peak_rss_bytes() / 2 ** 30


#: the learned chains of the bench: the shipped KITTI models (the paper's full network and the
#: compressed one), each with its card's chain settings; one of them is ``--method best``
LEARNED = ("kitti2015", "kitti2015_compact")


def learned_setup(name: str, max_disp: int):
    """(model, config, shipped name) of a shipped learned model, or of "best" (the model
    ``--method best`` runs on KITTI frames)."""

    path = weights_for_input(KITTI_SHAPE[1], KITTI_SHAPE[0]) if name == "best" else shipped_weights(name)
    return load_model(path), learned_config(path, max_disp), shipped_name(path)


def chain_child(max_disp: int, method: str, repeats: int = 3, data=None) -> dict:
    """Compile and run the chain of ``method`` (best, a shipped model or a classical preset) on the bench
    pair in this (fresh) process; warm time, compile time and peak RSS."""


    if method in LEARNED or method == "best":
        model, cfg, _ = learned_setup(method, max_disp)
    else:
        model, cfg = None, preset(method, max_disp)
    left, right, src = _bench_pair(data=data)
    t = warm_chain(left, right, cfg, model, repeats)
    return {"warm_s": t["warm_s"], "compile_s": t["compile_s"],
            "peak_rss_gib": peak_rss_gib(), "backend": jax.default_backend(), "source": src}


def warm_chain(left, right, cfg, model=None, repeats: int = 3, confidence: bool = False) -> dict:
    """The whole chain of ``cfg`` (and ``model``) on one pair, compiled for its size bucket:
    ``{"warm_s": median of repeats after one warm-up run, "compile_s", "disparity"}``
    (``confidence``: the chain also computes the confidence map, as ``make demo`` does)."""

    predictor = Predictor(cfg, model, confidence=confidence)
    gl, gr = predictor.prepare(left, right)
    t0 = time.perf_counter()
    predictor.compiled(*gl.shape)
    compile_s = time.perf_counter() - t0
    disp = predictor.run(gl, gr)
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        disp = predictor.run(gl, gr)
        runs.append(time.perf_counter() - t0)
    return {"warm_s": float(np.median(runs)), "compile_s": compile_s, "disparity": disp}


def demo_child(repeats: int = 3) -> dict:
    """``make demo``'s computation in this (fresh) process: the built-in Motorcycle pair through
    ``--method best`` with its confidence map; warm time, compile time, peak RSS."""

    sample = load_builtin_sample()
    h, w = sample.left.shape[:2]
    run = resolve("best", width=w, height=h, dataset="middlebury", max_disp=int(sample.max_disp_hint or 70))
    t = warm_chain(sample.left, sample.right, run.config, run.model(), repeats, confidence=True)
    return {"warm_s": t["warm_s"], "compile_s": t["compile_s"], "peak_rss_gib": peak_rss_gib(),
            "model": run.description, "shape": [h, w], "max_disp": run.config.max_disp}


def _child(code: str, env=None) -> tuple[dict | None, float, str]:
    """Run ``python -c code`` in a fresh process: (its last stdout line as JSON or None, wall
    seconds, last stderr line)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    result = None
    if proc.returncode == 0 and out.strip():
        try:
            result = json.loads(out.strip().splitlines()[-1])
        except json.JSONDecodeError:
            result = None
    last_err = err.strip().splitlines()[-1] if err.strip() else ""
    return result, wall, last_err


def chain_memory(max_disp: int, method: str, data=None) -> dict:
    """Warm time, compile time and peak RSS of the whole chain in a fresh child process."""
    code = ("import json;from stereojax.app.bench import chain_child;"
            f"print(json.dumps(chain_child({max_disp}, {method!r}, data={data!r})))")
    res, _, err = _child(code, {**os.environ, "STEREOJAX_CACHE_DIR": "off"})
    return res if res is not None else {"error": err or "child failed"}


def demo_memory(repeats: int = 3) -> dict:
    """:func:`demo_child` in a fresh child process (no compilation cache)."""
    code = ("import json;from stereojax.app.bench import demo_child;"
            f"print(json.dumps(demo_child({repeats})))")
    res, _, err = _child(code, {**os.environ, "STEREOJAX_CACHE_DIR": "off"})
    return res if res is not None else {"error": err or "child failed"}


def process_timings(max_disp: int, method: str, left_path: Path, right_path: Path, work: Path) -> dict:
    """``stereojax predict`` as a user runs it, twice, with an empty compilation cache: the wall
    time of the cold first process and of the second one (cache hit), and their peak RSS."""
    cache = work / f"cache_{method}"
    env = {**os.environ, "STEREOJAX_CACHE_DIR": str(cache)}
    out = {}
    for name in ("cold", "cache_hit"):
        code = ("import sys, json; from stereojax.app.cli import main; "
                f"rc = main(['predict', {str(left_path)!r}, {str(right_path)!r}, '--out', "
                f"{str(work / ('out_' + method))!r}, '--max-disp', '{max_disp}', "
                f"{'--weights' if method in LEARNED else '--method'!r}, {method!r}]); "
                f"t = json.load(open({str(work / ('out_' + method) / 'timings.json')!r})); "
                "from stereojax.app.bench import peak_rss_gib; "
                "print(json.dumps({'rc': rc, 'peak_rss_gib': peak_rss_gib(), **t}))")
        inner, wall, err = _child(code, env)
        if inner is None:
            inner = {"error": err or "failed", "peak_rss_gib": float("nan")}
        out[name] = {"wall_s": wall, **inner}
    return out


def sgbm_timings(left, right, max_disp, repeats=3) -> dict:

    out = {}
    for pad in (True, False):
        sgbm_disparity(left, right, num_disp=max_disp, pad=pad)
        runs = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            sgbm_disparity(left, right, num_disp=max_disp, pad=pad)
            runs.append(time.perf_counter() - t0)
        out["padded" if pad else "unpadded"] = float(np.median(runs))
    return out


#: the vector units that decide this CPU's speed on the chain (the bench's numbers are for one machine)
SIMD_FLAGS = ("avx", "avx2", "fma", "avx512f", "avx512_bf16", "amx_tile")


def cpu_description() -> str:
    """The processor's model name and its vector units from /proc/cpuinfo, e.g. "AMD EPYC (avx, fma)"."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine()
    model = next((line.split(":", 1)[1].strip() for line in info.splitlines() if line.startswith("model name")),
                 platform.machine())
    flags = set(next((line.split(":", 1)[1].split() for line in info.splitlines() if line.startswith("flags")), []))
    return f"{model} ({', '.join(f for f in SIMD_FLAGS if f in flags) or 'no AVX'})"


def matmul_rate(n: int = 4096, repeats: int = 3) -> float:
    """Measured dense f32 matmul rate of this machine, GFLOP/s (n x n x n)."""

    a = jnp.ones((n, n), jnp.float32)
    f = jax.jit(lambda x, y: x @ y)
    _, t = _time(f, a, a, repeats=repeats)
    return 2 * n ** 3 / t["warm_s"] / 1e9


def learned_profile(left, right, max_disp: int, repeats: int = 2, exact_disps: int = 8,
                    which: str = "best") -> dict:
    """Warm time of each stage of a learned chain (``which``: "best" or a name of :data:`LEARNED`),
    :func:`stage_timings`; and that network's exact head (every disparity) timed on
    ``exact_disps`` disparities and scaled to ``max_disp`` (the work is linear in D)."""


    model, cfg, name = learned_setup(which, max_disp)
    net, v = model.net, model.variables
    rows = stage_timings(left, right, cfg, model, repeats)
    c = cfg.cost
    evals = c.candidates + c.unsure_share * (c.unsure_candidates - c.candidates)
    gl, gr = (jnp.asarray(a) for a in prepare_pair(left, right, cfg))
    fl, fr = jax.jit(lambda a, b: lc.tower_features(net, v, a, b))(gl, gr)
    _, t = _time(jax.jit(lambda f1, f2: lc.dense_cost(net, v, f1, f2, exact_disps, c.rows_per_tile)),
                 fl, fr, repeats=1)
    h, w = gl.shape
    exact_s = t["warm_s"] * max_disp / exact_disps
    exact = {"warm_s": exact_s, "compile_s": t["compile_s"],
             "tflop": (network_flops(net, h, w, max_disp) - network_flops(net, h, w, 0)) / 1e12}
    exact["gflop_s"] = exact["tflop"] * 1e3 / exact_s
    exact["chain_s"] = sum(r["warm_s"] for k, r in rows.items() if k not in NETWORK_STAGES) \
        + rows.get("tower features", {}).get("warm_s", 0.0) + exact_s
    return {"model": name, "net": dataclasses.asdict(net), "config": cfg.to_dict(), "stages": rows,
            "exact": exact, "evals_per_pixel": evals,
            "network_tflop": network_flops(net, h, w, evals) / 1e12,
            "head_tflop": (network_flops(net, h, w, evals) - network_flops(net, h, w, 0)) / 1e12}


#: the stages of a learned chain that are its network: the tower, and the head (its matching cost)
NETWORK_STAGES = ("tower features", "matching cost")


def _kitti_files(left, right, work: Path, data=None) -> tuple[Path, Path]:
    """The bench pair as files (the KITTI originals when present)."""
    lp, rp = _kitti_bench_paths(data)
    if lp.exists() and rp.exists():
        return lp, rp

    lp, rp = work / "left.png", work / "right.png"
    cv2.imwrite(str(lp), left)
    cv2.imwrite(str(rp), right)
    return lp, rp


def run_bench(out_dir: Path, repeats: int = 3, max_disp: int = 228, data=None) -> dict:
    """Everything ``make bench`` reports, in one run on KITTI 2015 000021 (see README)."""



    cfg = preset("census", max_disp)
    left, right, src = _bench_pair(data=data)
    print(f"bench: {src}, {left.shape[1]}x{left.shape[0]}, {max_disp} disparities, "
          f"{os.cpu_count()} CPU cores ({cpu_description()}), jax {jax.__version__} on {jax.default_backend()}",
          flush=True)
    sgbm = [sgbm_timings(left, right, max_disp, repeats)]
    print(f"  OpenCV StereoSGBM (3-way, {cv2.getNumThreads()} threads): {sgbm[0]}", flush=True)
    stages = stage_timings(left, right, cfg, repeats=repeats)
    for name, t in stages.items():
        print(f"  census {name:36s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
    profiles = {}
    for which in LEARNED:
        profiles[which] = prof = learned_profile(left, right, max_disp, which=which)
        for name, t in prof["stages"].items():
            print(f"  {which} {name:45s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
        print(f"  {which}: exact head (extrapolated): {prof['exact']}", flush=True)
    chains = {m: chain_memory(max_disp, m, data) for m in (*LEARNED, "census")}
    best = learned_setup("best", max_disp)[2]
    print(f"  whole chains, warm, fresh processes: {chains}", flush=True)
    demo = demo_memory(repeats)
    print(f"  make demo's computation (built-in Motorcycle pair, best, confidence), fresh process: {demo}",
          flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        lp, rp = _kitti_files(left, right, work, data)
        procs = {m: process_timings(max_disp, m, lp, rp, work) for m in ("best", "kitti2015_compact", "census")}
    print(f"  stereojax predict processes (cold, cache hit): {procs}", flush=True)
    sgbm.append(sgbm_timings(left, right, max_disp, repeats))
    sgbm_pad = float(np.median([t["padded"] for t in sgbm]))
    rate = matmul_rate()
    anchors_file = out_dir / "anchors.json"
    anchors = json.loads(anchors_file.read_text()) if anchors_file.is_file() else None
    result = {"frame": src, "shape": list(left.shape[:2]), "max_disp": max_disp,
              "cpu_cores": os.cpu_count(), "machine": cpu_description(),
              "jax": jax.__version__, "backend": jax.default_backend(), "sgbm_s": sgbm,
              "sgbm_padded_s": sgbm_pad, "census_stages": stages, "profiles": profiles,
              "chains": chains, "best": best, "processes": procs, "demo": demo,
              "accuracy": accuracy_records(out_dir), "matmul_gflop_s": rate, "anchors": anchors,
              "config_census": cfg.to_dict()}
    write_json(out_dir / "bench.json", result)
    with atomic_output(out_dir / "bench.md") as tmp:
        Path(tmp).write_text(format_bench(result))
    print(f"-> {out_dir}/bench.json, {out_dir}/bench.md")
    return result


#: the targets of issue 16, checked by format_bench
TARGETS = {"best_s": 6.0, "best_stretch_s": 3.0, "census_x_sgbm": 20.0, "peak_rss_bytes": 2e9,
           "second_process_extra_s": 5.0}
#: the targets of issue 25 (ratios to OpenCV SGBM timed in the same run; peak RSS of a predict process)
BAND_TARGETS = {"census_x_sgbm": 10.0, "compact_x_sgbm": 25.0, "best_chain_x_sgbm": 15.0,
                "peak_rss_gib": 1.2}


#: the targets of issue 26 (`best` in two seconds): ratios to OpenCV SGBM of the same run, `best`'s
#: share of Pandora's time (make bench-anchors), peak RSS of a `best` predict process, make demo's
#: warm computation, validation > 3 px on KITTI 2015 000021-000030
BEST_TARGETS = {"best_x_sgbm": 30.0, "stretch_x_sgbm": 15.0, "stretch_val": 3.92, "pandora_share": 0.2,
                "peak_rss_gib": 1.2, "demo_s": 5.0, "val": 3.97}


#: the targets of issue 36 (one pass through the chain): ratios to SGBM of the same run; peak RSS of
#: a census and a compact predict process with the compiled chain read from the cache
CHAIN_TARGETS = {"census_x_sgbm": 6.0, "compact_x_sgbm": 15.0, "best_chain_x_sgbm": 8.0, "peak_rss_gib": 1.0}

#: the stages whose cost entries per second the report sets against OpenCV's (issue 36)
RATE_STAGES = ("coarse pass (bands)", "matching cost", "candidate chain", "CBCA before SGM", "SGM",
               "CBCA after SGM", "right view + WTA")


def entry_rates(r: dict) -> list[dict]:
    """Cost entries per second of the band kernels of each profiled chain against OpenCV SGBM's
    (its H x W x D entries in its measured time, cost and every path included): one row per
    (chain, stage) of :data:`RATE_STAGES` that ran, with ``x_opencv`` the time per entry
    relative to OpenCV's."""
    h, w = r["shape"]
    sgbm_rate = h * w * r["max_disp"] / r["sgbm_padded_s"]
    chains = [("census", r["census_stages"])] + [(m, p["stages"]) for m, p in r["profiles"].items()]
    rows = []
    for chain_name, stages in chains:
        for name in RATE_STAGES:
            t = stages.get(name)
            if not t or not t.get("entries") or t["warm_s"] <= 0:
                continue
            if chain_name != "census" and name == "matching cost":
                continue          # the learned head: network time, not a band kernel
            rate = t["entries"] / t["warm_s"]
            rows.append({"chain": chain_name, "stage": name, "entries": t["entries"], "warm_s": t["warm_s"],
                         "rate": rate, "x_opencv": sgbm_rate / rate})
    return rows


def chain_targets(r: dict) -> list[str]:
    """The lines on issue 36's targets: met, or by how much they are missed and which stage holds it."""
    sg, chains, t = r["sgbm_padded_s"], r["chains"], CHAIN_TARGETS
    rates = {(row["chain"], row["stage"]): row for row in entry_rates(r)}

    def held(stages: dict, chain_name: str) -> str:
        name, v = max(((n, v) for n, v in stages.items() if n not in NETWORK_STAGES or chain_name == "census"),
                      key=lambda kv: kv[1]["warm_s"])
        rate = rates.get((chain_name, name))
        per = (f", {rate['rate'] / 1e6:.0f} M entries/s, {rate['x_opencv']:.1f}× OpenCV's time per entry"
               if rate else "")
        return f"Held most by {name} ({v['warm_s']:.2f} s{per}); slowest: {_top(stages)}."

    out = []
    if "warm_s" in chains.get("census", {}):
        _target_line(out, "census chain, × SGBM", chains["census"]["warm_s"] / sg, t["census_x_sgbm"], "×",
                     held(r["census_stages"], "census"))
    prof = r["profiles"].get("kitti2015_compact")
    if prof and "warm_s" in chains.get("kitti2015_compact", {}):
        _target_line(out, "`kitti2015_compact`, × SGBM", chains["kitti2015_compact"]["warm_s"] / sg,
                     t["compact_x_sgbm"], "×", held(prof["stages"], "kitti2015_compact"))
    prof = r["profiles"].get("kitti2015")
    if prof and "warm_s" in chains.get("kitti2015", {}):
        net = _network_s(prof)
        rest = chains["kitti2015"]["warm_s"] - net
        _target_line(out, "the chain around `kitti2015`'s tower and head, × SGBM", rest / sg, t["best_chain_x_sgbm"],
                     "×", f"{rest:.2f} s of {chains['kitti2015']['warm_s']:.2f} s (tower + head {net:.2f} s). "
                     + held(prof["stages"], "kitti2015"))
    for m in ("census", "kitti2015_compact"):
        p = r["processes"].get(m)
        if p:
            _target_line(out, f"peak RSS of a `{m}` predict process, compiled chain from the cache",
                         p["cache_hit"]["peak_rss_gib"], t["peak_rss_gib"], " GiB",
                         f"Cold cache: {p['cold']['peak_rss_gib']:.2f} GiB; the rest is the interpreter, jax and "
                         "XLA's buffers of the chain.")
    return out


def rate_table(r: dict) -> list[str]:
    """The markdown table of :func:`entry_rates`."""
    h, w = r["shape"]
    n = h * w * r["max_disp"]
    lines = [f"OpenCV SGBM: {n / 1e6:.0f} M entries ({w}x{h}x{r['max_disp']}) in {r['sgbm_padded_s']:.3f} s = "
             f"{n / r['sgbm_padded_s'] / 1e6:.0f} M entries/s (its cost, every path and its WTA).", "",
             "| chain | stage | M entries | warm s | M entries/s | × OpenCV's time per entry |", "|---|---|---|---|---|---|"]
    lines += [f"| {x['chain']} | {x['stage']} | {x['entries'] / 1e6:.1f} | {x['warm_s']:.3f} | {x['rate'] / 1e6:.0f} | "
              f"{x['x_opencv']:.1f} |" for x in entry_rates(r)]
    return lines


def accuracy_records(out_dir: Path) -> dict:
    """The accuracy records the targets of issue 26 are read against (other runs, not this one):
    the full KITTI network's and the chosen student's validation > 3 px, and the Middlebury
    student's fold mean, each with the file it comes from (missing files are left out)."""
    out = {}

    def read(name):
        f = Path(out_dir) / name
        return json.loads(f.read_text()) if f.is_file() else None

    dd, fin, mid = read("dense_distill.json"), read("dense_distill_final.json"), read("middlebury_folds_student.json")
    if dd:
        out["kitti2015"] = {"val": dd["full"]["val"], "seconds": dd["full"]["seconds"], "source": "dense_distill.md"}
    if fin:
        out["student"] = {"name": fin["point"], "val": fin["val"], "seconds": fin["seconds"], "limit": fin["best_limit"],
                          "becomes_best": fin["becomes_best"], "source": "dense_distill_final.md"}
    if mid:
        out["middlebury_student"] = {"bad3": mid["mean"]["learned"]["bad3"], "limit": mid["student_bar"],
                                     "seconds": mid["seconds"]["learned"], "becomes_best": mid["becomes_best"],
                                     "source": "middlebury_folds_student.md"}
    return out


def _ordered(stages: dict) -> list:
    """The rows of a stage profile in the chain's order (JSON round trips sort the keys)."""

    order = [s.name for s in STAGES]
    return sorted(stages.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else len(order))


def _arch(net: dict) -> str:
    return f"tower {net['features']} maps, head {'-'.join(map(str, net['widths']))}"


def _target_line(out: list, name: str, value: float, goal: float, unit: str, why: str = "") -> None:
    """Append one target's line to ``out``: met, or by how much it is missed and why."""
    ok = value <= goal
    out.append(f"* {name} ≤ {goal:g}{unit}: {value:.2f}{unit} — " + ("met." if ok else
               f"**not met**, {value - goal:.2f}{unit} over. {why}").rstrip())


def _top(stages: dict, n: int = 3) -> str:
    """The ``n`` slowest stages, "name s, ..."."""
    return ", ".join(f"{name} {v['warm_s']:.2f} s" for name, v in
                     sorted(stages.items(), key=lambda kv: -kv[1]["warm_s"])[:n])


def _network_s(prof: dict) -> float:
    """Warm seconds of a learned chain's tower and head stages (its profile's)."""
    return sum(v["warm_s"] for name, v in prof["stages"].items() if name in NETWORK_STAGES)


def best_targets(r: dict) -> list[str]:
    """The lines on issue 26's targets: met, or by how much they are missed and why."""
    sg, t, best = r["sgbm_padded_s"], BEST_TARGETS, r["best"]
    chain, prof = r["chains"].get(best, {}), r["profiles"].get(best)
    acc = r.get("accuracy") or {}
    student, val = acc.get("student"), acc.get(best, {}).get("val")
    out = []
    if student:
        verdict = "stays the full network" if not student["becomes_best"] else "is that student"
        short = (f"The fastest student ({student['name']}) scores {student['val']:.2f} % against the bound "
                 f"{student['limit']:g} % at {student['seconds']:.2f} s ({student['source']}), so `best` {verdict}")
    else:
        short = "No student record (experiments/results/dense_distill_final.json)"
    if "warm_s" in chain and prof:
        net = _network_s(prof)
        _target_line(out, f"`best` (= `{best}`), × SGBM", chain["warm_s"] / sg, t["best_x_sgbm"], "×",
                     f"{chain['warm_s']:.2f} s, of which tower + head {net:.2f} s ({prof['network_tflop']:.1f} TFLOP "
                     f"at {prof['evals_per_pixel']:g} head evaluations per pixel) and the chain around them "
                     f"{chain['warm_s'] - net:.2f} s. {short}.")
        if val is not None:
            stretch = chain["warm_s"] / sg <= t["stretch_x_sgbm"] and val <= t["stretch_val"]
            out.append(f"* stretch, ≤ {t['stretch_x_sgbm']:g}× SGBM at ≤ {t['stretch_val']:g} %: "
                       f"{chain['warm_s'] / sg:.0f}× at {val:.2f} % — " + ("met." if stretch else "**not met**."))
    a = r.get("anchors")
    if a and a.get("pandora_s"):
        _target_line(out, "`best` / Pandora's time (make bench-anchors, its own run)", a["best_s"] / a["pandora_s"],
                     t["pandora_share"], "×", f"`best` {a['best_s']:.1f} s, Pandora {a['pandora_s']:.1f} s "
                     "(anchors.md); the same head as above.")
    p = r["processes"].get("best")
    if p:
        _target_line(out, "peak RSS of a `best` predict process (cold cache)", p["cold"]["peak_rss_gib"],
                     t["peak_rss_gib"], " GiB", "See issue 25's line above.")
    demo, mid = r.get("demo") or {}, acc.get("middlebury_student")
    if "warm_s" in demo:
        h, w = demo["shape"]
        why = (f"{demo['model']}, {w}x{h}, {demo['max_disp']} disparities, with the confidence map; compiling "
               f"{demo['compile_s']:.1f} s.")
        if mid:
            why += (f" The Middlebury student's fold mean {mid['bad3']:.2f} % > 3 px misses the bound "
                    f"{mid['limit']:g} % ({mid['source']}, {mid['seconds']:.1f} s per scene), so the demo "
                    "keeps the full network.")
        _target_line(out, "`make demo`'s computation after compiling (fresh process)", demo["warm_s"],
                     t["demo_s"], " s", why)
    if val is not None:
        _target_line(out, f"validation > 3 px of `best` (KITTI 2015 000021-000030, band chain; "
                     f"{acc[best]['source']})", val, t["val"], " %",
                     "The full network on the band chain (3.92 % over the full range).")
    return out


def band_targets(r: dict) -> list[str]:
    """The lines on issue 25's targets (ratios to SGBM of this run; peak RSS of predict processes)."""
    sg, chains, t = r["sgbm_padded_s"], r["chains"], BAND_TARGETS
    cfg = (r.get("config_census") or {}).get("band") or {}
    k = cfg.get("width", 0)
    h, w = r["shape"]
    out = []
    if "warm_s" in chains.get("census", {}):
        _target_line(out, "census chain, × SGBM", chains["census"]["warm_s"] / sg, t["census_x_sgbm"], "×",
                      f"Largest stages: {_top(r['census_stages'])}; the band kernels gather each neighbour's band "
                      f"(K = {k}: f32[H, W, K] is {h * w * max(k, 1) * 4 / 1e6:.0f} MB) where the full range shifts slices.")
    prof = r["profiles"].get("kitti2015_compact")
    if prof and "warm_s" in chains.get("kitti2015_compact", {}):
        _target_line(out, "`kitti2015_compact`, × SGBM", chains["kitti2015_compact"]["warm_s"] / sg, t["compact_x_sgbm"], "×",
                      f"Largest stages: {_top(prof['stages'])}.")
    prof = r["profiles"].get("kitti2015")
    if prof and "warm_s" in chains.get("kitti2015", {}):
        net = _network_s(prof)
        rest = chains["kitti2015"]["warm_s"] - net
        _target_line(out, "`kitti2015` without its tower and head, × SGBM", rest / sg, t["best_chain_x_sgbm"], "×",
                      f"{rest:.2f} s of {chains['kitti2015']['warm_s']:.2f} s (tower + head {net:.2f} s); "
                      f"largest other stages: {_top({n: v for n, v in prof['stages'].items() if n not in NETWORK_STAGES})}.")
    for m, p in r["processes"].items():
        peak = p["cold"]["peak_rss_gib"]
        _target_line(out, f"peak RSS of a `{m}` predict process (cold cache), GiB", peak, t["peak_rss_gib"], " GiB",
                      f"With the compiled chain read from the cache: {p['cache_hit']['peak_rss_gib']:.2f} GiB "
                      "(compiling takes about 0.6 GiB); the rest is XLA's buffers of the chain.")
    return out


def format_bench(r: dict) -> str:
    """The markdown report of :func:`run_bench`'s result."""
    sg = r["sgbm_padded_s"]
    chains, profiles, t = r["chains"], r["profiles"], TARGETS
    h, w = r["shape"]

    def ratio(x):
        return f"{x / sg:.0f}x"

    def target(ok):
        return "met" if ok else "**not met**"

    lines = [f"# Benchmark: {r['frame']}, {w}x{h}, {r['max_disp']} disparities, {r['cpu_cores']} CPU cores, "
             f"jax {r['jax']} ({r['backend']}), {r.get('machine', '')}", "",
             "All numbers from one run of `make bench` (`stereojax bench`); OpenCV StereoSGBM timed at the "
             "start and the end of the run (median), so ratios compare like with like.", "",
             "## Warm time per frame (after compilation), ratio to OpenCV SGBM", "",
             "| method | network | head evaluations / pixel | warm s | × SGBM | target |", "|---|---|---|---|---|---|",
             f"| OpenCV StereoSGBM (MODE_SGBM_3WAY, left-padded) | | | {sg:.3f} | 1x | |"]
    for which in LEARNED:
        chain, prof = chains[which], profiles[which]
        if "warm_s" not in chain:
            continue
        is_best = which == r["best"]
        ok = chain["warm_s"] <= t["best_s"]
        goal = (f"`best` ≤ {t['best_s']:g} s: {target(ok)}; stretch ≤ {t['best_stretch_s']:g} s: "
                f"{target(chain['warm_s'] <= t['best_stretch_s'])}" if is_best else
                f"(≤ {t['best_s']:g} s: {'yes' if ok else 'no'}; not `best`)")
        label = f"`--method best` = `{which}`" if is_best else f"`--weights {which}`"
        lines.append(f"| stereojax {label} | {_arch(prof['net'])} | {prof['evals_per_pixel']:g} | "
                     f"{chain['warm_s']:.2f} | {ratio(chain['warm_s'])} | {goal} |")
    full = profiles["kitti2015"]
    ex = full["exact"]
    lines.append(f"| stereojax `kitti2015`, exact head (extrapolated from 8 disparities) | "
                 f"{_arch(full['net'])} | {r['max_disp']} | {ex['chain_s']:.0f} | {ratio(ex['chain_s'])} | |")
    census = chains["census"]
    if "warm_s" in census:
        lines.append(f"| stereojax census chain | | | {census['warm_s']:.2f} | {ratio(census['warm_s'])} | "
                     f"≤ {t['census_x_sgbm']:g}x: {target(census['warm_s'] <= t['census_x_sgbm'] * sg)} |")
    a = r.get("anchors")
    if a and a.get("pandora_s"):
        lines += ["", f"CNES Pandora {a.get('pandora_version', '')} (MC-CNN-fast, Middlebury weights, + libsgm), "
                  f"timed by `make bench-anchors` in a run of its own beside stereojax and SGBM: Pandora "
                  f"{a['pandora_s']:.1f} s, `best` {a['best_s']:.1f} s"
                  + (f", `kitti2015_compact` {a['compact_s']:.1f} s" if "compact_s" in a else "")
                  + f", SGBM {a['sgbm_s']:.3f} s; so `best` is {a['best_s'] / a['pandora_s']:.2f}× Pandora's time"
                  + (f" and `kitti2015_compact` {a['compact_s'] / a['pandora_s']:.2f}×" if "compact_s" in a else "")
                  + " ([anchors.md](anchors.md))."]
    if all("entries" in v for v in r["census_stages"].values()):
        lines += ["", "## The targets of issue 36 (one pass through the chain), met or missed, and why", ""]
        lines += chain_targets(r)
        lines += ["", "## Cost entries per second of the band kernels, against OpenCV's", ""]
        lines += rate_table(r)
    lines += ["", "## The targets of issue 25 (bands), met or missed, and why", ""]
    lines += band_targets(r)
    lines += ["", "## The targets of issue 26 (`best` in two seconds), met or missed, and why", ""]
    lines += best_targets(r)
    lines += ["", "## Processes: compile once, peak memory", "",
              "| method | first process (cold cache) s | second process (cache hit) s | compile in 1st / 2nd s "
              "| peak RSS GiB | targets |", "|---|---|---|---|---|---|"]
    for m, p in r["processes"].items():
        cold, hit = p["cold"], p["cache_hit"]
        warm = chains[r["best"] if m == "best" else m].get("warm_s", float("nan"))
        checks = [f"2nd ≤ warm + {t['second_process_extra_s']:g} s: "
                  f"{target(hit['wall_s'] <= warm + t['second_process_extra_s'])}"]
        peak = max(cold["peak_rss_gib"], hit["peak_rss_gib"])
        if m == "best":
            checks.append(f"peak RSS ≤ {t['peak_rss_bytes'] / 1e9:g} GB: {target(peak * 2 ** 30 <= t['peak_rss_bytes'])}")
        lines.append(f"| {m} | {cold['wall_s']:.1f} | {hit['wall_s']:.1f} | {cold.get('compile_s', float('nan')):.1f} / "
                     f"{hit.get('compile_s', float('nan')):.1f} | {peak:.2f} | {'; '.join(checks)} |")
    lines += ["", "(wall time of the whole `stereojax predict` process: interpreter start, imports, loading, "
              "compiling or reading the compiled chain from the cache, the run, writing outputs.)"]
    for which in LEARNED:
        prof = profiles[which]
        ex = prof["exact"]
        lines += ["", f"## Where the time of `{which}` goes (each stage jitted alone, warm)", "",
                  "| stage | warm s | compile s |", "|---|---|---|"]
        lines += [f"| {k} | {v['warm_s']:.2f} | {v['compile_s']:.1f} |" for k, v in _ordered(prof["stages"])]
        lines += ["", f"Network: {prof['network_tflop'] * 1e3:.0f} GFLOP per frame, of which the head after its "
                  f"split first layer {prof['head_tflop'] * 1e3:.0f} GFLOP at {prof['evals_per_pixel']:g} evaluations "
                  f"per pixel; its exact head {ex['tflop']:.1f} TFLOP, {ex['warm_s']:.0f} s extrapolated "
                  f"({ex['gflop_s']:.0f} GFLOP/s; dense f32 matmul peak here {r['matmul_gflop_s']:.0f} GFLOP/s)."]
    lines += ["", "## Census chain stages (each jitted alone, warm)", "", "| stage | warm s | compile s |", "|---|---|---|"]
    lines += [f"| {k} | {v['warm_s']:.3f} | {v['compile_s']:.2f} |" for k, v in _ordered(r["census_stages"])]
    lines += ["", "Peak RSS of a process that compiles and runs the chain (no cache): " + ", ".join(
        f"{m} {c.get('peak_rss_gib', float('nan')):.2f} GiB" for m, c in chains.items()) + ".", ""]
    return "\n".join(lines)
