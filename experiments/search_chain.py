"""Coordinate search of the learned chain's CBCA, SGM and refinement settings on TRAINING frames,
with the learned cost volume of every frame computed once and cached (issue "accuracy", part 3).

Command:  .venv/bin/python experiments/search_chain.py [--dataset kitti2015] [--frames 000001-000020]
              [--weights kitti2015] [--rounds 2] [--out experiments/results]
Running time here (2 cores, KITTI): about 15 s per frame for the volume (the shipped pruned
adaptive head), then per setting about 2.5 s per frame plus 5-10 s compiling (the settings are
static arguments of the jitted chain).

The volume is the one ``--method best`` computes (``preset("learned")``: the head at the ranked
census candidates, its candidate chain fixed); the search varies only what comes after it:
CBCA passes before/after SGM, arm threshold tau and arm length, P1, P2, the gradient reduction
(q1, q2, threshold), LR tolerance and the median window. Starting from the shipped preset (or, with ``--start``, a model's stored settings), each
parameter in turn takes the value of its list that gives the lowest mean > 3 px error (noc GT,
dense output, as KITTI's table) over the frames; ``--rounds`` passes over all parameters.

The frames must be training frames (see experiments/PROTOCOL.md): the validation frames
000021-000030 are scored once, afterwards, with ``stereojax evaluate``.
Writes OUT/chain_search_<dataset>.md (every setting tried, in order) and .json.
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

from stereojax.inference.predictor import Predictor
from stereojax.inference.programs import disparity_from_volume
from stereojax.config import StereoConfig, preset
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, parse_frames, search_range
from stereojax.data.io import write_json
from stereojax.app.evaluation import evaluate_frames
from stereojax.models.registry import learned_config, load_model, shipped_weights

#: (section, field, values tried); the shipped value is always among the candidates
SPACE = [
    ("sgm", "p1", [0.25, 0.35, 0.5, 0.7, 1.0]),
    ("sgm", "p2", [4.0, 6.0, 8.0, 11.0, 15.0]),
    ("cbca", "iterations_before", [0, 1, 2, 3, 4]),
    ("cbca", "iterations_after", [0, 1, 2]),
    ("cbca", "tau", [10.0, 15.0, 20.0, 30.0]),
    ("cbca", "arm_length", [3, 5, 7, 9]),
    ("sgm", "q1", [1.5, 3.0, 4.5]),
    ("sgm", "q2", [3.0, 6.0, 10.0]),
    ("sgm", "grad_threshold", [8.0, 15.0, 25.0]),
    ("refine", "lr_tolerance", [0.5, 1.0, 2.0, 3.0]),
    ("refine", "median_size", [0, 3, 5, 7]),
]

#: a smaller space for data sets of many sizes (Middlebury: every scene size and disparity range
#: is a program of its own, so each setting costs a compilation per scene)
SPACE_SMALL = [
    ("sgm", "p1", [0.25, 0.35, 0.5, 0.7, 1.0]),
    ("sgm", "p2", [4.0, 6.0, 8.0, 11.0, 15.0]),
    ("cbca", "iterations_before", [0, 1, 2, 3, 4]),
    ("refine", "lr_tolerance", [0.5, 1.0, 2.0, 3.0]),
    ("refine", "median_size", [0, 3, 5, 7]),
]

#: around a setting already searched (``--start card``): one step either way of every value the
#: KITTI search chose, P1 and P2 beyond the ends of SPACE's lists (the first search stopped at
#: P1 = 1.0 and P2 = 4.0, the top and the bottom of its lists)
SPACE_LOCAL = [
    ("sgm", "p1", [0.7, 1.0, 1.5, 2.0]),
    ("sgm", "p2", [3.0, 4.0, 5.0, 6.0]),
    ("cbca", "iterations_before", [0, 1, 2]),
    ("cbca", "tau", [7.0, 10.0, 15.0]),
    ("cbca", "arm_length", [5, 7]),
    ("sgm", "q2", [6.0, 10.0, 15.0]),
    ("refine", "lr_tolerance", [1.0, 2.0]),
    ("refine", "median_size", [5, 7, 9]),
]

SPACES = {"full": SPACE, "small": SPACE_SMALL, "local": SPACE_LOCAL}


def with_value(cfg: StereoConfig, section: str, name: str, value) -> StereoConfig:
    sub = dataclasses.replace(getattr(cfg, section), **{name: value})
    try:
        return dataclasses.replace(cfg, **{section: sub}).validate()
    except Exception:          # e.g. p2 < p1: not a valid setting
        return None


def cache_volumes(samples, model, base: StereoConfig, max_disp) -> dict:
    """The learned volume of every sample, computed once (:meth:`stereojax.Predictor.volume`):
    ``{"model", "samples", "max_disp": {name: D}, "volumes": {name: Volume}}``.
    max_disp(sample) -> disparities."""
    cache = {"model": model, "samples": list(samples), "max_disp": {}, "volumes": {}}
    t0 = time.perf_counter()
    for s in cache["samples"]:
        md = cache["max_disp"][s.name] = max_disp(s)
        cache["volumes"][s.name] = Predictor(base.with_max_disp(md), model).volume(s.left, s.right)
        print(f"volume {s.name} ({s.left.shape[1]}x{s.left.shape[0]}, {md} disparities): "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
    return cache


def score(cache, cfg: StereoConfig, threshold: str = "bad3") -> tuple[float, list[float]]:
    """Mean error (``threshold``: bad2, bad3, ... or "bad2+bad3" for their mean; on the sample's
    GT) of the chain ``cfg`` run on the cached volumes, and the per-frame errors."""
    def from_volume(s, md):
        return Predictor(cfg.with_max_disp(md), cache["model"]).from_volume(cache["volumes"][s.name])

    rows = evaluate_frames(cache["samples"], {"chain": from_volume}, lambda s: cache["max_disp"][s.name])["frames"]
    errs = [float(sum(r["chain"][k] for k in threshold.split("+")) / len(threshold.split("+"))) for r in rows]
    # every setting is a new program: drop the old ones (a search of ~75 KITTI-sized programs
    # kept in memory ended in "LLVM compilation error: Cannot allocate memory" here)
    disparity_from_volume.clear_cache()
    return float(sum(errs) / len(errs)), errs


def coordinate_search(cache, base: StereoConfig, space=SPACE, rounds: int = 2, threshold: str = "bad3",
                      on_trial=None):
    """Each parameter of ``space`` in turn takes its best value (lowest mean error over the
    cached frames), ``rounds`` times over (stopping early when nothing changes).
    Returns (best config, its error, the shipped config's error, the log of every trial).
    on_trial(best, best_err, start_err, log): called after every trial (to save progress)."""
    log, seen = [], {}

    def trial(cfg, what):
        key = cfg.to_json()
        if key not in seen:
            t = time.perf_counter()
            seen[key] = score(cache, cfg, threshold)
            log.append({"setting": what, threshold: seen[key][0], "per_frame": seen[key][1],
                        "seconds": time.perf_counter() - t})
            print(f"{seen[key][0]:6.3f}  {time.perf_counter() - t:5.1f}s  {what}", flush=True)
        return seen[key][0]

    best = base
    best_err = start_err = trial(best, "start")
    for rnd in range(rounds):
        changed = False
        for section, name, values in space:
            for v in values:
                cand = with_value(best, section, name, v)
                if cand is None or cand == best:
                    continue
                err = trial(cand, f"round {rnd + 1}: {section}.{name} = {v}  (on {changes(base, best) or 'preset'})")
                if err < best_err - 1e-6:
                    best, best_err, changed = cand, err, True
                if on_trial is not None:
                    on_trial(best, best_err, start_err, log)
        if not changed:
            break
    return best, best_err, start_err, log


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", default="kitti2015", choices=["kitti2015", "middlebury"])
    ap.add_argument("--frames", default="000001-000020")
    ap.add_argument("--weights", help="checkpoint (default: the shipped model of --dataset)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--space", default="full", choices=sorted(SPACES),
                    help="full: 11 parameters (KITTI); small: P1, P2, CBCA passes, LR tolerance, "
                         "median; local: one step around an already searched setting (use with --start)")
    ap.add_argument("--start", default="preset",
                    help="'preset' (preset('learned')) or a model (shipped name or weights path) "
                         "whose stored chain settings the search starts from")
    ap.add_argument("--tag", default="", help="suffix of the output file names")
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args()
    root = Path(args.data) / ("kitti2015/training" if args.dataset == "kitti2015" else "middlebury")
    frames = parse_frames(args.frames) if args.dataset == "kitti2015" else args.frames.split(",")
    model = load_model(args.weights or shipped_weights(args.dataset))
    base = preset("learned") if args.start == "preset" else learned_config(args.start)
    gt = "noc" if args.dataset == "kitti2015" else "occ"
    samples = [load() for _, load in load_dataset(root, args.dataset, frames=frames, gt=gt)]
    cache = cache_volumes(samples, model, base, lambda s: search_range(args.dataset, s, None))

    def save(best, best_err, start_err, log):
        write_search(Path(args.out), args, [x.name for x in cache["samples"]], base, best, best_err, start_err, log)

    threshold = "bad3" if args.dataset == "kitti2015" else "bad2+bad3"
    space = SPACES[args.space]
    best, best_err, start_err, log = coordinate_search(cache, base, space, args.rounds, threshold, on_trial=save)
    save(best, best_err, start_err, log)
    print(json.dumps({"start": start_err, "best": best_err, "changes": changes(base, best)}))


def write_search(out: Path, args, frames, base, best, best_err, start_err, log) -> None:
    """OUT/chain_search_<dataset>.{json,md}: every trial so far and the best setting."""
    name = f"chain_search_{args.dataset}{args.tag}"
    # the card's "chain" entry is always relative to preset("learned"), whatever the start
    result = {"dataset": args.dataset, "frames": frames, "weights": str(args.weights or "shipped"),
              "start_from": args.start, "start": start_err, "best": best_err,
              "changes": changes(base, best), "overrides": overrides(preset("learned"), best),
              "best_config": best.to_dict(), "trials": log}
    write_json(out / f"{name}.json", result)
    lines = [f"# Learned-chain settings searched on {args.dataset} training frames",
             "", f"Frames: {', '.join(frames)} (training frames only; see experiments/PROTOCOL.md).",
             f"Command: `.venv/bin/python experiments/search_chain.py --dataset {args.dataset} "
             f"--frames {args.frames} --rounds {args.rounds} --space {args.space}"
             f"{f' --weights {args.weights}' if args.weights else ''}"
             f"{f' --start {args.start}' if args.start != 'preset' else ''}"
             f"{f' --tag {args.tag}' if args.tag else ''}`", "",
             f"Mean {'> 3 px (noc' if args.dataset == 'kitti2015' else 'of > 2 and > 3 px (all-pixel GT'}, dense): "
             f"start ({args.start}) {start_err:.3f} %, best {best_err:.3f} % with "
             f"{changes(base, best) or 'no change'}.", "", "| error % | s | setting |", "|---|---|---|"]
    key = "bad3" if args.dataset == "kitti2015" else "bad2+bad3"
    lines += [f"| {r[key]:.3f} | {r['seconds']:.0f} | {r['setting']} |" for r in log]
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")


def overrides(a: StereoConfig, b: StereoConfig) -> dict:
    """The fields where b differs from a as StereoConfig overrides ({"sgm": {"p1": 1.0}, ...}),
    the form of a model card's "chain" entry."""
    out: dict = {}
    for section in ("cbca", "sgm", "refine"):
        for f in dataclasses.fields(getattr(a, section)):
            va, vb = getattr(getattr(a, section), f.name), getattr(getattr(b, section), f.name)
            if va != vb:
                out.setdefault(section, {})[f.name] = vb
    return out


def changes(a: StereoConfig, b: StereoConfig) -> str:
    """The fields where b differs from a, as 'sgm.p1=0.7, ...'."""
    out = []
    for section in ("cbca", "sgm", "refine"):
        for f in dataclasses.fields(getattr(a, section)):
            va, vb = getattr(getattr(a, section), f.name), getattr(getattr(b, section), f.name)
            if va != vb:
                out.append(f"{section}.{f.name}={vb}")
    return ", ".join(out)


if __name__ == "__main__":
    main()
