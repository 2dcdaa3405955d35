"""Scoring methods on frames with ground truth: the one evaluation loop of stereojax.

``stereojax evaluate``, the experiments and the model selection all call
:func:`evaluate_frames`; a *method* is a function ``predict(sample, max_disp)`` that returns the
disparity, ``(disparity, est_valid)``, or ``(disparity, info)`` with ``info`` a dict of timings
(``seconds``, ``compile_s``, ...) and optionally ``est_valid``::

    result = evaluate_frames(samples, {"best": chain_method(config, model), "sgbm": sgbm_method()},
                             max_disp=228)
    result["mean"]["best"]["bad3"], result["frames"][0]["sgbm"]["d1"]
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import numpy as np
from tqdm import tqdm

from stereojax import kernels as kernels_mod, metrics
from stereojax.app.baselines import sgbm_disparity
from stereojax.app.batch import frame_key_of_run
from stereojax.app.integrity import damaged, file_entries
from stereojax.app.outputs import color_scale, folder_lock, output_folder, write_prediction
from stereojax.data import io
from stereojax.data.datasets import NOC_SOURCE, search_range
from stereojax.devices import current_device, map_frames
from stereojax.errors import StereoInputError
from stereojax.inference.predictor import Predictor
from stereojax.interrupt import stop_on_signals

COLUMNS = ["bad2", "bad3", "bad4", "bad5", "d1", "epe", "density", "seconds_warm"]
LABELS = {"pipeline": "stereojax pipeline", "sgbm": "OpenCV SGBM, left-padded",
          "sgbm_unpadded": "OpenCV SGBM, unpadded"}
#: the regions a frame can be scored on (``regions`` of :func:`evaluate_frames`)
REGIONS = {"noc": "non-occluded", "all": "all pixels"}


def region_key(method: str, region: str) -> str:
    """The row key of a method scored on one region, e.g. "pipeline (all)"."""
    return f"{method} ({region})"


def _masks(sample, regions) -> dict | None:
    """region -> ground-truth mask of the sample (None: a region's ground truth is missing)."""
    if regions is None:
        return {None: sample.gt_valid}
    masks = {"noc": sample.gt_noc_valid, "all": sample.gt_valid}
    out = {r: masks[r] for r in regions}
    return None if any(m is None for m in out.values()) else out


def chain_method(config, model=None, phases=None, cascade=None) -> Callable:
    """The stereojax chain ``config`` (its max_disp replaced per frame) as a method: runs through
    :class:`stereojax.inference.predictor.Predictor` on the calling :func:`~stereojax.devices.map_frames`
    worker's device, compilation timed apart (``compile_s``); ``cascade``: a
    :class:`~stereojax.matching_cost.cascade.Cascade` with ``model`` as its student."""

    def predict(sample, max_disp):
        predictor = Predictor(config.with_max_disp(max_disp), model, current_device(), cascade=cascade)
        return predictor.timed(sample.left, sample.right, phases)
    return predict


def sgbm_method(pad: bool = True) -> Callable:
    """OpenCV StereoSGBM (:func:`stereojax.app.baselines.sgbm_disparity`) as a method; ``pad``: the
    left image padded by max_disp so that the left border strip gets estimates."""

    def predict(sample, max_disp):
        t0 = time.perf_counter()
        disp, valid = sgbm_disparity(sample.left, sample.right, num_disp=max_disp, pad=pad)
        return disp, {"est_valid": valid, "seconds": time.perf_counter() - t0, "compile_s": 0.0}
    return predict


def _split(out) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """(disparity, est_valid, info) of what a method returned."""
    if not isinstance(out, tuple):
        return out, None, {}
    disp, extra = out
    if isinstance(extra, Mapping):
        info = dict(extra)
        return disp, info.pop("est_valid", None), info
    return disp, extra, {}


def _load(item):
    """(frame id, sample) of a sample or a ``(frame_id, load)`` pair (load() -> sample)."""
    if isinstance(item, tuple):
        frame_id, load = item
        return frame_id, load()
    return item.name, item


def evaluate_frames(frames: Iterable, methods: Mapping[str, Callable], max_disp, *,
                    fill: str = "interpolate", devices: list | None = None, on_frame=None,
                    progress: str | None = None, total: int | None = None, reuse=None,
                    regions: tuple | None = None) -> dict:
    """Run every method on every frame and score it with :func:`stereojax.metrics.evaluate`.

    frames: samples (``.name``, ``.left``, ``.right``, ``.gt``, ``.gt_valid``) or ``(frame_id,
    load)`` pairs that load one when its turn comes. methods: name -> ``predict(sample,
    max_disp)``. max_disp: an int or ``max_disp(sample) -> int``. fill: pixels without estimate
    (see :func:`~stereojax.metrics.evaluate`). devices: spread the frames over these devices
    (:func:`~stereojax.devices.map_frames`). on_frame(row, sample, disparities): called in order
    after each scored frame (e.g. to write its outputs). progress: a tqdm bar with this title on
    stderr (None: no bar, with the frames/s and the time left). reuse(frame_id) -> a row of an
    earlier run, or None: a frame with a row is neither loaded nor computed, and its row is
    taken as it is (on_frame is not called for it). regions: None scores each frame on its
    ``gt_valid``; ("noc", "all") scores the non-occluded (``gt_noc_valid``) and all ground-truth
    pixels (``gt_valid``) apart, under the keys ``region_key(method, region)``, e.g.
    "pipeline (noc)"; a frame without either is listed in ``missing_gt``.

    Returns ``{"frames": [row], "mean": {method: means}, "missing_gt": [frame ids]}`` where a row
    is ``{"frame", "max_disp", method: {metrics..., "seconds", "warm", timings...}}``. A frame's
    ``seconds`` are warm when the method timed compilation apart (``compile_s``) or when it ran
    a frame of the same size and range before; ``mean[method]["seconds_warm"]`` is the mean over
    warm frames (NaN if none). Frames without ground truth are listed in ``missing_gt``, frames
    whose row came from ``reuse`` in ``reused``.
    """

    seen: dict[str, set] = {name: set() for name in methods}

    def work(item):
        frame_id = item[0] if isinstance(item, tuple) else item.name
        earlier = reuse(frame_id) if reuse is not None else None
        if earlier is not None:
            return frame_id, None, earlier, None
        frame_id, sample = _load(item)
        if sample.gt is None or _masks(sample, regions) is None:
            return frame_id, sample, None, None
        md = max_disp(sample) if callable(max_disp) else int(max_disp)
        outputs = {}
        for name, predict in methods.items():
            t0 = time.perf_counter()
            out = predict(sample, md)
            outputs[name] = (out, time.perf_counter() - t0)
        return frame_id, sample, md, outputs

    bar = None
    if progress is not None:
        bar = tqdm(total=total if total is not None else _length(frames), desc=progress, unit="frame",
                   file=sys.stderr, dynamic_ncols=True)
    keys = list(methods) if regions is None else [region_key(m, r) for m in methods for r in regions]
    rows, missing, reused, first = [], [], [], keys[0]
    try:
        for frame_id, sample, md, outputs in map_frames(work, frames, devices):
            if bar is not None:
                bar.update(1)
            if sample is None:                   # an earlier run's row (md holds it)
                rows.append(md)
                reused.append(frame_id)
                continue
            if outputs is None:
                missing.append(frame_id)
                continue
            row, disparities = {"frame": frame_id, "max_disp": md}, {}
            for name, (out, secs) in outputs.items():
                disp, est_valid, info = _split(out)
                key = (sample.left.shape, md)
                warm = "compile_s" in info or key in seen[name]
                seen[name].add(key)
                timing = {"seconds": info.pop("seconds", secs), "warm": warm, **info}
                for region, mask in _masks(sample, regions).items():
                    scores = metrics.evaluate(disp, sample.gt, mask, est_valid=est_valid, fill=fill)
                    row[name if region is None else region_key(name, region)] = {**scores, **timing}
                disparities[name] = disp
            rows.append(row)
            if on_frame is not None:
                on_frame(row, sample, disparities)
            if bar is not None:
                bar.set_postfix(bad3=f"{row[first]['bad3']:.2f}%")
    finally:
        if bar is not None:
            bar.close()
    return {"frames": rows, "mean": mean_rows(rows, keys) if rows else {}, "missing_gt": missing,
            "reused": reused}


def _length(frames):
    try:
        return len(frames)
    except TypeError:
        return None


def mean_rows(rows: list[dict], methods: list[str]) -> dict:
    """Per method, the mean of every measure over frames (:func:`~stereojax.metrics.mean_metrics`)
    and ``seconds_warm``, the mean seconds of the warm frames (NaN if none)."""
    mean = {}
    for m in methods:
        mean[m] = metrics.mean_metrics([r[m] for r in rows])
        warm = [r[m]["seconds"] for r in rows if r[m].get("warm", True)]
        mean[m]["seconds_warm"] = float(np.mean(warm)) if warm else float("nan")
    return mean


def _label(key: str, labels: Mapping[str, str]) -> str:
    """Table label of a row key: "pipeline" or "pipeline (all)" -> "stereojax pipeline, all pixels"."""
    for region, text in REGIONS.items():
        suffix = f" ({region})"
        if key.endswith(suffix):
            base = key[:-len(suffix)]
            return f"{labels.get(base, base)}, {text}"
    return labels.get(key, key)


def format_table(mean: Mapping[str, Mapping], pipeline: str | None = None) -> str:
    """The means of :func:`evaluate_frames` as a markdown table, one row per method; ``pipeline``
    names the chain's row (e.g. "stereojax kitti2015", :attr:`Resolved.label`)."""
    labels = {**LABELS, **({"pipeline": pipeline} if pipeline else {})}
    head = ("| method | >2 px % | >3 px % | >4 px % | >5 px % | D1 % | EPE px | density % "
            "| s/frame (warm) |")
    lines = [head, "|" + "---|" * (len(COLUMNS) + 1)]
    for name, m in mean.items():
        cells = ["n/a" if np.isnan(m[c]) else f"{m[c]:.2f}" for c in COLUMNS]
        lines.append(f"| {_label(name, labels)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def gt_line(dataset: str, gt_of: Mapping[str, str | None] | None) -> str | None:
    """``--gt auto``: the line that says which ground truth is scored, and why, from ``gt_of``
    (frame id -> "noc", "occ" or None, :func:`stereojax.data.datasets.ground_truth_of`); None when
    no frame has ground truth (the run then fails, saying so)."""
    if gt_of is None:
        return "ground truth: non-occluded pixels where a frame has them, else all pixels (--gt auto)"
    noc = [f for f, g in gt_of.items() if g == "noc"]
    occ = [f for f, g in gt_of.items() if g == "occ"]
    source = NOC_SOURCE.get(dataset, "a non-occlusion mask")
    if not noc and not occ:
        return None
    if not occ:
        return (f"ground truth: non-occluded pixels, which every frame with ground truth has ({source}); "
                "--gt occ scores all pixels, --gt both each apart")
    if not noc:
        return f"ground truth: all pixels, since no frame has non-occluded ground truth ({source})"
    names = ", ".join(occ[:5]) + (" ..." if len(occ) > 5 else "")
    return (f"ground truth: non-occluded pixels on {len(noc)} frame(s), all pixels on the {len(occ)} without "
            f"non-occluded ground truth ({source}): {names}; --gt noc skips those, --gt occ scores all "
            "pixels everywhere")


#: what to try when a frame lacks the ground truth asked for (the end of the missing-GT line)
_GT_HINT = {"noc": "--gt occ scores all pixels (the non-occluded ones need {source})",
            "occ": "--gt noc scores the non-occluded pixels",
            "both": "--gt noc or --gt occ scores the one there is"}


def _gt_text(gt: str, rows: list[dict]) -> str:
    """The ground truth of a results.md title: "noc GT", or under auto what the frames got."""
    if gt != "auto":
        return f"{gt} GT"
    occ = [r["frame"] for r in rows if r.get("gt") == "occ"]
    if not occ:
        return "noc GT"
    if len(occ) == len(rows):
        return "occ GT (all pixels)"
    return f"noc GT (all pixels on {', '.join(occ[:5])}{' ...' if len(occ) > 5 else ''})"


def evaluate_dataset(items, dataset: str, run, out, *, gt: str = "noc", fill: str = "interpolate",
                     max_disp: int | None = None, sgbm: bool = False, devices: list | None = None,
                     overwrite: bool = False, verify: bool = False) -> dict:
    """``stereojax evaluate``: the chain of ``run`` (:class:`stereojax.models.registry.Resolved`), and
    OpenCV SGBM left-padded and unpadded with ``sgbm``, on the ``(frame_id, load)`` items of a
    dataset (:func:`stereojax.data.datasets.load_dataset`).

    Writes ``OUT/<frame>_disparity*.png``, ``<frame>_error.png`` and ``OUT/frames/<frame>.json``
    (the frame's scores and what made them) after each frame, then ``results.json`` and
    ``results.md``; prints the table. A frame whose record matches this run (dataset, ground
    truth, fill, method, weights, chain settings, SGBM) is taken from its record instead of
    computed again (``overwrite``: every frame is computed) when each of its files has its
    recorded size (``verify``: and SHA-256; a damaged frame is named and scored again), so an
    interrupted evaluation
    continues where it stopped and its mean is that of an uninterrupted one. ``gt``: "noc",
    "occ", "both" (each scored apart) or "auto": each frame scored on the ground truth its
    loader gave (``load_dataset(..., gt="auto")``: non-occluded where the data has it, else all
    pixels), said in one line first (:func:`gt_line`, from the items' ``gt_of``) and recorded
    in each row's ``gt``. Frames without
    ``gt`` ground truth are skipped with a warning (:class:`StereoInputError` when none has
    it; both name the ``--gt`` that would score them). Nothing is written before the first frame
    is scored, so a run that fails before it leaves the folder as it found it. SIGINT/SIGTERM
    raise :class:`stereojax.interrupt.Interrupted` after the records of the finished frames are
    written. Returns what results.json holds."""


    out = Path(out)
    if gt == "auto":
        line = gt_line(dataset, getattr(items, "gt_of", None))
        if line:
            print(f"stereojax: {line}", flush=True)
    if devices and len(devices) > 1:
        print(f"{len(devices)} devices, one frame each at a time", file=sys.stderr)
    methods = {"pipeline": chain_method(run.config, run.model(), cascade=run.cascade_arg())}
    if sgbm:
        methods.update(sgbm=sgbm_method(pad=True), sgbm_unpadded=sgbm_method(pad=False))
    key = {"dataset": dataset, "gt": gt, "fill": fill, "max_disp": max_disp, "methods": list(methods),
           **frame_key_of_run(run)}
    records = out / "frames"
    legend = out / "error_legend.png"                 # what <frame>_error.png's colours mean
    legend_written = []

    def write_legend():
        if not legend_written:
            io.write_png(legend, io.error_legend())
            legend_written.append(True)

    def write(row, sample, disparities):
        write_legend()                                # with the first output, not before it
        if gt == "auto":                              # what this frame was scored on
            row["gt"] = "noc" if sample.gt_noc_valid is not None else "occ"
        disp = disparities["pipeline"]
        names = write_prediction(out, f"{row['frame']}_", disp,
                                 color_max=color_scale(disp, sample.gt, sample.gt_valid))
        io.write_error_map(out / f"{row['frame']}_error.png", disp, sample.gt, sample.gt_valid)
        io.write_json(records / f"{row['frame']}.json", {"key": key, "row": row,
                                                          "files": file_entries(out, [*names, f"{row['frame']}_error.png"])})

    def earlier(frame_id):
        try:
            stored = json.loads((records / f"{frame_id}.json").read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(stored, dict) or stored.get("key") != json.loads(json.dumps(key)):
            return None
        problem = damaged(out, stored.get("files"), verify)
        if problem:
            print(f"{frame_id}: recorded as scored but {problem}; scoring it again", file=sys.stderr)
            return None
        return stored.get("row")

    with folder_lock(output_folder(out), "evaluate"), stop_on_signals():
        result = evaluate_frames(items, methods, lambda s: search_range(dataset, s, max_disp), fill=fill,
                                 devices=devices, on_frame=write, progress=f"evaluate {dataset}",
                                 reuse=None if overwrite else earlier,
                                 regions=("noc", "all") if gt == "both" else None)
    per_frame, missing_gt = result["frames"], result["missing_gt"]
    if result["reused"]:
        print(f"{len(result['reused'])} of {len(per_frame)} frames from the records of an earlier run in "
              f"{records} (--overwrite computes them again)", file=sys.stderr)
    if missing_gt:
        names = ", ".join(missing_gt[:5]) + (" ..." if len(missing_gt) > 5 else "")
        what = {"both": "non-occluded and all-pixel ", "auto": ""}.get(gt, f"{gt} ")
        msg = f"no {what}ground truth for {len(missing_gt)} frame(s): {names}"
        hint = _GT_HINT.get(gt, "").format(source=NOC_SOURCE.get(dataset, "a non-occlusion mask"))
        if not per_frame:
            raise StereoInputError(msg + "; nothing to evaluate" + (f"; {hint}" if hint else ""))
        print(f"warning: {msg}; skipped" + (f"; {hint}" if hint else ""), file=sys.stderr)
    if not legend.exists():                           # every frame from the records of an earlier run
        write_legend()
    results = {"dataset": dataset, "gt": gt, "fill": fill, "frames": per_frame, "mean": result["mean"],
               "reused": result["reused"],
               "config": run.with_max_disp(per_frame[0]["max_disp"]).config.to_dict(),
               "kernels": kernels_mod.record(run.config.kernels)}
    io.write_json(out / "results.json", results)
    table = format_table(result["mean"], run.label)
    with io.atomic_output(out / "results.md") as tmp:
        Path(tmp).write_text(f"# {dataset}, {len(per_frame)} frames, {_gt_text(gt, per_frame)}, missing "
                             f"estimates: {fill}\n\n"
                             f"{table}\n")
    print(table)
    print(f"-> {out}/results.json")
    return results
