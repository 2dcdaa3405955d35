"""The ``stereojax`` command: predict, evaluate, demo, bench, train.

Every user mistake ends with one line on stderr and the exit code of its error class
(see docs/usage.md, "Exit codes"); outputs are written atomically, so an interrupted run leaves
either the complete file or none.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Sequence

from stereojax import kernels as kernels_mod
from stereojax.app.batch import pair_line, predict_batch, predict_pair, summary_line
from stereojax.app.bench import run_bench
from stereojax.app.demo import run_demo
from stereojax.app.evaluation import evaluate_dataset
from stereojax.app.outputs import folder_lock, output_folder, remove_if_empty
from stereojax.app.parser import DEFAULT_MAX_DISP, build_parser
from stereojax.app.ray_batch import connect, predict_batch_ray
from stereojax.config import StereoConfig
from stereojax.data.calibration import calibration_from_options, describe, rectified_or_raw
from stereojax.data.datasets import load_builtin_sample, load_dataset, parse_frames
from stereojax.data.io import json_default as _json_default, read_image
from stereojax.data.pairs import find_pairs, unmatched_line
from stereojax.devices import local_devices
from stereojax.errors import ConfigError, InputWarning, StereoError, StereoInputError
from stereojax.inference.compile_cache import enable
from stereojax.inference.prepare import check_disp_range
from stereojax.interrupt import Interrupted
from stereojax.models.registry import resolve
from stereojax.progress import Phases

# ---- helpers -----------------------------------------------------------------------------------

def _resolve(args, width: int = 0, height: int = 0, dataset: str | None = None, max_disp: int | None = None):
    """What runs for this command line and input (:func:`stereojax.models.registry.resolve`). The number
    of disparities: ``max_disp``, else ``--max-disp`` when given, else a ``--config`` file's
    ``max_disp``, else 228 (KITTI's); a ``--max-disp`` given beside a config file wins."""
    if max_disp is None:
        max_disp = getattr(args, "max_disp", None)
    config = StereoConfig.from_file(args.config) if getattr(args, "config", None) else None
    if max_disp is None:
        max_disp = config.max_disp if config is not None else DEFAULT_MAX_DISP
    run = resolve(args.method, getattr(args, "weights", None), config, width, height, dataset,
                  max_disp, getattr(args, "exact_head", False), getattr(args, "scene", "auto"),
                  getattr(args, "cascade", None), getattr(args, "cascade_weights", None))
    if getattr(args, "kernels", None):        # --kernels wins over a --config file's kernels
        run = dataclasses.replace(run, config=dataclasses.replace(run.config, kernels=args.kernels).validate())
    return run


def _kernels_setting(args) -> str:
    """The ``kernels`` setting of the command line: ``--kernels``, else a ``--config`` file's, else auto."""
    if getattr(args, "kernels", None):
        return args.kernels
    if getattr(args, "config", None):
        return StereoConfig.from_file(args.config).kernels
    return "auto"


def _kernels_lines(args) -> tuple[str | None, str | None]:
    """(the line printed first, the line printed right after the command's first line): the kernels
    that run, in words (:func:`stereojax.kernels.describe`). ``auto`` without the native library:
    the first line says that the chain runs the JAX kernels, and why. ``--kernels native`` without
    it: :class:`~stereojax.errors.ConfigError`."""
    setting = _kernels_setting(args)
    line = f"stereojax: kernels: {kernels_mod.describe(setting)}"
    if setting == "auto" and not kernels_mod.status().loaded:
        return line, None
    return None, line


def _rectifier(args):
    """predict's Rectifier (``--calib RAW --rectify``) or None; the mismatches are one-line errors."""
    rectify = getattr(args, "rectify", False)
    if args.calib is None:
        if rectify:
            raise ConfigError("--rectify needs --calib with a raw stereo calibration (see stereojax calibrate)")
        if getattr(args, "frame", "rectified") != "rectified":
            raise ConfigError("--frame original needs --calib RAW --rectify")
        return None
    rect, _ = rectified_or_raw(args.calib, rectify)
    if rect is None and getattr(args, "frame", "rectified") != "rectified":
        raise ConfigError("--frame original needs --rectify (the original camera of a raw calibration)")
    return rect


def _calibration(args, show: bool = True):
    """(the calibration of the command line or None, its one-line description or None)."""
    rect = _rectifier(args) if args.calib is not None or getattr(args, "rectify", False) else None
    if rect is not None:
        if args.baseline is not None or args.focal is not None:
            raise ConfigError("give either --calib or --baseline/--focal, not both")
        calib, source = rect.calibration, f"{args.calib} rectified ({rect.size[0]}x{rect.size[1]} images)"
        args.rectifier = rect
    else:
        calib, source = calibration_from_options(args.calib, args.baseline, args.focal, args.doffs)
        args.rectifier = None
    line = describe(calib, source) if calib is not None else None
    if show and line:
        print(line)
    return calib if show else (calib, line)


def _max_disp_note(args) -> str | None:
    """The line that says which of ``--max-disp`` and a ``--config`` file's ``max_disp`` runs."""
    if not getattr(args, "config", None) or getattr(args, "disp_range", None):
        return None
    file_md = StereoConfig.from_file(args.config).max_disp
    if args.max_disp is None or args.max_disp == file_md:
        return f"{file_md} disparities from {args.config}"
    return f"--max-disp {args.max_disp} overrides max_disp {file_md} of {args.config}"


def _first_size(pairs) -> tuple[int, int] | None:
    """(width, height) of the first readable left image of ``pairs`` (None: none of the first
    few reads; the frames report their own errors)."""
    for _, left, _ in pairs[:3]:
        try:
            img = read_image(left)
        except StereoError:
            continue
        return img.shape[1], img.shape[0]
    return None


def _disp_range_arg(values):
    """``--disp-range MIN MAX`` -> (MIN, MAX); ``--disp-range auto`` -> "auto"; absent -> None."""
    if values is None:
        return None
    if values == ["auto"]:
        return "auto"
    if len(values) != 2:
        raise StereoInputError(f"--disp-range takes MIN MAX or auto, got {' '.join(values)!r}")
    try:
        nums = [int(v) for v in values]
    except ValueError:
        raise StereoInputError(f"--disp-range takes two integers MIN MAX (or auto), got {' '.join(values)!r}") from None
    return check_disp_range(tuple(nums))


# ---- commands ----------------------------------------------------------------------------------

def cmd_predict(args) -> int:
    first, after = _kernels_lines(args)
    if first:
        print(first, flush=True)
    pairs, batch = find_pairs(args.inputs, args.pairs)
    if args.ray and batch:       # before JAX starts its threads: a local cluster forks its processes
        connect(args.ray)
    devices = local_devices(args.devices)          # a bad --devices is refused for one pair too
    calib, calib_line = _calibration(args, show=False)
    if args.ply and calib is None:
        raise ConfigError("--ply needs a calibration for depth: give --calib FILE, or --baseline and --focal")
    if args.max_depth is not None and not args.max_depth > 0:
        raise ConfigError(f"--max-depth must be a positive number of metres, got {args.max_depth}")
    if args.max_depth is not None and calib is None:
        raise ConfigError("--max-depth needs a calibration for depth: give --calib FILE, or --baseline and --focal")
    out = output_folder(args.out)
    enable()
    # a batch takes the folder's lock first: a refused second batch says nothing else
    with folder_lock(out, "predict") if batch else contextlib.nullcontext():
        return _predict(args, pairs, batch, out, devices, calib, calib_line, after)


def _predict(args, pairs, batch, out, devices, calib, calib_line, kernels_line=None) -> int:
    opts = dict(calib=calib, ply=args.ply, min_confidence=args.min_confidence, check_rectified=args.check_rectified,
                tile=args.tile, disp_range=_disp_range_arg(args.disp_range), max_depth=args.max_depth)
    if getattr(args, "rectifier", None) is not None:
        opts.update(rectifier=args.rectifier, frame=args.frame)
    resolve = lambda w, h: _resolve(args, w, h)  # noqa: E731
    size = _first_size(pairs)
    announced = None
    if size is not None:                           # the first line: what runs, and why
        run = resolve(*size)
        announced = run.description
        print(f"stereojax: method: {run.chosen_line}", flush=True)
    if kernels_line:                               # right after it: the kernels
        print(kernels_line, flush=True)
    for line in (_max_disp_note(args), calib_line):
        if line:
            print(f"stereojax: {line}", flush=True)
    if not batch and args.ray:
        raise ConfigError("--ray runs a batch: give two folders, a KITTI training/ or testing/ folder, a folder of "
                          "Middlebury scenes or a pair list (one pair runs here without --ray)")
    if not batch and args.sequence:
        raise ConfigError("--sequence needs several pairs: two folders, a KITTI folder or a pair list")
    viewer = _viewer(args)                         # a missing rerun-sdk is refused before any work
    if not batch:
        print(pair_line(predict_pair(*pairs[0][1:], out, resolve, phases=Phases(), **opts), out))
        _log_viewer(viewer, args, out, [(None, out)], calib, sequence=False, left_path=pairs[0][1])
        return 0
    unmatched = getattr(pairs, "unmatched", [])
    if unmatched:
        print(f"stereojax predict: {unmatched_line(unmatched)}", file=sys.stderr)
    if args.sequence:
        if args.ray:
            raise ConfigError("--sequence runs its frames in order on one device; it takes no --ray")
        from stereojax.app.sequence_run import predict_sequence
        s = predict_sequence(pairs, out, resolve, opts, fps=args.fps, overwrite=args.overwrite, verify=args.verify,
                             unmatched=unmatched, announced=announced)
    elif args.ray:
        s = predict_batch_ray(pairs, out, resolve, args.ray, workers=args.ray_workers, overwrite=args.overwrite,
                              verify=args.verify, unmatched=unmatched, announced=announced, **opts)
    else:
        s = predict_batch(pairs, out, resolve, devices=devices, overwrite=args.overwrite, verify=args.verify,
                          unmatched=unmatched, announced=announced, **opts)
    print(summary_line(s, out))
    done = [(name, out / name) for name, *_ in pairs if (out / name / "disparity.pfm").is_file()]
    _log_viewer(viewer, args, out, done, calib, sequence=args.sequence)
    return 2 if s["failed"] else 0


def _viewer(args):
    """The Rerun log of --rerun FILE.rrd / --rerun-serve, or None."""
    if not (args.rerun or args.rerun_serve):
        return None
    from stereojax.data.rerun_log import RerunLog, rerun_module

    rerun_module()                     # one line with the install command when rerun-sdk is missing
    if args.rerun and Path(args.rerun).suffix != ".rrd":
        raise ConfigError(f"--rerun takes a file ending in .rrd, got {args.rerun!r}")
    return lambda: RerunLog(args.rerun, args.rerun_serve, name=f"stereojax predict {Path(args.out).name}")


def _log_viewer(viewer, args, out: Path, frames, calib, sequence: bool, left_path=None) -> None:
    """Log the finished frames (name, folder) to Rerun: a sequence on the frame timeline with its
    fallbacks as text events, a batch under each frame's name."""
    if viewer is None:
        return
    from stereojax.data.rerun_log import log_outputs

    log = viewer()
    to_original = args.rectifier.to_original if args.rectifier is not None and args.frame == "original" else None
    try:
        for i, (name, folder) in enumerate(frames):
            events = []
            if sequence:
                rec = json.loads((folder / "timings.json").read_text()).get("sequence", {})
                events = [f"{name}: " + (f"no prior ({rec['fallback']})" if rec.get("fallback")
                                         else "prior from the previous frame")]
            log_outputs(log, folder, name, calib, index=i if sequence else None, events=events,
                        to_original=to_original, left_path=left_path, max_depth=args.max_depth)
    finally:
        log.close()
    if args.rerun:
        print(f"stereojax: Rerun recording of {len(frames)} frame(s) -> {args.rerun} (open with: rerun {args.rerun})")
    if args.rerun_serve:
        print(f"stereojax: Rerun web viewer at http://localhost:9090/?url={log.url} (Ctrl-C ends it)", flush=True)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass


def cmd_evaluate(args) -> int:
    first, after = _kernels_lines(args)
    if first:
        print(first, flush=True)
    out = output_folder(args.out)
    enable()
    items = load_dataset(args.data, args.dataset, frames=parse_frames(args.frames),
                         gt="occ" if args.gt == "both" else args.gt)
    run = _resolve(args, 0, 0, args.dataset)
    print(f"stereojax: method: {run.chosen_line}", flush=True)
    if after:
        print(after, flush=True)
    evaluate_dataset(items, args.dataset, run, out, gt=args.gt, fill=args.fill, max_disp=args.max_disp,
                     sgbm=args.sgbm, devices=local_devices(args.devices), overwrite=args.overwrite,
                     verify=args.verify)
    return 0


def cmd_demo(args) -> int:
    first, after = _kernels_lines(args)
    if first:
        print(first, flush=True)
    out = output_folder(args.out)
    enable()
    sample = load_builtin_sample()
    max_disp = args.max_disp or int(sample.max_disp_hint or 70)
    run_demo(sample, _resolve(args, sample.left.shape[1], sample.left.shape[0], "middlebury", max_disp), out,
             kernels_line=after)
    return 0


def cmd_train(args) -> int:
    # imported here, not at the top: training brings optax and the training loop, which a
    # predict, evaluate or demo process never needs (tests/system/test_speed.py checks it)
    from stereojax.learning.train import (TrainConfig, config_from_options, maybe_initialize_distributed,
                                          net_from_init, train_on_dataset)

    maybe_initialize_distributed()
    out = output_folder(args.out)
    if args.config:
        cfg = TrainConfig.from_file(args.config)
    else:
        cfg = config_from_options(args.preset, args.head or "downsize", args.loss, args.features,
                                  args.widths,
                                  args.distill_weight if args.distill else None, args.augment,
                                  steps=args.steps, seed=args.seed, delta=args.delta, lr=args.lr,
                                  checkpoint_every=args.checkpoint_every)
        if args.init:                  # the network of the model it starts from
            cfg = net_from_init(cfg, args.init, args.features, args.widths, args.head)
    if args.checkpoint_every:          # beside a --config file too
        cfg = dataclasses.replace(cfg, checkpoint_every=args.checkpoint_every).validate()
    summary = train_on_dataset(cfg, args.data, args.dataset, args.frames, args.val_frames, out,
                               resume=args.resume, devices=args.devices, init=args.init, distill=args.distill)
    print(json.dumps(summary, indent=2, default=_json_default))
    return 0


def cmd_tune(args) -> int:
    from stereojax.app.tune import tune
    from stereojax.data.datasets import search_range
    from stereojax.models.registry import check_weights_exist, shipped_name

    if args.weights in ("kitti2015", "kitti2015_compact", "middlebury") or shipped_name(args.weights):
        raise ConfigError(f"{args.weights} is a shipped model with its own searched card; tune a checkpoint of "
                          "your own (e.g. one from stereojax train --init ...)")
    check_weights_exist(args.weights)
    if args.rounds < 1:
        raise ConfigError(f"--rounds must be at least 1, got {args.rounds}")
    gt = "noc" if args.dataset.startswith("kitti") else "occ"
    samples = [load() for _, load in load_dataset(args.data, args.dataset, parse_frames(args.frames), gt=gt)]
    samples = [s for s in samples if s.gt is not None]
    if not samples:
        raise StereoInputError(f"no frame of {args.frames} has ground truth: tune needs frames with ground truth")
    enable()
    threshold = "bad3" if args.dataset.startswith("kitti") else "bad2+bad3"
    print(f"stereojax tune: {Path(args.weights).name} on {len(samples)} frames, space {args.space}, "
          f"{args.rounds} round(s), mean {threshold.replace('+', ' and ')} %", flush=True)
    result = tune(args.weights, samples, lambda s: search_range(args.dataset, s, args.max_disp), args.space,
                  args.rounds, threshold)
    print(f"stereojax tune: {result['start']:.3f} -> {result['best']:.3f} % with "
          f"{result['changes'] or 'no change'} -> {result['card']}")
    return 0


def cmd_calibrate(args) -> int:
    from stereojax.data.stereo_rig import calibrate, parse_board, write_rig_atomic

    out = Path(args.out)
    if out.suffix.lower() not in (".yaml", ".yml", ".xml", ".json"):
        raise ConfigError(f"--out must end in .yaml, .yml, .xml or .json, got {args.out!r}")
    board = parse_board(args.board)
    rig, report = calibrate(args.left, args.right, board, args.square)
    for line in report.warnings:
        warnings.warn(line, InputWarning, stacklevel=1)
    for left, right, why in report.dropped:
        print(f"stereojax calibrate: dropped {left} / {right}: {why}", file=sys.stderr)
    write_rig_atomic(out, rig, {"board": args.board, "square": float(args.square),
                                "pairs_used": len(report.used)})
    unit = "m" if args.square != 1.0 else "squares"
    print(f"stereojax calibrate: {len(report.used)} of {len(report.used) + len(report.dropped)} pairs, RMS "
          f"{rig.rms:.3f} px, baseline {rig.baseline:.4g} {unit}, {rig.size[0]}x{rig.size[1]} -> {out}")
    return 0


def cmd_bench(args) -> int:
    run_bench(Path(args.out), repeats=args.repeats, max_disp=args.max_disp, data=args.data)
    return 0


# ---- entry point -------------------------------------------------------------------------------

def _warning_printer(command: str):
    """Show warnings (e.g. a colour image paired with a grey one) as one line on stderr."""
    def show(message, category, filename, lineno, file=None, line=None):
        print(f"stereojax {command}: warning: {message}", file=sys.stderr)
    return show


COMMANDS = {"predict": cmd_predict, "evaluate": cmd_evaluate, "demo": cmd_demo, "train": cmd_train,
            "bench": cmd_bench, "calibrate": cmd_calibrate, "tune": cmd_tune}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_printer(args.command)
            return COMMANDS[args.command](args)
    except StereoError as exc:
        print(f"stereojax {args.command}: error: {exc}", file=sys.stderr)
        remove_if_empty()              # a run that failed before its first output leaves no folder
        return exc.exit_code
    except Interrupted as exc:
        note = getattr(exc, "note", None)
        if note:
            print(f"stereojax {args.command}: {exc}: {note}", file=sys.stderr)
            return exc.exit_code
        done = exc.summary
        what = f": {done['ok']} of {done['frames']} frames done, summary.json written" if done else ""
        print(f"stereojax {args.command}: {exc}{what}; run the same command to continue", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"stereojax {args.command}: interrupted", file=sys.stderr)
        remove_if_empty()              # an --out folder this run made and left empty goes too
        return 130
    except MemoryError:
        print(f"stereojax {args.command}: error: out of memory; try a smaller --max-disp or image",
              file=sys.stderr)
        return 6


if __name__ == "__main__":
    sys.exit(main())
