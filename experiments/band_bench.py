"""The band chain against the full-range chain and OpenCV SGBM, timed in one run on the bench
frame (KITTI 2015 000021, 1242x375, 228 disparities), with each chain's peak RSS in a fresh
child process (the whole of `make bench` takes longer; this is its core for issue 25).

    python experiments/band_bench.py [--data ../shared/data]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from stereojax.app import bench
from stereojax.data.datasets import DEFAULT_DATA

RESULTS = Path(__file__).resolve().parent / "results"
METHODS = ("census", "kitti2015_compact", "kitti2015")

_CHILD = """
import dataclasses, json
from stereojax import bench
from stereojax.config import BandConfig
method, full, data = {method!r}, {full!r}, {data!r}
if method in bench.LEARNED:
    model, cfg, _ = bench.learned_setup(method, 228)
else:
    from stereojax.config import preset
    model, cfg = None, preset(method, 228)
if full:
    cfg = dataclasses.replace(cfg, band=BandConfig())
left, right, src = bench._bench_pair(data=data)
t = bench.warm_chain(left, right, cfg, model, 1)
print(json.dumps({{"warm_s": t["warm_s"], "compile_s": t["compile_s"], "peak_rss_gib": bench.peak_rss_gib()}}))
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS / "band_bench"))
    args = ap.parse_args(argv)
    left, right, src = bench._bench_pair(data=args.data)
    rows = {}
    sgbm = bench.sgbm_timings(left, right, 228, args.repeats)["padded"]
    for method in METHODS:
        for full in (False, True):
            code = _CHILD.format(method=method, full=full, data=args.data)
            res, _, err = bench._child(code, {**os.environ, "STEREOJAX_CACHE_DIR": "off"})
            name = method + (" (full range)" if full else " (bands)")
            rows[name] = res if res is not None else {"error": err}
            r = rows[name]
            print(f"{name:32s} " + (f"warm {r['warm_s']:.2f} s ({r['warm_s'] / sgbm:.0f}x SGBM), compile "
                                   f"{r['compile_s']:.1f} s, peak RSS {r['peak_rss_gib']:.2f} GiB"
                                   if "warm_s" in r else r["error"]), flush=True)
    sgbm2 = bench.sgbm_timings(left, right, 228, args.repeats)["padded"]     # again, after the chains
    out = Path(args.out)
    result = {"source": src, "sgbm_padded_s": sgbm, "sgbm_padded_after_s": sgbm2, "chains": rows}
    out.with_suffix(".json").write_text(json.dumps(result, indent=2))
    lines = ["# The band chain beside the full-range chain and OpenCV SGBM", "",
             f"{src}, 1242x375, 228 disparities, this 2-core CPU; one run of `python experiments/band_bench.py`. "
             f"SGBM (3-way, left-padded) {sgbm:.3f} s before the chains and {sgbm2:.3f} s after; ratios use "
             "the first. Each chain compiled and run in a fresh child process (warm = the run after the "
             "compiling one); peak RSS is that child's.", "",
             "| chain | warm s | × SGBM | compile s | peak RSS GiB |", "|---|---|---|---|---|",
             f"| OpenCV StereoSGBM | {sgbm:.3f} | 1× | – | – |"]
    for name, r in rows.items():
        if "warm_s" in r:
            lines.append(f"| {name} | {r['warm_s']:.2f} | {r['warm_s'] / sgbm:.0f}× | {r['compile_s']:.1f} | "
                         f"{r['peak_rss_gib']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
