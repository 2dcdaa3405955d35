"""Predicting pairs from files: one pair into a folder, or a batch of pairs into
``OUT/<frame>/`` with a progress bar, one line per failed pair and ``summary.json``.

A batch resumes: a frame folder is complete when its ``frame.json`` (written last) lists files
that are all there, and it is reused when that record's method, weights, chain settings,
calibration and input files equal this run's; anything else is computed again (``overwrite``:
everything). A frame is computed into a hidden folder beside its final one and renamed into
place, so a killed batch leaves every frame folder complete or absent.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from stereojax import kernels as kernels_mod
from stereojax.app.integrity import damaged, file_entries
from stereojax.app.outputs import (blank_unconfident, folder_lock, output_folder, pid_alive,
                                   write_confidence, write_prediction, write_rectified)
from stereojax.app.warnlog import recording
from stereojax.data.calibration import plausibility_warnings
from stereojax.data.datasets import load_pair
from stereojax.data.depth import MEASURABLE_DISP, disparity_to_depth
from stereojax.data.io import write_json
from stereojax.data.disp_range import AutoRange, auto_disp_range
from stereojax.data.rectification import check_rectified
from stereojax.devices import current_device, map_frames
from stereojax.errors import InputWarning, StereoError, StereoInputError
from stereojax.inference.compile_cache import bucket_shape
from stereojax.inference.memory import current_rss_bytes, peak_rss_bytes
from stereojax.inference.predictor import Predictor
from stereojax.inference.prepare import check_size
from stereojax.interrupt import Interrupted, stop_on_signals

MANIFEST = "frame.json"
_PARTIAL = ".partial-"


def _file_id(path) -> dict:
    """What identifies an input file's content cheaply: its path, size and modification time."""
    p = Path(path)
    st = p.stat()
    return {"path": str(p.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


_SHA: dict = {}


def _sha256(path) -> str | None:
    if path is None:
        return None
    key = str(Path(path).resolve())
    if key not in _SHA:
        _SHA[key] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return _SHA[key]


def frame_key_of_run(run) -> dict:
    """What of a :class:`stereojax.models.registry.Resolved` a result depends on: the method, the weights
    (by content) and the chain settings."""
    return {"method": run.method, "weights": str(run.weights) if run.weights else None,
            "weights_sha256": _sha256(run.weights), "config": run.config.to_dict()}


def frame_record(run, calib, ply: bool, left_path, right_path, min_confidence: float = 0.0,
                 disp_range=None, max_depth: float | None = None, rectifier=None, frame: str = "rectified") -> dict:
    """What a frame's outputs depend on: :func:`frame_key_of_run`, the calibration, the
    point-cloud option (with its default depth limit, :data:`~stereojax.data.depth.MEASURABLE_DISP`,
    when no ``--max-depth`` replaces it), the confidence threshold, the disparity-range option (None,
    [MIN, MAX] or "auto"), ``--max-depth`` (when given) and the two input files."""
    rng = list(disp_range) if isinstance(disp_range, (tuple, list)) else disp_range
    return {**frame_key_of_run(run),
            "calib": dataclasses.asdict(calib) if calib is not None else None, "ply": bool(ply),
            "min_confidence": float(min_confidence), "disp_range": rng,
            **({"max_depth": float(max_depth)} if max_depth is not None else {}),
            **({"ply_min_disp": MEASURABLE_DISP} if ply and max_depth is None else {}),
            **({"rectification": rectifier.to_json(), "frame": frame} if rectifier is not None else {}),
            "left": _file_id(left_path), "right": _file_id(right_path)}


#: what frame.json holds beside the record of what made the frame
_RESULT_KEYS = ("outputs", "files", "timings", "size", "disp_range_used", "warnings", "kernels")


def frame_problem(target: Path, record: dict, verify: bool = False) -> str | None:
    """None when ``target`` holds a finished frame made with ``record`` whose files pass
    :func:`stereojax.app.integrity.damaged`; else why not ("settings differ", or the damaged file)."""

    try:
        stored = json.loads((target / MANIFEST).read_text())
    except (OSError, ValueError):
        return "no readable frame.json"
    if not isinstance(stored, dict):
        return "no readable frame.json"
    files = stored.get("files")
    for k in _RESULT_KEYS:
        stored.pop(k, None)
    if stored != json.loads(json.dumps(record)):
        return "made with other settings or inputs"
    return damaged(target, files, verify)


def predict_pair(left_path, right_path, target: Path, resolve: Callable, calib=None, ply: bool = False,
                 phases=None, record: bool = False, min_confidence: float = 0.0,
                 check_rectified: str = "warn", tile: str = "auto", disp_range=None,
                 max_depth: float | None = None, sequence=None, rectifier=None, frame: str = "rectified") -> dict:
    """Disparity (and depth with ``calib``) of one pair of image files, written into ``target``,
    with its confidence map (``confidence.png``, ``confidence.npy``); pixels whose confidence
    is below ``min_confidence`` have no disparity and no depth (0 in the PNGs).
    tile: "auto" computes a pair that would not fit the memory limit in horizontal bands
    (:mod:`stereojax.inference.tiling`), "off" refuses it (:class:`~stereojax.errors.MemoryBudgetError`).
    check_rectified: "warn" (an :class:`~stereojax.errors.InputWarning` when the pair does not
    look rectified or looks swapped, :func:`stereojax.data.rectification.check_rectified`), "error"
    (a :class:`~stereojax.errors.StereoInputError` instead) or "off". With ``calib``, a median
    depth outside 0.1-1000 m is warned about (:func:`stereojax.data.calibration.plausibility_warnings`).
    disp_range: None (0 .. max_disp - 1), (MIN, MAX) (MIN <= d < MAX) or "auto" (from the feature
    matches of the rectification check, :func:`stereojax.data.rectification.auto_disp_range`; the
    range used is printed by the CLI and written to ``timings.json`` and ``frame.json``).

    rectifier: a :class:`~stereojax.data.stereo_rig.Rectifier`: the raw pair is rectified first
    (``left_rectified.png``, ``right_rectified.png`` and ``rectification.json`` are written; depth
    is on the rectified grid). frame: "original" rotates points.ply into the raw left camera's frame.

    max_depth: points farther than this (metres) have no depth in depth.npy / depth.png and no
    point in points.ply. When more than :data:`RANGE_SHARE` of the confident pixels sit at an end
    of the disparity range, an :class:`~stereojax.errors.InputWarning` says so with a suggested
    range (:func:`range_warning`). Every warning shown is also kept, in ``timings.json``,
    ``frame.json`` and the result's ``warnings`` (:mod:`stereojax.app.warnlog`).

    resolve(width, height) -> :class:`stereojax.models.registry.Resolved` says what runs for this input.
    record: also write ``frame.json`` (what the frame was made with, and its files) last.
    Returns ``{"disparity", "confidence", "timings", "written", "run", "warnings"}``; ``timings``
    as :meth:`stereojax.inference.predictor.Predictor.timed`."""

    try:
        with recording() as warned:
            return _predict_pair(left_path, right_path, target, resolve, calib, ply, phases, record, min_confidence,
                                 check_rectified, tile, disp_range, max_depth, warned, sequence, rectifier, frame)
    except Exception as exc:
        if not _caused_by_interrupt(exc):
            raise
        _interrupted(phases)
        raise KeyboardInterrupt from exc
    except KeyboardInterrupt:      # Ctrl-C on a single pair (a batch turns signals into Interrupted)
        _interrupted(phases)
        raise


def _caused_by_interrupt(exc: BaseException) -> bool:
    """Whether a Ctrl-C is behind ``exc``: a KeyboardInterrupt raised inside a C callback (numpy's
    dtype lookup while JAX traces, measured) comes out as a SystemError caused by it."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _interrupted(phases) -> None:
    if phases is not None and hasattr(phases, "interrupted"):
        phases.interrupted()   # the message that follows starts on its own line
    from stereojax.app.outputs import remove_if_empty
    remove_if_empty()          # an --out folder this run made and left empty goes


def _predict_pair(left_path, right_path, target, resolve, calib, ply, phases, record, min_confidence,
                  check_rectified, tile, disp_range, max_depth, warned, sequence=None, rectifier=None,
                  frame="rectified") -> dict:

    sample = load_pair(left_path, right_path)
    if rectifier is not None:       # a raw pair: rectified before anything else looks at it
        sample = dataclasses.replace(sample, **dict(zip(("left", "right"), rectifier.rectify(sample.left,
                                                                                           sample.right))))
    if disp_range != "auto":     # an unusable pair is refused in one line before anything else runs
        h, w = np.shape(sample.left)[:2]
        early = resolve(w, h).config
        if disp_range is not None:
            early = early.with_max_disp(disp_range[1] - disp_range[0])
        check_size(h, w, early)
    low = disp_range[0] if isinstance(disp_range, tuple | list) else 0
    check = _check_rectified(sample, check_rectified, need=disp_range == "auto", min_disp=low,
                             rectified=rectifier is not None)
    found = _disp_range(disp_range, check, sample)
    used = found.range if isinstance(found, AutoRange) else found
    if isinstance(found, AutoRange) and phases is not None and not getattr(phases, "quiet", False):
        print(f"disparity range auto: {found.describe()}", file=sys.stderr)
    run = resolve(sample.left.shape[1], sample.left.shape[0])
    cfg = run.config
    if sequence is not None:        # a stream: the previous frame's disparity is this one's prior
        (disp, conf), timings = _sequence_frame(sequence, run, sample)
    else:
        predictor = Predictor(cfg, run.model(), current_device(), confidence=True, tile=tile, disp_range=used,
                              cascade=run.cascade_arg())
        cfg = predictor.config
        (disp, conf), timings = predictor.timed(sample.left, sample.right, phases)
    if used is not None:
        timings = {**timings, "disp_range": list(used)}
    lo, hi = used if used is not None else (0, cfg.max_disp)
    _warn_range(disp, conf, lo, hi, sample, check, pinned_low=used is not None)
    disp = blank_unconfident(disp, conf, min_confidence)
    target.mkdir(parents=True, exist_ok=True)
    written = write_prediction(target, "", disp, calib, sample.left, ply=ply, max_depth=max_depth,
                               confidence=conf,
                               to_original=rectifier.to_original if rectifier is not None and frame == "original"
                               else None) \
        + write_confidence(target, "", conf)
    if rectifier is not None:
        written += write_rectified(target, rectifier, sample.left, sample.right, frame)
    if calib is not None:
        _check_depth(disp, calib)
    timings = {**timings, "warnings": list(warned)}
    ran = kernels_mod.record(cfg.kernels)           # which kernels ran in this process, and why
    write_json(target / "config.json", cfg.to_dict())
    write_json(target / "timings.json", {**timings, "height": disp.shape[0], "width": disp.shape[1],
                                         "max_disp": cfg.max_disp, "method": cfg.cost.method,
                                         "chosen": run.description, "kernels": ran})
    written += ["config.json", "timings.json"]
    if record:
        write_json(target / MANIFEST, {**frame_record(run, calib, ply, left_path, right_path, min_confidence,
                                                      disp_range, max_depth, rectifier, frame),
                                       "disp_range_used": None if used is None else list(used),
                                       "size": list(disp.shape), "outputs": written,
                                       "files": file_entries(target, written), "timings": timings,
                                       "warnings": list(warned), "kernels": ran})
    return {"disparity": disp, "confidence": conf, "timings": timings, "written": written, "run": run,
            "warnings": list(warned)}


def _sequence_frame(holder, run, sample):
    """((disparity, confidence), timings) of one frame of a stream
    (:class:`stereojax.app.sequence_run.SequenceHolder`); ``timings["sequence"]``: its record."""
    frame, compile_s = holder.push(run, sample)
    record = dict(frame.record)
    seconds = record.pop("seconds")
    h, w = frame.disparity.shape
    return (frame.disparity, frame.confidence), {"seconds": seconds, "compile_s": compile_s,
                                                 "bucket": list(bucket_shape(h, w)), "device": str(current_device()),
                                                 "sequence": record}


def _check_rectified(sample, mode: str, need: bool = False, min_disp: int = 0, rectified: bool = False):
    """The rectification check of a pair (None when off and not ``need``ed for an auto range);
    ``min_disp``: the range's lowest disparity (a negative one allows matches to the right);
    ``rectified``: the pair was rectified with ``--calib --rectify`` (a problem then blames the
    calibration)."""
    if mode == "off" and not need:
        return None
    check = check_rectified(sample.left, sample.right, min_disp=min_disp)
    if check.skipped and mode != "off":
        warnings.warn(check.skipped, InputWarning, stacklevel=3)
    problem = check.problem if mode != "off" else None
    if problem and rectified and "rectified" in problem:
        problem = (f"the calibration does not rectify these images: after --rectify, matched features still lie up "
                   f"to {check.row_offset_p90:.1f} px apart vertically (90th percentile of {check.matches} matches; "
                   f"median {check.row_offset_median:+.1f} px); was it made for this rig, and have the cameras moved?")
    if problem and mode == "error":
        raise StereoInputError(problem)
    if problem:
        warnings.warn(problem, InputWarning, stacklevel=3)
    return check


def _disp_range(option, check, sample):
    """The (MIN, MAX) a pair runs with: the option's, or for "auto" the
    :class:`~stereojax.data.disp_range.AutoRange` the pair shows."""
    if option != "auto":
        return option
    found = auto_disp_range(sample.left, sample.right, check)
    if found is None:
        raise StereoInputError(f"--disp-range auto could not tell the disparity range ({check.matches} feature "
                               "matches, too few pixels matched densely); give --disp-range MIN MAX or --max-disp")
    return found


#: warn when more than this share of the confident pixels sit at an end of the disparity range
RANGE_SHARE = 0.01
#: "confident": confidence at least this (:func:`stereojax.validation.confidence_measure.confidence`)
RANGE_CONFIDENCE = 0.5


def range_warning(disp, conf, lo: int, hi: int, width: int, pinned_low: bool = False,
                  matches: tuple[int, int] | None = None) -> str | None:
    """One line when more than :data:`RANGE_SHARE` of the confident pixels (confidence >=
    :data:`RANGE_CONFIDENCE`) sit within 1.5 px of the top of the searched range MIN <= d < MAX (or,
    with ``pinned_low``, of its bottom): the scene likely reaches beyond it and those pixels are
    pinned at the limit. The line gives the share and a wider range to try: the pair's automatic range
    (``matches``, :func:`stereojax.data.disp_range.auto_disp_range`)
    where it reaches beyond the limit, else twice the range; None when the range holds the scene."""
    d, c = np.asarray(disp), np.asarray(conf)
    sure = np.isfinite(d) & (c >= RANGE_CONFIDENCE)
    n = int(sure.sum())
    if n == 0:
        return None
    top = float(np.mean(d[sure] >= hi - 1.5))
    low = float(np.mean(d[sure] <= lo + 0.5)) if pinned_low else 0.0
    if max(top, low) <= RANGE_SHARE:
        return None
    span = hi - lo
    if top >= low:
        seen = matches is not None and matches[1] > hi
        new_hi = min(matches[1] if seen else lo + 2 * span, width - 1)
        new_hi = -(-new_hi // 16) * 16 if new_hi + 15 < width else new_hi
        suggest = f"--max-disp {new_hi}" if lo == 0 else f"--disp-range {lo} {new_hi}"
        why = f" (the pair's --disp-range auto reaches d = {matches[1] - 1})" if seen else ""
        return (f"{100 * top:.1f} % of the confident pixels sit at the top of the disparity range (d >= {hi - 1} "
                f"of {lo} <= d < {hi}): the scene likely reaches further; try {suggest}{why} or --disp-range auto")
    seen = matches is not None and matches[0] < lo
    new_lo = max(matches[0] if seen else lo - span // 2, -(width - 2))
    why = f" (the pair's --disp-range auto reaches d = {matches[0]})" if seen else ""
    return (f"{100 * low:.1f} % of the confident pixels sit at the bottom of the disparity range (d <= {lo} of "
            f"{lo} <= d < {hi}): try --disp-range {new_lo} {hi}{why} or --disp-range auto")


def _warn_range(disp, conf, lo, hi, sample, check, pinned_low=False) -> None:
    """Warn when the range pins the scene (:func:`range_warning`), with the range the pair's
    auto range shows (:func:`stereojax.data.disp_range.auto_disp_range`; the rectification check
    is made now if it was off)."""
    width = disp.shape[1]
    if range_warning(disp, conf, lo, hi, width, pinned_low) is None:
        return
    if check is None:
        check = check_rectified(sample.left, sample.right, min_disp=lo)
    found = auto_disp_range(sample.left, sample.right, check)
    line = range_warning(disp, conf, lo, hi, width, pinned_low, None if found is None else found.range)
    warnings.warn(line, InputWarning, stacklevel=3)


def _check_depth(disp, calib) -> None:


    z = disparity_to_depth(disp, calib.baseline, calib.focal, calib.doffs)
    for line in plausibility_warnings(depth=z):
        warnings.warn(line, InputWarning, stacklevel=3)


def _predict_into_place(pair, out: Path, resolve, opts: dict) -> dict:
    """:func:`predict_pair` into a hidden folder, renamed to ``out/<name>`` once complete."""
    name, left_p, right_p = pair
    final = out / name
    staging = out / f".{name}{_PARTIAL}{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        result = predict_pair(left_p, right_p, staging, resolve, record=True, **opts)
        if final.exists():
            old = out / f".{name}.old-{os.getpid()}"
            final.rename(old)
            staging.rename(final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            staging.rename(final)
        return result
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _reusable(pair, out: Path, resolve, opts: dict, verify: bool = False) -> tuple[bool, str | None]:
    """(whether ``out/<name>`` is complete and made with what this run would use, why a frame
    that was recorded as finished is not: a damaged or missing file). The images are not read:
    when both input files are the ones recorded, their size is the recorded one."""
    name, left_p, right_p = pair
    try:
        stored = json.loads((out / name / MANIFEST).read_text())
        if stored.get("left") != _file_id(left_p) or stored.get("right") != _file_id(right_p):
            return False, None
        height, width = stored["size"]
        record = frame_record(resolve(width, height), opts["calib"], opts["ply"], left_p, right_p,
                              opts["min_confidence"], opts.get("disp_range"), opts.get("max_depth"),
                              opts.get("rectifier"), opts.get("frame", "rectified"))
        problem = frame_problem(out / name, record, verify)
        if problem is None:
            return True, None
        return False, None if problem == "made with other settings or inputs" else problem
    except (StereoError, OSError, ValueError, KeyError, TypeError):
        return False, None


def predict_batch(pairs, out: Path, resolve: Callable, calib=None, ply: bool = False,
                  devices: list | None = None, overwrite: bool = False, min_confidence: float = 0.0,
                  check_rectified: str = "warn", tile: str = "auto", disp_range=None, verify: bool = False,
                  unmatched=None, max_depth: float | None = None, announced: str | None = None,
                  rectifier=None, frame: str = "rectified") -> dict:
    """Every ``(name, left, right)`` pair into ``out/<name>/``: frames already complete with
    this run's settings are skipped (all computed with ``overwrite``), one compiled chain per
    size bucket, a progress bar with frames/s and the time left, one line per failed pair (the
    batch goes on), and ``out/summary.json``, which is also returned.

    A frame recorded as complete is kept only when each of its files has its recorded size
    (``verify``: and its recorded SHA-256); one that fails is computed again and named in one
    line and in ``summary.json``'s ``damaged``. ``unmatched``: input names that had no partner
    (:func:`stereojax.data.pairs.find_pairs`), reported in summary.json. ``announced``: the
    method line the caller printed already (a frame that runs another method prints its own).

    The batch holds ``out``'s lock (:func:`stereojax.app.outputs.folder_lock`): a second batch on
    the same folder is refused with :class:`~stereojax.errors.OutputBusyError` (exit code 8).

    On SIGINT or SIGTERM the frame in progress is finished or left absent, summary.json is
    written with what was done, and :class:`stereojax.interrupt.Interrupted` is raised."""

    with folder_lock(output_folder(out), "predict"):
        return predict_batch_locked(pairs, out, resolve, dict(
            calib=calib, ply=ply, min_confidence=min_confidence, check_rectified=check_rectified, tile=tile,
            disp_range=disp_range, max_depth=max_depth, rectifier=rectifier, frame=frame), devices, overwrite,
            verify, unmatched, announced)


def remove_stale(out: Path, every: bool = False) -> None:
    """Remove the staging folders (``.<frame>.partial-PID``, ``.<frame>.old-PID``) that a killed run
    left; never one of a process that is still alive (``every``: all of them, when the caller
    knows that no process of its batch writes any more)."""

    for stale in [*out.glob(f".*{_PARTIAL}*"), *out.glob(".*.old-*")]:
        pid = stale.name.rsplit("-", 1)[-1]
        if not every and pid.isdigit() and int(pid) != os.getpid() and pid_alive(int(pid)):
            continue
        shutil.rmtree(stale, ignore_errors=True)


def frame_work(pair, out: Path, resolve: Callable, opts: dict):
    """One frame of a batch into ``out/<name>/`` (:func:`_predict_into_place`): (pair, what the
    summary needs of it, None) or (pair, None, the error's one line). What it returns is small
    and picklable, so that a Ray worker can run it (:mod:`stereojax.app.ray_batch`)."""
    try:
        r = _predict_into_place(pair, out, resolve, opts)
    except (StereoError, OSError) as exc:
        return pair, None, str(exc)

    return pair, {"timings": r["timings"], "shape": list(np.shape(r["disparity"])), "run": r["run"],
                  "warnings": r["warnings"], "rss_mb": current_rss_bytes() / 2 ** 20}, None


def _complete_frames(pairs, out: Path, resolve: Callable, opts: dict, verify: bool) -> tuple[list, list]:
    """The frames an earlier run completed (their names), and those recorded as complete whose
    files fail the check (``{"frame", "problem"}``)."""
    skipped, damaged = [], []
    for p in pairs:
        ok, problem = _reusable(p, out, resolve, opts, verify)
        if ok:
            skipped.append(p[0])
        elif problem:
            damaged.append({"frame": p[0], "problem": problem})
    return skipped, damaged


def _batch_summary(pairs, rows, skipped, failed, damaged, interrupted, wall: float, workers, unmatched) -> dict:
    """What ``summary.json`` holds after a batch (see :func:`predict_batch`)."""
    compute = sum(r["seconds"] for r in rows)
    n_dev = max(workers or 1, 1)
    return {"frames": len(pairs), "ok": len(rows) + len(skipped), "computed": len(rows),
            "skipped": len(skipped), "failed": failed,
            "not_done": len(pairs) - len(rows) - len(skipped) - len(failed),
            "interrupted": interrupted.signal_name if interrupted else None,
            "devices": n_dev, "wall_s": wall,
            "frames_per_s": len(rows) / wall if wall > 0 else 0.0,
            "frames_per_s_warm": len(rows) * n_dev / compute if compute > 0 else 0.0,
            "compile_s": sum(r["compile_s"] for r in rows), "peak_rss_mb": peak_rss_bytes() / 2 ** 20,
            "warnings": sum(len(r["warnings"]) for r in rows),
            "frames_with_warnings": [r["frame"] for r in rows if r["warnings"]],
            "per_frame": rows, "skipped_frames": skipped, "damaged": damaged,
            "unmatched": list(unmatched or [])}


def kept_row(out: Path, name: str) -> dict:
    """``summary.json``'s row of a frame an earlier run completed, read back from its
    ``frame.json`` (the seconds, size, device, warnings and sequence record of the run that made
    it; no ``rss_mb``), with ``"kept": true``."""
    try:
        stored = json.loads((out / name / MANIFEST).read_text())
        timings = stored.get("timings") or {}
        height, width = stored["size"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {"frame": name, "kept": True}
    return {"frame": name, "seconds": timings.get("seconds"), "compile_s": timings.get("compile_s"),
            "device": timings.get("device"), "bucket": timings.get("bucket"), "width": int(width),
            "height": int(height), "rss_mb": None, "warnings": list(stored.get("warnings") or []),
            **({"sequence": timings["sequence"]} if "sequence" in timings else {}), "kept": True}


def predict_batch_locked(pairs, out: Path, resolve: Callable, opts: dict, devices, overwrite: bool,
                          verify: bool, unmatched, announced, mapper=None, workers: int | None = None,
                          where: str | None = None, keep_skipped: bool = False) -> dict:
    """The batch, with the output folder's lock held. ``mapper(todo)`` yields :func:`frame_work`'s
    triples (default: the local devices, :func:`stereojax.devices.map_frames`); ``workers``: how
    many frames run at once (for frames/s); ``where``: a line that says where they run.
    ``keep_skipped``: ``summary.json``'s ``per_frame`` lists the frames kept from an earlier run
    too, in the pairs' order (:func:`kept_row`; a sequence's every frame), not only the computed
    ones; the counts and speeds are the computed frames' either way."""


    devices = list(devices or [])
    if mapper is None:
        def mapper(items):
            return map_frames(lambda pair: frame_work(pair, out, resolve, opts), items, devices)
        workers = max(len(devices), 1)
        where = f"{len(devices)} devices, one frame each at a time" if len(devices) > 1 else None
    remove_stale(out)
    skipped, damaged = ([], []) if overwrite else _complete_frames(pairs, out, resolve, opts, verify)
    done = set(skipped)
    todo = [p for p in pairs if p[0] not in done]
    rows, failed, described, interrupted = [], [], {announced} - {None}, None
    t_start = time.perf_counter()
    with tqdm(total=len(pairs), initial=len(skipped), desc="predict", unit="frame", file=sys.stderr,
              dynamic_ncols=True) as bar:
        if skipped:
            checked = "sizes and SHA-256 checked" if verify else "file sizes checked; --verify reads the digests"
            tqdm.write(f"stereojax predict: {len(skipped)} of {len(pairs)} frames already complete in {out} "
                       f"(skipped, {checked}; --overwrite computes them again)", file=sys.stderr)
        for d in damaged:
            tqdm.write(f"stereojax predict: {d['frame']}: recorded as complete but {d['problem']}; computing "
                       "it again", file=sys.stderr)
        if where:
            tqdm.write(f"stereojax predict: {where}", file=sys.stderr)
        try:
            with stop_on_signals():
                for (name, left_p, right_p), result, error in mapper(todo):
                    bar.update(1)
                    if error is not None:
                        failed.append({"frame": name, "left": str(left_p), "right": str(right_p), "error": error})
                        tqdm.write(f"stereojax predict: error: {name}: {error}", file=sys.stderr)
                        continue
                    timings, run = result["timings"], result["run"]
                    if run.description not in described:
                        described.add(run.description)
                        tqdm.write(f"stereojax predict: {name}: method: {run.chosen_line}", file=sys.stderr)
                    rows.append({"frame": name, "seconds": timings["seconds"], "compile_s": timings["compile_s"],
                                 "device": timings["device"], "bucket": timings["bucket"],
                                 "width": int(result["shape"][1]), "height": int(result["shape"][0]),
                                 "rss_mb": result["rss_mb"], "warnings": result["warnings"],
                                 **({"sequence": timings["sequence"]} if "sequence" in timings else {})})
                    bar.set_postfix(bucket=f"{timings['bucket'][1]}x{timings['bucket'][0]}")
        except Interrupted as stop:
            interrupted = stop
    summary = _batch_summary(pairs, rows, skipped, failed, damaged, interrupted, time.perf_counter() - t_start,
                             workers, unmatched)
    if keep_skipped and skipped:
        order = {p[0]: i for i, p in enumerate(pairs)}
        every = rows + [kept_row(out, name) for name in skipped]
        summary["per_frame"] = sorted(every, key=lambda r: order.get(r["frame"], len(order)))
    write_json(out / "summary.json", summary)
    if interrupted:
        interrupted.summary = summary
        raise interrupted
    return summary


def pair_line(r: dict, out: Path) -> str:
    """The line ``stereojax predict`` prints after one pair (:func:`predict_pair`'s result)."""
    disp, timings = r["disparity"], r["timings"]
    rng = timings.get("disp_range")
    span = f", disparities {rng[0]} <= d < {rng[1]}" if rng else ""
    return (f"disparity {disp.shape[1]}x{disp.shape[0]} ({r['run'].description}{span}), {timings['seconds']:.2f} s "
            f"(+ {timings['compile_s']:.1f} s compiling) -> {out} ({', '.join(r['written'])})")


def summary_line(s: dict, out: Path) -> str:
    """The line ``stereojax predict`` prints after a batch."""
    failed = s["failed"]
    return (f"{s['ok']} of {s['frames']} pairs ({s['computed']} computed, {s['skipped']} already complete) "
            f"-> {out}/<frame>/ in {s['wall_s']:.1f} s "
            f"({s['frames_per_s']:.2f} frames/s overall, {s['frames_per_s_warm']:.2f} frames/s "
            f"after {s['compile_s']:.1f} s compiling), peak RSS {s['peak_rss_mb'] / 1024:.2f} GiB; "
            f"summary.json" + (f"; {len(failed)} failed: " + ", ".join(f["frame"] for f in failed[:10])
                               if failed else "")
            + (f"; {s['warnings']} warning(s) in {len(s['frames_with_warnings'])} frame(s) (summary.json, "
               "frame.json)" if s.get("warnings") else "")
            + (f"; {len(s['damaged'])} damaged frame(s) computed again" if s.get("damaged") else "")
            + (f"; {len(s['unmatched'])} image(s) without a partner" if s.get("unmatched") else ""))
