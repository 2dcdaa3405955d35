"""Is the student wrong where it is unsure? The premise of issue 38's cascade, measured before
any cascade is built.

On the selection fold KITTI 2015 000016-000020 (never validation), the compact student
(``kitti2015_compact``) and the full network (``kitti2015``) each run the whole chain with their
confidence maps. For a share q of the pixels, the q least confident of the student's, the
full network's disparity replaces the student's *after* the chain (an oracle-free stand-in
for the cascade, which would mix the costs before aggregation instead). Reported per q:
> 3 px of that mixture, the share of the student's excess error over the full network it closes
((student - mix) / (student - full)), and the same for q random pixels as the contrast. If the
confidence picks the student's errors, the mixture should close most of the gap at small q.
Error: > 3 px on the KITTI all-pixels ground truth (missing estimates interpolated, as KITTI does).

Command:  .venv/bin/python experiments/investigations/cascade_premise.py   (about 6 min here)
-> experiments/results/cascade_premise.{json,md}
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from stereojax.data.datasets import DEFAULT_DATA, load_kitti2015
from stereojax.devices import current_device
from stereojax.inference.predictor import Predictor
from stereojax.metrics import evaluate
from stereojax.models.registry import resolve

OUT = Path(__file__).resolve().parents[1] / "results"
FRAMES = [f"{i:06d}" for i in range(16, 21)]
SHARES = (0.05, 0.10, 0.20, 0.40)
MODELS = {"student": "kitti2015_compact", "full": "kitti2015"}


def predictor(weights: str, w: int, h: int) -> tuple[Predictor, str]:
    res = resolve("best", weights=weights, width=w, height=h, dataset="kitti2015")
    return Predictor(res.config, res.model(), current_device(), confidence=True), res.label


def mixtures(student, conf, full, gt, valid, rng) -> dict:
    """> 3 px of the student with the full network's answer at its q least confident pixels
    (and at q random pixels), for each q of SHARES."""
    order = np.argsort(conf, axis=None, kind="stable")          # least confident first
    out = {}
    for q in SHARES:
        n = int(round(q * conf.size))
        pick = np.zeros(conf.size, bool)
        pick[order[:n]] = True
        rand = np.zeros(conf.size, bool)
        rand[rng.choice(conf.size, n, replace=False)] = True
        row = {}
        for name, chosen in (("confidence", pick), ("random", rand)):
            mix = np.where(chosen.reshape(conf.shape), full, student)
            row[name] = float(evaluate(mix, gt, valid)["bad3"])
        out[f"{q:g}"] = row
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--frames", default=",".join(FRAMES))
    args = ap.parse_args()
    root = Path(args.data) / "kitti2015" / "training"
    rng = np.random.default_rng(0)
    runs, rows = {}, []
    for f in args.frames.split(","):
        s = load_kitti2015(root, f)
        h, w = s.left.shape[:2]
        got = {}
        for key, weights in MODELS.items():
            if (key, (h, w)) not in runs:
                runs[(key, (h, w))] = predictor(weights, w, h)
            pred, label = runs[(key, (h, w))]
            (disp, conf), t = pred.timed(s.left, s.right)
            got[key] = (np.asarray(disp), np.asarray(conf), t["seconds"], label)
        (sd, sc, st, sl), (fd, _, ft, fl) = got["student"], got["full"]
        row = {"frame": f, "size": [w, h], "student": float(evaluate(sd, s.gt, s.gt_valid)["bad3"]),
               "full": float(evaluate(fd, s.gt, s.gt_valid)["bad3"]), "student_s": st, "full_s": ft,
               "models": {"student": sl, "full": fl},
               "mix": mixtures(sd, sc, fd, s.gt, s.gt_valid, rng)}
        rows.append(row)
        print(f, {k: row[k] for k in ("student", "full")}, row["mix"], flush=True)
        write(rows)


def write(rows):
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "cascade_premise.json").write_text(json.dumps({"frames": rows, "shares": SHARES}, indent=1))
    mean = lambda get: float(np.mean([get(r) for r in rows]))       # noqa: E731
    s, f = mean(lambda r: r["student"]), mean(lambda r: r["full"])
    lines = ["# Is the student wrong where it is unsure? (issue 38's premise)", "",
             "`experiments/investigations/cascade_premise.py`, one run on this machine (2 cores), KITTI 2015 "
             f"{rows[0]['frame']}–{rows[-1]['frame']} (selection fold). > 3 px, all ground-truth pixels. The full "
             "network's disparity replaces the student's at the q least confident (or q random) pixels, after "
             "the chain.", "",
             f"Student `{rows[0]['models']['student']}`: {s:.2f} %, {mean(lambda r: r['student_s']):.1f} s per frame "
             f"(the run, compiling apart); full `{rows[0]['models']['full']}`: {f:.2f} %, "
             f"{mean(lambda r: r['full_s']):.1f} s.", "",
             "| q | > 3 px, least confident replaced | gap closed | > 3 px, random replaced | gap closed |",
             "|---|---|---|---|---|", f"| 0 (student) | {s:.2f} | 0 % | {s:.2f} | 0 % |"]
    for q in SHARES:
        c, r = mean(lambda x: x["mix"][f"{q:g}"]["confidence"]), mean(lambda x: x["mix"][f"{q:g}"]["random"])
        gap = max(s - f, 1e-9)
        lines.append(f"| {100 * q:g} % | {c:.2f} | {100 * (s - c) / gap:.0f} % | {r:.2f} | {100 * (s - r) / gap:.0f} % |")
    lines.append(f"| 100 % (full) | {f:.2f} | 100 % | {f:.2f} | 100 % |")
    lines += ["", "Per frame (> 3 px): " + "; ".join(f"{r['frame']} student {r['student']:.2f}, full {r['full']:.2f}"
                                                   for r in rows) + "."]
    (OUT / "cascade_premise.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
