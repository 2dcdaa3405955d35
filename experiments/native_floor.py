"""The memory floor of the native kernels (issue 51): each native kernel of the census chain
timed on the bench frame's own band volume (KITTI 2015 000021, 1242x375, K = 48: 22.4 M entries,
89 MB) beside a plain native copy of that volume on the same threads, with the chain's freed
buffers kept by glibc (the default once the kernels load) and with fresh pages
(STEREOJAX_MALLOC=0, in a child process), and OpenCV SGBM in the same run.

    python experiments/native_floor.py [--data ../shared/data]   -> experiments/results/native_floor.{json,md}

A kernel that must read one volume and write one cannot beat the copy; the copy's time is a
measurement of the machine (its memory and page faults), not of a kernel.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"

#: kernel -> the volumes it must at least read and write (in units of the band volume)
TRAFFIC = {"copy (the floor)": 2, "census (matching cost)": 1, "CBCA": 2, "SGM": 2, "WTA": 1,
           "right view + WTA": 1, "confidence": 1}


def measure(data, repeats: int = 7) -> dict:
    import jax
    import jax.numpy as jnp

    from stereojax import chain, kernels
    from stereojax.aggregation import cross_based as cb
    from stereojax.app import bench
    from stereojax.config import preset
    from stereojax.disparity import right_view as rv, winner_takes_all as wt
    from stereojax.inference.prepare import prepare_pair
    from stereojax.matching_cost import classical as cl
    from stereojax.optimization import semi_global as sg
    from stereojax.validation import confidence_measure as cm

    assert kernels.status().loaded, kernels.status().reason
    left, right, src = bench._bench_pair(data=data)
    cfg = preset("census", 228)
    gl, gr = (jnp.asarray(a) for a in prepare_pair(left, right, cfg))
    st = chain.run(["coarse pass (bands)", "matching cost", "cross arms"], chain.initial(gl, gr), cfg)
    vol, k = st.vol, cfg.band.width
    disp = wt.wta_volume(vol, "native")
    dright = rv.right_wta(vol, st.right_offset, 1.0, "native")

    def best_of(fn, *args):
        fn = jax.jit(fn)
        jax.block_until_ready(fn(*args))
        runs = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*args))
            runs.append(time.perf_counter() - t0)
        return min(runs)

    kern = {
        "copy (the floor)": (kernels.copy_native, vol.cost),
        "census (matching cost)": (lambda l, r, o: cl.census_band(l, r, o, k, 228, cfg.cost.census_radius,
                                                                  "replicate", None, "native").cost,
                                   gl, gr, vol.offset),
        "CBCA": (lambda v, a: cb.cbca_volume(v, a, 1, cfg.cbca.arm_length, "native").cost, vol, st.arms),
        "SGM": (lambda v, l, r: sg.sgm_volume(v, l, r, cfg.sgm, "native").cost, vol, gl, gr),
        "WTA": (lambda v: wt.wta_volume(v, "native"), vol),
        "right view + WTA": (lambda v, o: rv.right_wta(v, o, 1.0, "native"), vol, st.right_offset),
        "confidence": (lambda v, d, r: cm.confidence_volume(v, d, r, 1.0, "native"), vol, disp, dright),
    }
    rows = {name: best_of(fn, *args) for name, (fn, *args) in kern.items()}
    sgbm = bench.sgbm_timings(left, right, 228, repeats)
    return {"frame": src, "entries": int(vol.cost.size), "bytes": int(vol.cost.nbytes), "threads": kernels.threads(),
            "malloc": os.environ.get("STEREOJAX_MALLOC", "1"), "warm_s": rows, "sgbm_s": sgbm,
            "machine": bench.cpu_description()}


def report(kept: dict, fresh: dict) -> str:
    mb = kept["bytes"] / 1e6
    sgbm = kept["sgbm_s"]["padded"]
    lines = [f"# The memory floor of the native kernels: {kept['frame']}, band volume of {kept['entries'] / 1e6:.1f} M "
             f"entries ({mb:.0f} MB), {kept['threads']} threads, {kept['machine']}",
             "", "Each kernel timed warm (best of 7) on the chain's own volume, with glibc keeping the chain's freed "
             "buffers (the default) and with fresh pages for every output (`STEREOJAX_MALLOC=0`); the floor is the "
             "copy of that volume by the same threads. OpenCV SGBM in the same run: "
             f"{sgbm:.3f} s for the whole frame (MODE_SGBM_3WAY: its cost, its paths and its WTA over 228 disparities).", "",
             "| kernel | volumes moved (least) | warm s, kept pages | GB/s | × the copy's time per volume | "
             "warm s, fresh pages | × OpenCV's time per entry |",
             "|---|---|---|---|---|---|---|"]
    copy_per_volume = kept["warm_s"]["copy (the floor)"] / TRAFFIC["copy (the floor)"]
    ocv_per_entry = sgbm / (375 * 1242 * 228)
    for name, t in kept["warm_s"].items():
        vols = TRAFFIC[name]
        gbs = vols * kept["bytes"] / t / 1e9
        per_entry = t / kept["entries"]
        lines.append(f"| {name} | {vols} | {t:.4f} | {gbs:.1f} | {t / (vols * copy_per_volume):.2f} | "
                     f"{fresh['warm_s'][name]:.4f} | {per_entry / ocv_per_entry:.2f} |")
    lines += ["", f"With fresh pages the copy takes {fresh['warm_s']['copy (the floor)']:.4f} s against "
              f"{kept['warm_s']['copy (the floor)']:.4f} s: every stage's output is a new buffer, and without the "
              "kept buffers its pages are faulted in again on every run."]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(measure(args.data)))
        return
    runs = {}
    for malloc in ("1", "0"):
        env = {**os.environ, "STEREOJAX_MALLOC": malloc}
        cmd = [sys.executable, __file__, "--child"] + (["--data", args.data] if args.data else [])
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        runs[malloc] = json.loads(out.stdout.strip().splitlines()[-1])
    out_dir = Path(args.out)
    (out_dir / "native_floor.json").write_text(json.dumps({"kept": runs["1"], "fresh": runs["0"]}, indent=2) + "\n")
    text = report(runs["1"], runs["0"])
    (out_dir / "native_floor.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
