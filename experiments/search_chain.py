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
import json
from pathlib import Path

from stereojax.config import preset
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, parse_frames, search_range
from stereojax.data.io import write_json
from stereojax.models.registry import learned_config, load_model, shipped_weights

# the search itself lives in the package (``stereojax tune`` runs it on one's own frames)
from stereojax.app.tune import (SPACE, SPACE_LOCAL, SPACE_SMALL, SPACES, cache_volumes, changes,  # noqa: E402,F401
                                coordinate_search, overrides, score, with_value)

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


if __name__ == "__main__":
    main()
