"""Benchmark: every stage of the chain on a KITTI-sized frame, the whole chain, and OpenCV SGBM.

Times are warm (after compilation), the median of ``repeats`` runs; compilation is timed
separately. The whole chain's peak memory is the peak resident set size of a fresh child
process that compiles and runs it once (so nothing else in this process inflates it), and
XLA's own buffer estimate of the compiled chain is reported beside it.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

KITTI_SHAPE = (375, 1242)


def _bench_pair(shape=KITTI_SHAPE):
    """A real KITTI-sized pair: the built-in Motorcycle sample resized to 1242x375 would not have
    KITTI's statistics, so use a KITTI frame when ../shared/data is present, else the sample."""
    import cv2

    root = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti2015" / "training"
    left_p, right_p = root / "image_2" / "000021_10.png", root / "image_3" / "000021_10.png"
    if left_p.exists() and right_p.exists():
        left, right = cv2.imread(str(left_p)), cv2.imread(str(right_p))
        src = "KITTI 2015 000021"
    else:
        from .data.datasets import load_builtin_sample

        s = load_builtin_sample()
        left, right = s.left, s.right
        src = "built-in Motorcycle, resized"
    h, w = shape
    left = cv2.resize(left, (w, h), interpolation=cv2.INTER_AREA)
    right = cv2.resize(right, (w, h), interpolation=cv2.INTER_AREA)
    return left, right, src


def _time(fn, *args, repeats=3):
    import jax

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


def stage_timings(left, right, cfg, repeats=3):
    """Per-stage warm and compile times of the chain (each stage jitted on its own)."""
    import jax
    import jax.numpy as jnp

    from . import aggregation, cost, pipeline, refine
    from .sgm import sgm

    gl, gr = (jnp.asarray(a) for a in pipeline.prepare_pair(left, right, cfg))
    d, r = cfg.max_disp, cfg.refine
    rows = {}
    vol, rows["matching cost (%s)" % cfg.cost.method] = _time(
        jax.jit(lambda a, b: cost.matching_cost(a, b, d, cfg.cost)), gl, gr, repeats=repeats)
    arms = aggregation.cross_arms(gl, cfg.cbca.tau, cfg.cbca.arm_length)
    c1, rows[f"CBCA x{cfg.cbca.iterations_before}"] = _time(
        jax.jit(lambda v: aggregation.cbca(v, arms, cfg.cbca.iterations_before, cfg.cbca.arm_length)),
        vol, repeats=repeats)
    c2, rows[f"SGM {cfg.sgm.directions} directions"] = _time(
        jax.jit(lambda v, a, b: sgm(v, a, b, cfg.sgm)), c1, gl, gr, repeats=repeats)
    if cfg.cbca.iterations_after:
        c2, rows[f"CBCA x{cfg.cbca.iterations_after} (after SGM)"] = _time(
            jax.jit(lambda v: aggregation.cbca(v, arms, cfg.cbca.iterations_after, cfg.cbca.arm_length)),
            c2, repeats=repeats)
    wl, rows["WTA"] = _time(jax.jit(refine.wta), c2, repeats=repeats)
    wr, rows["right view from left volume + WTA"] = _time(
        jax.jit(lambda c: refine.wta(refine.right_cost_from_left(c))), c2, repeats=repeats)
    wl = wl.astype(jnp.float32)
    labels, rows["left-right check"] = _time(
        jax.jit(lambda a, b: refine.lr_check(a, b.astype(jnp.float32), d, r.lr_tolerance)), wl, wr,
        repeats=repeats)
    filled, rows["occlusion/mismatch filling"] = _time(jax.jit(refine.fill_disparity), wl, labels,
                                                       repeats=repeats)
    sub, rows["sub-pixel"] = _time(jax.jit(refine.subpixel), c2, filled, repeats=repeats)
    med, rows[f"median {r.median_size}x{r.median_size}"] = _time(
        jax.jit(lambda x: refine.median_filter(x, r.median_size)), sub, repeats=repeats)
    # timed at radius 2 (5x5) even when the preset switches it off, so the cost is visible
    rad = r.bilateral_radius or 2
    name = f"bilateral {2 * rad + 1}x{2 * rad + 1}" + ("" if r.bilateral_radius else " (off in this preset)")
    _, rows[name] = _time(
        jax.jit(lambda x, g: refine.bilateral_filter(x, g, rad, r.bilateral_sigma_space,
                                                     r.bilateral_sigma_range)), med, gl, repeats=repeats)
    return rows


def chain_memory(max_disp: int, method: str) -> dict:
    """Run the whole chain once in a child process; return its peak RSS and timings."""
    code = ("import json,resource,sys,time;"
            "from stereojax.bench import _chain_child;"
            f"print(json.dumps(_chain_child({max_disp}, {method!r})))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr else "child failed"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _chain_child(max_disp: int, method: str) -> dict:
    import jax
    import jax.numpy as jnp

    from . import pipeline
    from .config import preset

    cfg = preset(method, max_disp)
    left, right, src = _bench_pair()
    gl, gr = (jnp.asarray(a) for a in pipeline.prepare_pair(left, right, cfg))
    t0 = time.perf_counter()
    compiled = pipeline.disparity_grey.lower(gl, gr, cfg).compile()
    compile_s = time.perf_counter() - t0
    mem = compiled.memory_analysis()
    jax.block_until_ready(compiled(gl, gr))
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(gl, gr))
        runs.append(time.perf_counter() - t0)
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"warm_s": float(np.median(runs)), "compile_s": compile_s,
            "peak_rss_gib": peak_kib / 2 ** 20,
            "xla_temp_gib": getattr(mem, "temp_size_in_bytes", 0) / 2 ** 30 if mem else None,
            "source": src}


def sgbm_timings(left, right, max_disp, repeats=3) -> dict:
    from .baselines import sgbm_disparity

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


def matmul_rate(n: int = 4096, repeats: int = 3) -> float:
    """Measured dense f32 matmul rate of this machine, GFLOP/s (n x n x n)."""
    import jax
    import jax.numpy as jnp

    a = jnp.ones((n, n), jnp.float32)
    f = jax.jit(lambda x, y: x @ y)
    _, t = _time(f, a, a, repeats=repeats)
    return 2 * n ** 3 / t["warm_s"] / 1e9


def learned_timings(left, right, max_disp: int, repeats: int = 2, exact_disps: int = 8) -> dict:
    """Warm times of the network cost volumes on the pair: cosine head (fresh weights), the
    shipped downsize model in pruned mode (K = 32) and, for the exact downsize head, the time
    of ``exact_disps`` disparities scaled to ``max_disp`` (the work is linear in D)."""
    import jax
    import jax.numpy as jnp

    from . import pipeline
    from .learned_cost import learned_cost
    from .nets import init_params, net_preset
    from .train import load_model, shipped_weights

    cfg = pipeline.StereoConfig(max_disp=max_disp)
    gl, gr = (jnp.asarray(a) for a in pipeline.prepare_pair(left, right, cfg))
    out = {}
    cos = net_preset("cosine", 64)
    _, out["cosine head cost volume"] = _time(
        lambda a, b: learned_cost(cos, init_params(cos, jax.random.PRNGKey(0)), a, b, max_disp), gl, gr,
        repeats=repeats)
    model = load_model(shipped_weights("kitti2015"))
    _, out["downsize head, pruned K=32"] = _time(
        lambda a, b: learned_cost(model.net, model.variables, a, b, max_disp, 32, 32), gl, gr, repeats=1)
    _, t = _time(lambda a, b: learned_cost(model.net, model.variables, a, b, exact_disps, 32, 0), gl, gr,
                 repeats=1)
    h, w = gl.shape
    widths = (2 * model.net.features,) + tuple(model.net.widths) + (1,)
    flop_per_pair = 2 * sum(a * b for a, b in zip(widths[1:-1], widths[2:]))   # layers after the split
    scale = max_disp / exact_disps
    out["downsize head, exact (extrapolated)"] = {"warm_s": t["warm_s"] * scale, "compile_s": t["compile_s"],
                                                  "tflop": flop_per_pair * h * w * max_disp / 1e12}
    out["downsize head, exact (extrapolated)"]["gflop_s"] = (
        out["downsize head, exact (extrapolated)"]["tflop"] * 1e3 / out["downsize head, exact (extrapolated)"]["warm_s"])
    return out


def run_bench(out_dir: Path, repeats: int = 3, max_disp: int = 228, method: str = "census") -> dict:
    import cv2
    import jax

    from .data.io import write_json
    from .config import preset
    from .data.io import atomic_output

    cfg = preset(method, max_disp)
    left, right, src = _bench_pair()
    print(f"bench: {src}, {left.shape[1]}x{left.shape[0]}, {max_disp} disparities, "
          f"{os.cpu_count()} CPU cores, jax {jax.__version__} on {jax.default_backend()}", flush=True)
    stages = stage_timings(left, right, cfg, repeats)
    for name, t in stages.items():
        print(f"  {name:40s} warm {t['warm_s']:7.3f} s   compile {t['compile_s']:6.2f} s", flush=True)
    chain = chain_memory(max_disp, method)
    print(f"  whole chain: {chain}", flush=True)
    sgbm = sgbm_timings(left, right, max_disp, repeats)
    print(f"  OpenCV StereoSGBM (3-way, {cv2.getNumThreads()} threads): {sgbm}", flush=True)
    rate = matmul_rate()
    learned = learned_timings(left, right, max_disp)
    print(f"  dense f32 matmul: {rate:.0f} GFLOP/s; learned cost volumes: {learned}", flush=True)
    result = {"frame": src, "shape": list(left.shape[:2]), "max_disp": max_disp, "method": method,
              "cpu_cores": os.cpu_count(), "machine": platform.processor() or platform.machine(),
              "jax": jax.__version__, "backend": jax.default_backend(), "stages": stages,
              "chain": chain, "sgbm_s": sgbm, "matmul_gflop_s": rate, "learned": learned,
              "config": cfg.to_dict()}
    write_json(out_dir / "bench.json", result)
    lines = [f"# Benchmark: {src}, {left.shape[1]}x{left.shape[0]}, {max_disp} disparities, "
             f"{os.cpu_count()} CPU cores, jax {jax.__version__} ({jax.default_backend()})", "",
             "| stage | warm s | compile s |", "|---|---|---|"]
    lines += [f"| {k} | {v['warm_s']:.3f} | {v['compile_s']:.2f} |" for k, v in stages.items()]
    if "warm_s" in chain:
        lines += ["", "| whole chain (one jit) | value |", "|---|---|",
                  f"| warm run | {chain['warm_s']:.2f} s |", f"| compile | {chain['compile_s']:.1f} s |",
                  f"| peak RSS of the process | {chain['peak_rss_gib']:.2f} GiB |",
                  f"| XLA temporary buffers | {chain['xla_temp_gib']:.2f} GiB |"]
    lines += ["", "| OpenCV StereoSGBM (MODE_SGBM_3WAY, blockSize 5) | s |", "|---|---|",
              f"| left-padded by the disparity range | {sgbm['padded']:.3f} |",
              f"| unpadded | {sgbm['unpadded']:.3f} |", "",
              f"| learned cost volume (matmul peak here: {rate:.0f} GFLOP/s) | warm s | compile s |",
              "|---|---|---|"]
    lines += [f"| {k} | {v['warm_s']:.2f} | {v['compile_s']:.1f} |" for k, v in learned.items()]
    ex = learned["downsize head, exact (extrapolated)"]
    lines += ["", f"Exact downsize head: {ex['tflop']:.0f} TFLOP per frame at {ex['gflop_s']:.0f} GFLOP/s "
              f"= {100 * ex['gflop_s'] / rate:.0f} % of the measured matmul rate.", ""]
    with atomic_output(out_dir / "bench.md") as tmp:
        Path(tmp).write_text("\n".join(lines))
    print(f"-> {out_dir}/bench.json, {out_dir}/bench.md")
    return result
