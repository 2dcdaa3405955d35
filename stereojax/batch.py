"""Predicting pairs from files: one pair into a folder, or a batch of pairs into
``OUT/<frame>/`` with a progress bar, one line per failed pair and ``summary.json``."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

from .data.io import write_json
from .errors import StereoError
from .outputs import write_prediction


def predict_pair(left_path, right_path, target: Path, resolve: Callable, calib=None, ply: bool = False,
                 phases=None) -> dict:
    """Disparity (and depth with ``calib``) of one pair of image files, written into ``target``.

    resolve(width, height) -> :class:`stereojax.models.Resolved` says what runs for this input.
    Returns ``{"disparity", "timings", "written", "run"}``; ``timings`` as
    :meth:`stereojax.pipeline.Predictor.timed`."""
    from .data.datasets import load_pair
    from .devices import current_device
    from .pipeline import Predictor

    sample = load_pair(left_path, right_path)
    run = resolve(sample.left.shape[1], sample.left.shape[0])
    cfg = run.config
    disp, timings = Predictor(cfg, run.model(), current_device()).timed(sample.left, sample.right, phases)
    target.mkdir(parents=True, exist_ok=True)
    written = write_prediction(target, "", disp, calib, sample.left, ply=ply)
    write_json(target / "config.json", cfg.to_dict())
    write_json(target / "timings.json", {**timings, "height": disp.shape[0], "width": disp.shape[1],
                                         "max_disp": cfg.max_disp, "method": cfg.cost.method,
                                         "chosen": run.description})
    return {"disparity": disp, "timings": timings, "written": written + ["config.json", "timings.json"],
            "run": run}


def predict_batch(pairs, out: Path, resolve: Callable, calib=None, ply: bool = False,
                  devices: list | None = None) -> dict:
    """Every ``(name, left, right)`` pair into ``out/<name>/``: one compiled chain per size
    bucket, a progress bar with frames/s, one line per failed pair (the batch goes on), and
    ``out/summary.json``, which is also returned."""
    from tqdm import tqdm

    from .devices import map_frames
    from .memory import current_rss_bytes, peak_rss_bytes

    devices = list(devices or [])

    def work(pair):
        name, left_p, right_p = pair
        try:
            return pair, predict_pair(left_p, right_p, out / name, resolve, calib, ply), None
        except (StereoError, OSError) as exc:
            return pair, None, exc

    rows, failed, described = [], [], set()
    with tqdm(total=len(pairs), desc="predict", unit="frame", file=sys.stderr, dynamic_ncols=True) as bar:
        if len(devices) > 1:
            tqdm.write(f"stereojax predict: {len(devices)} devices, one frame each at a time", file=sys.stderr)
        t_start = time.perf_counter()
        for (name, left_p, right_p), result, exc in map_frames(work, pairs, devices):
            bar.update(1)
            if exc is not None:
                failed.append({"frame": name, "left": str(left_p), "right": str(right_p), "error": str(exc)})
                tqdm.write(f"stereojax predict: error: {name}: {exc}", file=sys.stderr)
                continue
            disp, timings, run = result["disparity"], result["timings"], result["run"]
            if run.description not in described:
                described.add(run.description)
                tqdm.write(f"stereojax predict: method: {run.description}", file=sys.stderr)
            rows.append({"frame": name, "seconds": timings["seconds"], "compile_s": timings["compile_s"],
                         "device": timings["device"],
                         "bucket": timings["bucket"], "width": int(disp.shape[1]), "height": int(disp.shape[0]),
                         "rss_mb": current_rss_bytes() / 2 ** 20})
            bar.set_postfix(bucket=f"{timings['bucket'][1]}x{timings['bucket'][0]}")
    wall = time.perf_counter() - t_start
    compute = sum(r["seconds"] for r in rows)
    n_dev = max(len(devices), 1)
    summary = {"frames": len(pairs), "ok": len(rows), "failed": failed, "devices": n_dev,
               "wall_s": wall,
               "frames_per_s": len(rows) / wall if wall > 0 else 0.0,
               "frames_per_s_warm": len(rows) * n_dev / compute if compute > 0 else 0.0,
               "compile_s": sum(r["compile_s"] for r in rows), "peak_rss_mb": peak_rss_bytes() / 2 ** 20,
               "per_frame": rows}
    write_json(out / "summary.json", summary)
    return summary
