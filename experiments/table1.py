"""Table 1 — loss comparison: plain cross-entropy (Delta = 0, MC-CNN's loss) against the relaxed
loss (Delta = 0.05, paper Eq. 3.6), same network (downsize head) and schedule, several seeds.

Command:  make table1            (= .venv/bin/python experiments/table1.py [--seeds 3 --steps 1000 --kitti-frames 3])
          .venv/bin/python experiments/table1.py --quick      (smoke test, about a minute)
Running time here (2 cores): 51 min for the committed table (12 models of 1000 steps, each about
2-4 min of training and 1-2 min of scoring, with other jobs sharing the cores part of the time);
cached models are reused (see experiments/common.py), so a re-run only prints.
Prints and writes experiments/results/table1.{json,md}: per loss, mean ± std over seeds of the
patch-level validation error and of the > 3 px disparity error in four train -> test columns that
the data we have stands in for the paper's: KITTI 2015 -> KITTI 2015 (train 000001-000020, test
000021-000030, non-occluded GT), KITTI 2015 -> KITTI 2012 (frame 000000, all-pixel GT), KITTI
2015 -> Middlebury (the 4 test scenes of common.MIDDLEBURY_TEST, all-pixel GT) and Middlebury (6 scenes) -> KITTI 2015.
"""

import argparse

from common import LABELS, Setup, add_common_args, md_table, pm, write_outputs

LOSSES = {"bce": ("cross-entropy (Delta = 0)", 0.0), "relaxed": ("relaxed cross-entropy (Delta = 0.05)", 0.05)}
#: (training set, test set) columns
COLUMNS = [("kitti2015", "kitti2015"), ("kitti2015", "kitti2012"), ("kitti2015", "middlebury"),
           ("middlebury", "kitti2015")]


def main():
    ap = add_common_args(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    ap.add_argument("--seeds", type=int, help="seeds per loss (default 3; quick 1)")
    args = ap.parse_args()
    setup = Setup.from_args(args)
    seeds = list(range(args.seeds or (1 if setup.quick else 3)))
    cells = {}   # (loss, train, test) -> list over seeds of {"bad3", "patch_error"}
    for loss, (_, delta) in LOSSES.items():
        for train_set in sorted({c[0] for c in COLUMNS}):
            for seed in seeds:
                run = setup.train(train_set, "downsize", loss, delta, seed)
                patch = _patch_error(run)
                for tr, te in COLUMNS:
                    if tr != train_set:
                        continue
                    sc = setup.score_model(run, te)
                    cells.setdefault((loss, tr, te), []).append(
                        {"seed": seed, "bad3": sc["mean"]["bad3"], "bad2": sc["mean"]["bad2"],
                         "epe": sc["mean"]["epe"], "patch_error": patch, "run": run.name})
                    print(f"  {loss} seed {seed} {tr} -> {te}: > 3 px {sc['mean']['bad3']:.2f} %, "
                          f"patch error {patch:.2f} %", flush=True)
    header = ["loss"] + [f"patch error % ({LABELS[tr]} val)" for tr in ("kitti2015", "middlebury")] + \
        [f"{LABELS[tr]} → {LABELS[te]}, > 3 px %" for tr, te in COLUMNS]
    rows = []
    for loss, (label, _) in LOSSES.items():
        row = [label]
        for tr in ("kitti2015", "middlebury"):
            te = next(t for a, t in COLUMNS if a == tr)
            row.append(pm([c["patch_error"] for c in cells[(loss, tr, te)]]))
        row += [pm([c["bad3"] for c in cells[(loss, tr, te)]]) for tr, te in COLUMNS]
        rows.append(row)
    md = (f"# Table 1 — loss comparison (downsize head, {setup.steps} steps per model, "
          f"{len(seeds)} seed(s), mean ± std over seeds)\n\n" + md_table(header, rows) +
          "\n\nPatch error: share of misclassified validation pairs (KITTI 2015 000021-000030, or "
          "Middlebury Motorcycle). Disparity error: > 3 px, full chain (`preset(\"learned\")`, "
          f"pruned mode K = {setup.candidates}), on KITTI 2015 " + ", ".join(setup.frames("test", "kitti2015"))
          + " (non-occluded GT), KITTI 2012 000000 and Middlebury " + ", ".join(setup.frames("test", "middlebury"))
          + " (all-pixel GT).")
    data = {"seeds": seeds, "cells": {f"{l}|{tr}|{te}": v for (l, tr, te), v in cells.items()}}
    write_outputs(setup, "table1", data, md)


def _patch_error(run) -> float:
    import json

    summary = json.loads((run / "train_summary.json").read_text())
    return 100.0 * float(summary["validation"]["error"])


if __name__ == "__main__":
    main()
