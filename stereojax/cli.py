"""The ``stereojax`` command: predict, evaluate, demo, bench, train.

Every user mistake ends with one line on stderr and the exit code of its error class
(see docs/usage.md, "Exit codes"); outputs are written atomically, so an interrupted run leaves
either the complete file or none.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from .data.datasets import KITTI_MAX_DISP, parse_frames
from .data.io import json_default as _json_default, write_json
from .data.pairs import find_pairs
from .errors import ConfigError, OutputError, StereoError, StereoInputError
from .outputs import color_scale, write_prediction

DEFAULT_MAX_DISP = KITTI_MAX_DISP     # 228, the KITTI search range of the data layer


# ---- helpers -----------------------------------------------------------------------------------

def _config_file(args):
    """The StereoConfig of ``--config`` (None without it)."""
    from .config import StereoConfig

    if not getattr(args, "config", None):
        return None
    try:
        text = Path(args.config).read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read config file {args.config}: {exc.strerror}") from None
    return StereoConfig.from_json(text)


def _check_out_dir(path: Path) -> Path:
    """Create the output folder and check that it is writable before any long computation."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output folder {path}: {exc.strerror}") from None
    if not path.is_dir() or not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {path} is not writable")
    return path


def _resolve(args, width: int = 0, height: int = 0, dataset: str | None = None, max_disp: int | None = None):
    """What runs for this command line and input (:func:`stereojax.models.resolve`)."""
    from .models import resolve

    if max_disp is None:
        max_disp = getattr(args, "max_disp", None)
    md = DEFAULT_MAX_DISP if max_disp is None else max_disp
    return resolve(args.method, getattr(args, "weights", None), _config_file(args), width, height, dataset,
                   md, getattr(args, "exact_head", False))


class _Phases:
    """One line per phase on stdout (stderr stays for warnings and errors): what is being done,
    then, on the same line, how long it took."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet

    def start(self, what: str):
        self._t0, self._what = time.perf_counter(), what
        if not self.quiet:
            print(f"stereojax: {what} ...", end="", flush=True)

    def done(self) -> float:
        secs = time.perf_counter() - self._t0
        if not self.quiet:
            print(f" {secs:.1f} s", flush=True)
        return secs


def _run_pipeline(left, right, cfg, model=None, phases: _Phases | None = None):
    """Run the chain on one pair; returns (disparity f32[H, W], timings dict).

    The chain is compiled once per size bucket and config (ahead of time, with JAX's
    persistent compilation cache when the CLI enabled it); ``timings`` has ``seconds`` (the
    run, compilation excluded), ``compile_s`` (0 when this process had compiled it already)
    and the bucket."""
    from . import pipeline
    from .compile_cache import bucket_shape
    from jax import devices as jax_devices

    from .devices import current_device

    phases = phases or _Phases(quiet=True)
    device = current_device()           # the map_frames worker's device, or None
    predictor = pipeline.Predictor(cfg, model, device)
    gl, gr = predictor.prepare(left, right)
    shape = bucket_shape(*gl.shape)
    if predictor.is_compiled(*gl.shape):
        compile_s = 0.0
    else:
        phases.start(f"compiling the {cfg.cost.method} chain for {shape[1]}x{shape[0]} "
                     f"(size bucket of {gl.shape[1]}x{gl.shape[0]}), {cfg.max_disp} disparities")
        predictor.compiled(*gl.shape)
        compile_s = phases.done()
    phases.start(f"computing the disparity of {gl.shape[1]}x{gl.shape[0]}")
    disp = predictor.run(gl, gr)
    secs = phases.done()
    return disp, {"seconds": secs, "compile_s": compile_s, "bucket": [int(shape[0]), int(shape[1])],
                  "device": str(device if device is not None else jax_devices()[0])}


# ---- commands ----------------------------------------------------------------------------------

def _calibration(args):
    from .data.datasets import Calibration

    if (args.baseline is None) != (args.focal is None):
        raise ConfigError("--baseline and --focal must be given together")
    if args.baseline is None:
        return None
    if args.baseline <= 0 or args.focal <= 0:
        raise ConfigError(f"--baseline and --focal must be > 0, got {args.baseline}, {args.focal}")
    return Calibration(baseline=args.baseline, focal=args.focal, doffs=args.doffs)


def _predict_one(args, left_p, right_p, out: Path, stem_dir: str, calib, phases):
    from .data.datasets import load_pair

    sample = load_pair(left_p, right_p)
    run = _resolve(args, sample.left.shape[1], sample.left.shape[0])
    cfg = run.config
    disp, timings = _run_pipeline(sample.left, sample.right, cfg, run.model(), phases)
    target = out / stem_dir if stem_dir else out
    target.mkdir(parents=True, exist_ok=True)
    written = write_prediction(target, "", disp, calib, sample.left, ply=args.ply)
    write_json(target / "config.json", cfg.to_dict())
    write_json(target / "timings.json", {**timings, "height": disp.shape[0], "width": disp.shape[1],
                                         "max_disp": cfg.max_disp, "method": cfg.cost.method,
                                         "chosen": run.description})
    return disp, timings, written + ["config.json", "timings.json"], run


def cmd_predict(args) -> int:
    from .compile_cache import enable

    from .devices import local_devices

    pairs, batch = find_pairs(args.inputs, args.pairs)
    local_devices(args.devices)          # a bad --devices is refused for one pair too
    out = _check_out_dir(Path(args.out))
    calib = _calibration(args)
    enable()
    if not batch:
        _, left_p, right_p = pairs[0]
        disp, timings, written, run = _predict_one(args, left_p, right_p, out, "", calib, _Phases())
        print(f"disparity {disp.shape[1]}x{disp.shape[0]} ({run.description}), {timings['seconds']:.2f} s "
              f"(+ {timings['compile_s']:.1f} s compiling) -> {out} ({', '.join(written)})")
        return 0
    return _predict_batch(args, pairs, out, calib)


def _predict_batch(args, pairs, out: Path, calib) -> int:
    """Every pair of a batch: one compiled chain per size bucket, a progress bar with frames/s,
    one line per failed pair (the batch goes on), a summary, exit code 2 if any pair failed."""
    from tqdm import tqdm

    from .memory import current_rss_bytes, peak_rss_bytes

    from .devices import local_devices, map_frames

    devices = local_devices(args.devices)

    def work(pair):
        name, left_p, right_p = pair
        try:
            return pair, _predict_one(args, left_p, right_p, out, name, calib, _Phases(quiet=True)), None
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
            disp, timings, _, run = result
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
    compiles = sum(r["compile_s"] for r in rows)
    summary = {"frames": len(pairs), "ok": len(rows), "failed": failed, "devices": len(devices),
               "wall_s": wall,
               "frames_per_s": len(rows) / wall if wall > 0 else 0.0,
               "frames_per_s_warm": len(rows) * len(devices) / compute if compute > 0 else 0.0,
               "compile_s": compiles, "peak_rss_mb": peak_rss_bytes() / 2 ** 20, "per_frame": rows}
    write_json(out / "summary.json", summary)
    print(f"{len(rows)} of {len(pairs)} pairs -> {out}/<frame>/ in {wall:.1f} s "
          f"({summary['frames_per_s']:.2f} frames/s overall, {summary['frames_per_s_warm']:.2f} frames/s "
          f"after {compiles:.1f} s compiling), peak RSS {summary['peak_rss_mb'] / 1024:.2f} GiB; "
          f"summary.json" + (f"; {len(failed)} failed: " + ", ".join(f["frame"] for f in failed[:10])
                             if failed else ""))
    return 2 if failed else 0


def cmd_evaluate(args) -> int:
    from tqdm import tqdm

    from . import metrics
    from .baselines import sgbm_disparity
    from .compile_cache import enable
    from .data import io
    from .data.datasets import load_dataset, search_range
    from .devices import local_devices, map_frames

    out = _check_out_dir(Path(args.out))
    enable()
    frames = parse_frames(args.frames)
    items = load_dataset(args.data, args.dataset, frames=frames, gt=args.gt)
    run = _resolve(args, 0, 0, args.dataset)
    print(f"method: {run.description}", file=sys.stderr)
    devices = local_devices(args.devices)
    if len(devices) > 1:
        print(f"{len(devices)} devices, one frame each at a time", file=sys.stderr)
    model = run.model()

    def work(item):
        frame_id, load = item
        sample = load()
        if sample.gt is None:
            return frame_id, sample, None, None, None
        max_disp = search_range(args.dataset, sample, args.max_disp)
        disp, timings = _run_pipeline(sample.left, sample.right, run.with_max_disp(max_disp).config, model)
        return frame_id, sample, max_disp, disp, timings

    per_frame, missing_gt = [], []
    methods = ["pipeline"] + (["sgbm", "sgbm_unpadded"] if args.sgbm else [])
    with tqdm(total=len(items), desc=f"evaluate {args.dataset}", unit="frame", file=sys.stderr) as bar:
        for frame_id, sample, max_disp, disp, timings in map_frames(work, items, devices):
            bar.update(1)
            if disp is None:
                missing_gt.append(frame_id)
                continue
            row = {"frame": frame_id, "max_disp": max_disp}
            row["pipeline"] = {**metrics.evaluate(disp, sample.gt, sample.gt_valid, fill=args.fill),
                               "seconds": timings["seconds"], "compile_s": timings["compile_s"],
                               "device": timings["device"]}
            write_prediction(out, f"{frame_id}_", disp, color_max=color_scale(disp, sample.gt, sample.gt_valid))
            io.write_error_map(out / f"{frame_id}_error.png", disp, sample.gt, sample.gt_valid)
            if args.sgbm:
                for name, pad in (("sgbm", True), ("sgbm_unpadded", False)):
                    t0 = time.perf_counter()
                    d_cv, v_cv = sgbm_disparity(sample.left, sample.right, num_disp=max_disp, pad=pad)
                    secs = time.perf_counter() - t0
                    row[name] = {**metrics.evaluate(d_cv, sample.gt, sample.gt_valid, est_valid=v_cv,
                                                    fill=args.fill), "seconds": secs}
            per_frame.append(row)
            bar.set_postfix(bad3=f"{row['pipeline']['bad3']:.2f}%")
    if missing_gt:
        names = ", ".join(missing_gt[:5]) + (" ..." if len(missing_gt) > 5 else "")
        msg = f"no {args.gt} ground truth for {len(missing_gt)} frame(s): {names}"
        if not per_frame:
            raise StereoInputError(msg + "; nothing to evaluate")
        print(f"warning: {msg}; skipped", file=sys.stderr)
    summary = {m: metrics.mean_metrics([r[m] for r in per_frame]) for m in methods}
    for m in methods:
        # compilation is timed apart (compile_s), so every frame's seconds are warm
        summary[m]["seconds_warm"] = float(np.mean([r[m]["seconds"] for r in per_frame]))
    result = {"dataset": args.dataset, "gt": args.gt, "fill": args.fill, "frames": per_frame,
              "mean": summary, "config": run.with_max_disp(per_frame[0]["max_disp"]).config.to_dict()}
    write_json(out / "results.json", result)
    table = format_table(summary)
    with io.atomic_output(out / "results.md") as tmp:
        Path(tmp).write_text(f"# {args.dataset}, {len(per_frame)} frames, {args.gt} GT, "
                             f"missing estimates: {args.fill}\n\n{table}\n")
    print(table)
    print(f"-> {out}/results.json")
    return 0


def format_table(summary: dict) -> str:
    cols = ["bad2", "bad3", "bad4", "bad5", "d1", "epe", "density", "seconds_warm"]
    head = ("| method | >2 px % | >3 px % | >4 px % | >5 px % | D1 % | EPE px | density % "
            "| s/frame (warm) |")
    lines = [head, "|" + "---|" * (len(cols) + 1)]
    labels = {"pipeline": "stereojax pipeline", "sgbm": "OpenCV SGBM, left-padded",
              "sgbm_unpadded": "OpenCV SGBM, unpadded"}
    for name, m in summary.items():
        cells = ["n/a" if np.isnan(m[c]) else f"{m[c]:.2f}" for c in cols]
        lines.append(f"| {labels.get(name, name)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def cmd_demo(args) -> int:
    from . import metrics
    from .data import io
    from .data.datasets import load_builtin_sample

    from .compile_cache import enable

    out = _check_out_dir(Path(args.out))
    enable()
    sample = load_builtin_sample()
    max_disp = args.max_disp or int(sample.max_disp_hint or 70)
    run = _resolve(args, sample.left.shape[1], sample.left.shape[0], "middlebury", max_disp)
    cfg = run.config
    print(f"built-in sample: {sample.name} {sample.left.shape[1]}x{sample.left.shape[0]}, "
          f"{max_disp} disparities, {run.description}")
    phases = _Phases()
    phases.start("loading the model" if run.method == "learned" else "preparing")
    model = run.model()
    phases.done()
    disp, timings = _run_pipeline(sample.left, sample.right, cfg, model, phases)
    phases.start("writing disparity, depth, point cloud and error map")
    written = write_prediction(out, "", disp, sample.calib, sample.left, ply=True,
                               color_max=color_scale(disp, sample.gt, sample.gt_valid))
    io.write_png(out / "left.png", sample.left)
    m = metrics.evaluate(disp, sample.gt, sample.gt_valid)
    io.write_error_map(out / "error.png", disp, sample.gt, sample.gt_valid)
    write_json(out / "metrics.json", {**m, **timings, "method": cfg.cost.method, "max_disp": max_disp})
    phases.done()
    print(f">2 px {m['bad2']:.2f} %   >3 px {m['bad3']:.2f} %   >4 px {m['bad4']:.2f} %   "
          f">5 px {m['bad5']:.2f} %   EPE {m['epe']:.2f} px   ({timings['seconds']:.1f} s, "
          f"+ {timings['compile_s']:.1f} s compiling)")
    print(f"-> {out} ({', '.join(written + ['left.png', 'error.png', 'metrics.json'])})")
    return 0


def _parse_widths(text: str) -> tuple[int, ...]:
    try:
        widths = tuple(int(w) for w in text.split(","))
    except ValueError:
        raise ConfigError(f"--widths must be comma-separated integers such as 64,32, got {text!r}") from None
    if not widths or min(widths) < 1:
        raise ConfigError(f"--widths must be positive integers, got {text!r}")
    return widths


def cmd_train(args) -> int:
    from .data.datasets import load_dataset
    from .train import TrainConfig, fit, maybe_initialize_distributed, train_preset

    maybe_initialize_distributed()
    out = _check_out_dir(Path(args.out))
    if args.config:
        try:
            cfg = TrainConfig.from_dict(json.loads(Path(args.config).read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"cannot read training config {args.config}: {exc}") from None
    else:
        over = {k: v for k, v in (("steps", args.steps), ("seed", args.seed), ("delta", args.delta),
                                  ("lr", args.lr)) if v is not None}
        if args.features or args.widths:
            from .nets import net_preset

            net = net_preset(args.head, args.features or train_preset(args.preset, head=args.head).net.features)
            if args.widths:
                net = dataclasses.replace(net, widths=_parse_widths(args.widths)).validate()
            over["net"] = net
        if args.distill:
            over["distill"] = args.distill_weight
        cfg = train_preset(args.preset, head=args.head, loss=args.loss, **over)
        if args.augment:
            from .train import with_augmentation

            cfg = with_augmentation(cfg)
    gt = "occ" if args.dataset == "middlebury" else "noc"

    def load(frames):
        return [ld() for _, ld in load_dataset(args.data, args.dataset, parse_frames(frames), gt=gt)]

    train_samples = load(args.frames)
    val_samples = load(args.val_frames) if args.val_frames else None
    info = {"data": {"dataset": args.dataset, "frames": [s.name for s in train_samples],
                     "val_frames": [s.name for s in val_samples or []]}}
    print(f"training {cfg.net.head} head ({cfg.loss}, delta {cfg.delta}) on {len(train_samples)} "
          f"{args.dataset} images, {cfg.steps} steps -> {out}", flush=True)
    init = teacher = None
    from .models import load_model, weights_path

    if args.init:
        init = load_model(weights_path(args.init))
        info["init"] = args.init
    if cfg.distill:
        if not args.distill:
            raise ConfigError("the training config distils (distill > 0): name the teacher with --distill")
        teacher = load_model(weights_path(args.distill))
        info["distill_from"] = args.distill
    summary = fit(cfg, train_samples, val_samples, out, resume=args.resume, info=info, devices=args.devices,
                  init=init, teacher=teacher)
    print(json.dumps(summary, indent=2, default=_json_default))
    return 0


def cmd_bench(args) -> int:
    from .bench import run_bench

    run_bench(Path(args.out), repeats=args.repeats, max_disp=args.max_disp, data=args.data)
    return 0


# ---- entry point -------------------------------------------------------------------------------

class _OneLineParser(argparse.ArgumentParser):
    """Usage errors (unknown option, ``--max-disp 1.5``) as one line on stderr, exit code 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _warning_printer(command: str):
    """Show warnings (e.g. a colour image paired with a grey one) as one line on stderr."""
    def show(message, category, filename, lineno, file=None, line=None):
        print(f"stereojax {command}: warning: {message}", file=sys.stderr)
    return show


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(prog="stereojax", description="Stereo matching in JAX: disparity and depth "
                                "from a rectified pair (census/SAD cost, CBCA, SGM, refinement).")
    sub = p.add_subparsers(dest="command", required=True)

    def add_method(sp):
        sp.add_argument("--method", default="best", choices=["best", "learned", "census", "sad"],
                        help="matching cost (default: best = learned with the shipped model for this "
                        "kind of input -- KITTI-like wide frames: KITTI 2015 model, others: Middlebury "
                        "model -- or census when that model is not shipped)")
        sp.add_argument("--weights", help="network checkpoint for --method learned/best, or the name of "
                        "a shipped model (kitti2015_compact, kitti2015 = the paper's full network, middlebury)")
        sp.add_argument("--exact-head", action="store_true", help="learned cost: run the head at every "
                        "disparity instead of the candidates (slow on a CPU; its chain settings were never "
                        "searched)")
        sp.add_argument("--config", help="JSON file with a full StereoConfig (overrides the chain "
                        "settings of --method; its cost.method must fit --method)")

    def add_devices(sp):
        sp.add_argument("--devices", type=int, help="spread the frames over this many local devices, "
                        "one frame per device at a time (default: all; the results equal one device's)")

    sp = sub.add_parser("predict", help="disparity (and depth) of one rectified pair, or of many: "
                        "two folders, a KITTI training/ or testing/ folder, or a list of pairs")
    sp.add_argument("inputs", nargs="*", metavar="INPUT",
                    help="LEFT RIGHT (two images: one pair; two folders: pairs matched by file name), "
                    "or one KITTI training/ or testing/ folder, or one text file of 'LEFT RIGHT' lines")
    sp.add_argument("--pairs", help="text file with one 'LEFT RIGHT' pair per line")
    sp.add_argument("--out", required=True, help="output folder (a batch writes OUT/<frame>/...)")
    sp.add_argument("--max-disp", type=int, default=DEFAULT_MAX_DISP, help="number of disparities (default 228)")
    sp.add_argument("--baseline", type=float, help="baseline in metres (for depth)")
    sp.add_argument("--focal", type=float, help="focal length in pixels (for depth)")
    sp.add_argument("--doffs", type=float, default=0.0, help="x-difference of principal points (Middlebury)")
    sp.add_argument("--ply", action="store_true", help="also write a coloured point cloud (needs calibration)")
    add_devices(sp)
    add_method(sp)
    sp.set_defaults(func=cmd_predict)

    sp = sub.add_parser("evaluate", help="score the pipeline on KITTI 2012/2015 or Middlebury")
    sp.add_argument("--data", required=True, help="data root (e.g. ../shared/data/kitti2015/training)")
    sp.add_argument("--dataset", required=True, choices=["kitti2015", "kitti2012", "middlebury"])
    sp.add_argument("--frames", help="e.g. 000021-000030 or 21,22 (default: all)")
    sp.add_argument("--gt", default="noc", choices=["noc", "occ"], help="ground truth (default noc)")
    sp.add_argument("--fill", default="interpolate", choices=["interpolate", "error"],
                    help="pixels without estimate: KITTI background interpolation, or count as errors")
    sp.add_argument("--max-disp", type=int, help="default: 228 for KITTI, ndisp/GT for Middlebury")
    sp.add_argument("--sgbm", action="store_true",
                    help="also score OpenCV StereoSGBM, left-padded and unpadded, in the same run")
    sp.add_argument("--out", default="out/evaluate", help="output folder")
    add_devices(sp)
    add_method(sp)
    sp.set_defaults(func=cmd_evaluate)

    sp = sub.add_parser("demo", help="run the built-in Middlebury Motorcycle pair and print its errors")
    sp.add_argument("--out", default="out/demo")
    sp.add_argument("--max-disp", type=int, help="default: the sample's disparity range")
    add_method(sp)
    sp.set_defaults(func=cmd_demo)

    sp = sub.add_parser("train", help="train the matching network on patch pairs (CPU)")
    sp.add_argument("--data", required=True, help="data root (e.g. ../shared/data)")
    sp.add_argument("--dataset", default="kitti2015", choices=["kitti2015", "kitti2012", "middlebury"])
    sp.add_argument("--frames", default="000001-000020", help="training frames or scenes (comma list)")
    sp.add_argument("--val-frames", help="validation frames (patch error)")
    sp.add_argument("--preset", default="cpu", choices=["cpu", "paper", "tiny"])
    sp.add_argument("--head", default="downsize", choices=["downsize", "uniform", "cosine"])
    sp.add_argument("--loss", choices=["bce", "relaxed", "hinge"], help="default: relaxed, or hinge for cosine")
    sp.add_argument("--delta", type=float, help="margin of the relaxed loss (default 0.05)")
    sp.add_argument("--steps", type=int)
    sp.add_argument("--seed", type=int)
    sp.add_argument("--config", help="JSON TrainConfig (overrides the preset options)")
    sp.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.msgpack")
    sp.add_argument("--augment", action="store_true", help="MC-CNN-style patch augmentation (rotation, "
                    "scale, shear, brightness and contrast; right patches get their own small difference)")
    sp.add_argument("--init", help="start from these weights (a checkpoint or a shipped model name) "
                    "instead of random ones; the optimiser and schedule start afresh")
    sp.add_argument("--lr", type=float, help="initial learning rate (default: the preset's, 0.02)")
    sp.add_argument("--features", type=int, help="feature maps of the tower (default: the preset's, 64 for cpu)")
    sp.add_argument("--widths", help="hidden widths of a dense head, comma separated (default: the head's, "
                    "512,384,256,128 for downsize); e.g. 64,32 for a compressed network")
    sp.add_argument("--distill", help="teacher network (a checkpoint or a shipped model name): distil its "
                    "similarities beside the loss on the labels")
    sp.add_argument("--distill-weight", type=float, default=1.0, help="weight of the distillation term (default 1)")
    sp.add_argument("--devices", type=int, help="data-parallel over this many devices (default: all); "
                    "the batch must divide by it")
    sp.add_argument("--out", required=True)
    sp.set_defaults(func=cmd_train)

    sp = sub.add_parser("bench", help="time every stage on a KITTI-sized frame (and OpenCV SGBM)")
    sp.add_argument("--out", default="experiments/results")
    sp.add_argument("--repeats", type=int, default=3)
    sp.add_argument("--data", default="../shared/data", help="shared data root with KITTI 2015 000021 (default "
                    "../shared/data; without it the built-in sample, resized)")
    sp.add_argument("--max-disp", type=int, default=DEFAULT_MAX_DISP)
    sp.set_defaults(func=cmd_bench)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_printer(args.command)
            return args.func(args)
    except StereoError as exc:
        print(f"stereojax {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"stereojax {args.command}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(f"stereojax {args.command}: error: out of memory; try a smaller --max-disp or image",
              file=sys.stderr)
        return 6


if __name__ == "__main__":
    sys.exit(main())
