"""Large pairs in strips (issue "your own camera"): how much overlap the seams need, and the
seconds per megapixel and peak memory of 2-6 MP pairs, beside OpenCV SGBM in the same run.

1. Seams: KITTI 2015 training frames 000003 and 000021 (census chain, 228 disparities), whole
   and in strips of 160 rows with overlaps 0-64: pixels that differ by > 0.5 px from the whole
   frame, by distance to the nearest seam, and the > 3 px error of both (non-occluded GT).
2. Large pairs: the built-in Motorcycle pair upscaled to about 3 and 6 MP (disparities scaled
   with it), `stereojax predict --method census` in a child process with the default memory
   limit (the whole frame would not fit: it runs in strips), wall time, the chain's seconds, the
   strips and the child's peak RSS; OpenCV StereoSGBM (left-padded) on the same pair, timed in
   this process.

Command:  .venv/bin/python experiments/tiling.py [--data ../shared/data] [--out experiments/results]
Running time here: about 5 min. Writes OUT/tiling.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

import stereojax
from stereojax.app.baselines import sgbm_disparity
from stereojax.data.datasets import DEFAULT_DATA, load_builtin_sample, load_dataset
from stereojax.data.io import write_json, write_png
from stereojax.metrics import evaluate
from stereojax.inference.memory import memory_limit
from stereojax.inference.tiling import strips

OVERLAPS = (0, 16, 32, 48, 64)
ROWS = 160
SIZES_MP = (3.0, 6.0)


def seams(data) -> list[dict]:
    rows = []
    cfg = stereojax.preset("census", 228)
    predict = stereojax.Predictor(cfg)
    for frame in ("000003", "000021"):
        s = load_dataset(data, "kitti2015", [frame], gt="noc")[0][1]()
        whole = predict(s.left, s.right)
        h = whole.shape[0]
        b_whole = evaluate(whole, s.gt, s.gt_valid)["bad3"]
        for overlap in OVERLAPS:
            t0 = time.perf_counter()
            tiled = predict.in_strips(s.left, s.right, ROWS, overlap)
            secs = time.perf_counter() - t0
            cuts = np.array([b[3] for b in strips(h, ROWS, overlap)][:-1])
            dist = np.abs(np.arange(h)[:, None] - cuts[None, :]).min(1)
            differ = np.abs(tiled - whole) > 0.5
            near = {f"{a}-{b}": float(100 * differ[(dist >= a) & (dist < b)].mean())
                    for a, b in ((0, 8), (8, 32), (32, 10 ** 6)) if ((dist >= a) & (dist < b)).any()}
            rows.append({"frame": frame, "overlap": overlap, "strips": len(cuts) + 1, "seconds": secs,
                         "differ_pct": float(100 * differ.mean()), "differ_by_distance_pct": near,
                         "bad3_whole": b_whole, "bad3_tiled": evaluate(tiled, s.gt, s.gt_valid)["bad3"]})
            print(rows[-1], flush=True)
    return rows


def large(work: Path) -> list[dict]:
    sample = load_builtin_sample()
    h0, w0 = sample.left.shape[:2]
    rows = []
    for mp in SIZES_MP:
        scale = (mp * 1e6 / (h0 * w0)) ** 0.5
        w, h = int(round(w0 * scale)), int(round(h0 * scale))
        max_disp = int(round(70 * scale))
        left = cv2.resize(sample.left, (w, h), interpolation=cv2.INTER_CUBIC)
        right = cv2.resize(sample.right, (w, h), interpolation=cv2.INTER_CUBIC)
        lp, rp = work / f"l{mp:g}.png", work / f"r{mp:g}.png"
        write_png(lp, left)
        write_png(rp, right)
        out = work / f"out{mp:g}"
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "stereojax.app.cli", "predict", str(lp), str(rp), "--out", str(out),
                               "--method", "census", "--max-disp", str(max_disp), "--check-rectified", "off"],
                              capture_output=True, text=True)
        wall = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024 / 2 ** 30
        if proc.returncode != 0:
            raise SystemExit(proc.stderr)
        timings = json.loads((out / "timings.json").read_text())
        t0 = time.perf_counter()
        sgbm_disparity(left, right, num_disp=max_disp, pad=True)
        sgbm_s = time.perf_counter() - t0
        rows.append({"width": w, "height": h, "megapixels": w * h / 1e6, "max_disp": max_disp,
                     "wall_s": wall, "chain_s": timings["seconds"], "strips": timings.get("strips", 1),
                     "strip_rows": timings.get("strip_rows", h), "s_per_mp": timings["seconds"] / (w * h / 1e6),
                     "peak_rss_gib": peak, "peak_rss_note": "the largest child so far" if before else "",
                     "sgbm_s": sgbm_s, "limit_gib": memory_limit()[0] / 2 ** 30})
        print(rows[-1], flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        big = large(Path(tmp))
    seam = seams(args.data)
    out = Path(args.out)
    write_json(out / "tiling.json", {"seams": seam, "large": big, "rows": ROWS, "cpu_cores": os.cpu_count()})
    lines = ["# Large pairs in strips", "",
             f"## Seams (census chain, 228 disparities, strips of {ROWS} rows)", "",
             "Pixels whose stitched disparity differs from the whole frame's by > 0.5 px, by distance to the "
             "nearest seam, and the > 3 px error (non-occluded GT) whole and stitched.", "",
             "| frame | overlap rows | strips | differ % (all) | 0-8 rows | 8-32 rows | ≥ 32 rows | > 3 px whole | > 3 px stitched |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in seam:
        d = r["differ_by_distance_pct"]
        lines.append(f"| {r['frame']} | {r['overlap']} | {r['strips']} | {r['differ_pct']:.2f} | {d.get('0-8', 0):.2f} | "
                     f"{d.get('8-32', 0):.2f} | {d.get('32-1000000', 0):.2f} | {r['bad3_whole']:.2f} | {r['bad3_tiled']:.2f} |")
    lines += ["", "## 3 and 6 MP pairs (`stereojax predict --method census`, default memory limit)", "",
              "| size | MP | disparities | strips × rows | chain s | s / MP | process wall s | peak RSS GiB | limit GiB | SGBM s |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in big:
        lines.append(f"| {r['width']}x{r['height']} | {r['megapixels']:.1f} | {r['max_disp']} | {r['strips']} × {r['strip_rows']} | "
                     f"{r['chain_s']:.1f} | {r['s_per_mp']:.1f} | {r['wall_s']:.1f} | {r['peak_rss_gib']:.2f} | "
                     f"{r['limit_gib']:.1f} | {r['sgbm_s']:.2f} |")
    lines += ["", "The built-in Motorcycle pair upscaled (bicubic), disparities scaled with it; peak RSS of the "
              "predict process (ru_maxrss of the children, so each row is at least the row before); "
              f"{os.cpu_count()} CPU cores, no GPU.", "", "Command: `python experiments/tiling.py`", ""]
    (out / "tiling.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
