"""Benchmark: every stage of the chain on a KITTI-sized frame, the whole chain, and OpenCV SGBM.

Times are warm (after compilation), the median of ``repeats`` runs; compilation is timed
separately. The whole chain's peak memory is the peak resident set size of a fresh child
process that compiles and runs it once (so nothing else in this process inflates it), and
XLA's own buffer estimate of the compiled chain is reported beside it.

The classical stages run the native C++ kernels where they loaded (``StereoConfig.kernels``
"auto", :mod:`stereojax.kernels`); the census and ``kitti2015_compact`` chains are also timed with
the JAX kernels (``kernels="xla"``) in the same run, stage by stage and whole, so that bench.md
sets the two side by side (issue 51).

This module measures and writes ``bench.json``; what the numbers are held against (the targets
of the project's issues) and the markdown report live outside the library, in
``experiments/bench_report.py`` (``make bench`` runs both).
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

from stereojax import chain, kernels
from stereojax.app.baselines import sgbm_disparity
from stereojax.config import preset
from stereojax.data.datasets import DEFAULT_DATA, load_builtin_sample
from stereojax.data.io import write_json
from stereojax.inference.prepare import prepare_pair
from stereojax.inference.memory import peak_rss_bytes
from stereojax.inference.predictor import Predictor
from stereojax.inference.programs import pad_to
from stereojax.matching_cost.cascade import Cascade
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


def chain_child(max_disp: int, method: str, repeats: int = 3, data=None, kernels_setting: str | None = None) -> dict:
    """Compile and run the chain of ``method`` (best, a shipped model or a classical preset) on the bench
    pair in this (fresh) process; warm time, compile time, peak RSS and the kernels that ran
    (``kernels_setting``: "auto", "native" or "xla" replaces the config's; None keeps it)."""


    if method in LEARNED or method == "best":
        model, cfg, _ = learned_setup(method, max_disp)
    else:
        model, cfg = None, preset(method, max_disp)
    if kernels_setting is not None:
        cfg = dataclasses.replace(cfg, kernels=kernels_setting).validate()
    left, right, src = _bench_pair(data=data)
    t = warm_chain(left, right, cfg, model, repeats)
    return {"warm_s": t["warm_s"], "compile_s": t["compile_s"],
            "peak_rss_gib": peak_rss_gib(), "backend": jax.default_backend(), "source": src,
            "kernels": kernels.record(cfg.kernels)}


def warm_chain(left, right, cfg, model=None, repeats: int = 3, confidence: bool = False, cascade=None) -> dict:
    """The whole chain of ``cfg`` (and ``model``) on one pair, compiled for its size bucket:
    ``{"warm_s": median of repeats after one warm-up run, "compile_s", "disparity"}``
    (``confidence``: the chain also computes the confidence map, as ``make demo`` does;
    ``cascade``: a :class:`~stereojax.matching_cost.cascade.Cascade` with ``model`` its student)."""

    predictor = Predictor(cfg, model, confidence=confidence, cascade=cascade)
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


def chain_memory(max_disp: int, method: str, data=None, kernels_setting: str | None = None) -> dict:
    """Warm time, compile time and peak RSS of the whole chain in a fresh child process
    (``kernels_setting``: as :func:`chain_child`; not for the cascade)."""
    child = f"cascade_child({max_disp}, data={data!r})" if method == "cascade" else \
        f"chain_child({max_disp}, {method!r}, data={data!r}, kernels_setting={kernels_setting!r})"
    code = f"import json;from stereojax.app.bench import chain_child, cascade_child;print(json.dumps({child}))"
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
                    which: str = "best", xla: bool = False) -> dict:
    """Warm time of each stage of a learned chain (``which``: "best" or a name of :data:`LEARNED`),
    :func:`stage_timings`; and that network's exact head (every disparity) timed on
    ``exact_disps`` disparities and scaled to ``max_disp`` (the work is linear in D).
    ``xla``: the stages are also timed with the JAX kernels (``stages_xla``; with the native
    kernels loaded, else the default already is the JAX kernels and it is left out)."""


    model, cfg, name = learned_setup(which, max_disp)
    net, v = model.net, model.variables
    rows = stage_timings(left, right, cfg, model, repeats)
    rows_xla = (stage_timings(left, right, dataclasses.replace(cfg, kernels="xla"), model, repeats)
                if xla and kernels.native(cfg.kernels) else None)
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
    out = {"model": name, "net": dataclasses.asdict(net), "config": cfg.to_dict(), "stages": rows,
           "exact": exact, "evals_per_pixel": evals, "kernels": kernels.record(cfg.kernels),
           "network_tflop": network_flops(net, h, w, evals) / 1e12,
           "head_tflop": (network_flops(net, h, w, evals) - network_flops(net, h, w, 0)) / 1e12}
    if rows_xla is not None:
        out["stages_xla"] = rows_xla
    return out


#: the cascade of the bench (issue 38; experiments/results/cascade_curve.md): (student, full
#: network, share q of pixels re-scored)
CASCADE = ("kitti2015_compact", "kitti2015", 0.2)


def _cascade_setup(max_disp: int, share: float):
    student, cfg, _ = learned_setup(CASCADE[0], max_disp)
    return student, cfg, Cascade(load_model(shipped_weights(CASCADE[1])), share)


def cascade_child(max_disp: int, share: float = CASCADE[2], repeats: int = 3, data=None) -> dict:
    """The cascade's whole chain on the bench pair in this (fresh) process: warm time, compile
    time and peak RSS (as :func:`chain_child`)."""
    student, cfg, cascade = _cascade_setup(max_disp, share)
    left, right, src = _bench_pair(data=data)
    t = warm_chain(left, right, cfg, student, repeats, cascade=cascade)
    return {"warm_s": t["warm_s"], "compile_s": t["compile_s"], "peak_rss_gib": peak_rss_gib(),
            "backend": jax.default_backend(), "source": src, "share": share,
            "student": CASCADE[0], "full": CASCADE[1]}


def cascade_profile(left, right, max_disp: int, share: float = CASCADE[2], repeats: int = 2) -> dict:
    """Where the cascade's time goes: its three compiled programs timed one at a time (the
    student's bands, tower and candidates; the student's head and chain up to its confidence;
    the full network at the unsure pixels and the chain on the mixed volume), and the full
    network's tower alone (inside the third)."""
    student, cfg, cascade = _cascade_setup(max_disp, share)
    predictor = Predictor(cfg, student, cascade=cascade)
    gl, gr = predictor.prepare(left, right)
    chain_, _ = predictor.compiled(*gl.shape)
    lp, rp = pad_to(gl, chain_.shape), pad_to(gr, chain_.shape)
    valid = jnp.array(gl.shape, jnp.int32)
    sv, fv = predictor.variables
    carry, first = _time(chain_._first, lp, rp, valid, sv, None, None, repeats=repeats)   # no limits, no given bands
    (vol, conf), mid = _time(chain_._student, carry, sv, repeats=repeats)
    _, last = _time(chain_._second, carry, vol, conf, fv, repeats=repeats)
    full = cascade.full
    _, tower = _time(jax.jit(lambda a, b: lc.tower_features(full.net, fv, a, b, valid)), lp, rp, repeats=repeats)
    return {"share": share, "student": CASCADE[0], "full": CASCADE[1],
            "stages": dict(zip(CASCADE_PROGRAMS, (first, mid, last, tower)))}


#: the rows of :func:`cascade_profile`, in the order they run
CASCADE_PROGRAMS = ("student: bands, tower, candidate chain", "student: head, chain up to its confidence",
                    "full network at the unsure pixels + the chain on the mixed volume",
                    "(inside the last: the full network's tower on both images)")


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


#: the chains the bench also times with the JAX kernels, stage by stage and whole (issue 51):
#: ``kitti2015``'s JAX-kernel profile would cost minutes, so it keeps the default kernels only
XLA_CHAINS = ("census", "kitti2015_compact")


def run_bench(out_dir: Path, repeats: int = 3, max_disp: int = 228, data=None) -> dict:
    """Everything ``make bench`` reports, in one run on KITTI 2015 000021 (see README)."""



    cfg = preset("census", max_disp)
    left, right, src = _bench_pair(data=data)
    # with the native kernels loaded, the census and compact chains are timed with both kernel sets
    both = kernels.native(cfg.kernels)
    print(f"bench: {src}, {left.shape[1]}x{left.shape[0]}, {max_disp} disparities, "
          f"{os.cpu_count()} CPU cores ({cpu_description()}), jax {jax.__version__} on {jax.default_backend()}; "
          f"kernels: {kernels.describe(cfg.kernels)}" + ("; census and kitti2015_compact also with the JAX kernels"
                                                         if both else ""),
          flush=True)
    sgbm = [sgbm_timings(left, right, max_disp, repeats)]
    print(f"  OpenCV StereoSGBM (3-way, {cv2.getNumThreads()} threads): {sgbm[0]}", flush=True)
    stages = stage_timings(left, right, cfg, repeats=repeats)
    for name, t in stages.items():
        print(f"  census {name:36s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
    stages_xla = stage_timings(left, right, dataclasses.replace(cfg, kernels="xla"), repeats=repeats) if both else None
    for name, t in (stages_xla or {}).items():
        print(f"  census (xla) {name:30s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
    profiles = {}
    for which in LEARNED:
        profiles[which] = prof = learned_profile(left, right, max_disp, which=which, xla=which in XLA_CHAINS)
        for name, t in prof["stages"].items():
            print(f"  {which} {name:45s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
        for name, t in prof.get("stages_xla", {}).items():
            print(f"  {which} (xla) {name:39s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
        print(f"  {which}: exact head (extrapolated): {prof['exact']}", flush=True)
    profiles["cascade"] = cascade_profile(left, right, max_disp)
    print(f"  cascade (q = {CASCADE[2]:g}): {profiles['cascade']['stages']}", flush=True)
    chains = {m: chain_memory(max_disp, m, data) for m in (*LEARNED, "census", "cascade")}
    best = learned_setup("best", max_disp)[2]
    print(f"  whole chains, warm, fresh processes: {chains}", flush=True)
    chains_xla = {m: chain_memory(max_disp, m, data, kernels_setting="xla") for m in XLA_CHAINS} if both else {}
    if chains_xla:
        print(f"  whole chains with the JAX kernels, warm, fresh processes: {chains_xla}", flush=True)
    demo = demo_memory(repeats)
    print(f"  make demo's computation (built-in Motorcycle pair, best, confidence), fresh process: {demo}",
          flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        lp, rp = _kitti_files(left, right, work, data)
        procs = {m: process_timings(max_disp, m, lp, rp, work) for m in ("best", "kitti2015_compact", "census")}
    print(f"  stereojax predict processes (cold, cache hit): {procs}", flush=True)
    sgbm.append(sgbm_timings(left, right, max_disp, repeats))
    # the faster of the two: a slow SGBM run (measured 0.25 s at the start against 0.15 s at the end
    # of one run) would flatter every ratio, the faster one never does
    sgbm_pad = float(min(t["padded"] for t in sgbm))
    rate = matmul_rate()
    anchors_file = out_dir / "anchors.json"
    anchors = json.loads(anchors_file.read_text()) if anchors_file.is_file() else None
    result = {"frame": src, "shape": list(left.shape[:2]), "max_disp": max_disp,
              "cpu_cores": os.cpu_count(), "machine": cpu_description(),
              "jax": jax.__version__, "backend": jax.default_backend(), "sgbm_s": sgbm,
              "sgbm_padded_s": sgbm_pad, "census_stages": stages, "profiles": profiles,
              "chains": chains, "best": best, "processes": procs, "demo": demo,
              "matmul_gflop_s": rate, "anchors": anchors,
              "config_census": cfg.to_dict(),
              # issue 51: which kernels the default chains ran, and the JAX kernels beside them
              "kernels": kernels.record(cfg.kernels), "kernels_status": kernels.status()._asdict()}
    if stages_xla is not None:
        result["census_stages_xla"] = stages_xla
    if chains_xla:
        result["chains_xla"] = chains_xla
    write_json(out_dir / "bench.json", result)
    print(f"-> {out_dir}/bench.json (the report with the issues' targets: python experiments/bench_report.py)")
    return result
