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

Four ways to pick the unsure pixels are compared: the chain's confidence map (known only after
the whole chain has run), two measures of the student's raw matching cost that exist before
aggregation (so a cascade could mix the costs and run the chain once): the margin between its
best and second-best minimum (second minimum at least 2 disparities from the best), and its best
cost itself (no good match found); and q random pixels as the contrast.
Error: > 3 px on KITTI's non-occluded ground truth (disp_noc_0; missing estimates interpolated, as KITTI does).

Command:  .venv/bin/python experiments/investigations/cascade_premise.py   (about 6 min here)
-> experiments/results/cascade_premise.{json,md}
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import stereojax

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


MEASURES = ("confidence", "cost margin", "best cost", "random")
#: tile sizes (rows, columns) of the tower: the share of tiles the chosen pixels (left image)
#: and their candidates' matches (right image) touch, and the halo's work per tile
TILES = ((8, 16), (16, 32), (32, 64))
#: candidates per chosen pixel whose matches the right image's tiles must hold
K_FULL = 8
HALO = 4


def tile_shares(chosen: np.ndarray, cost: np.ndarray) -> dict:
    """For each tile size of TILES: the share of left tiles holding a chosen pixel, of right
    tiles holding a match (x - c) of one of their K_FULL best raw-cost disparities, and the
    tower's work on those tiles (halo included) as a share of the whole tower on both images."""
    h, w = chosen.shape
    ys, xs = np.nonzero(chosen)
    cand = np.argsort(cost[ys, xs], axis=-1, kind="stable")[:, :K_FULL]
    rx = np.maximum(xs[:, None] - cand, 0)
    out = {}
    for th, tw in TILES:
        ny, nx = -(-h // th), -(-w // tw)
        left = np.zeros((ny, nx), bool)
        left[ys // th, xs // tw] = True
        right = np.zeros((ny, nx), bool)
        right[np.repeat(ys, K_FULL) // th, rx.ravel() // tw] = True
        halo = (th + 2 * HALO) * (tw + 2 * HALO) / (th * tw)
        work = halo * (left.sum() + right.sum()) * th * tw / (2 * h * w)
        out[f"{th}x{tw}"] = {"left": float(left.mean()), "right": float(right.mean()), "tower": float(work)}
    return out


def cost_measures(cost: np.ndarray) -> dict[str, np.ndarray]:
    """Sureness of the student's raw matching cost ``f32[H, W, D]`` (higher = surer): the
    margin between the best and the second-best minimum at least 2 disparities away, and minus
    the best cost."""
    best = cost.argmin(-1)
    c1 = np.take_along_axis(cost, best[..., None], -1)[..., 0]
    d = np.arange(cost.shape[-1])[None, None, :]
    away = np.where(np.abs(d - best[..., None]) >= 2, cost, np.inf)
    c2 = away.min(-1)
    return {"cost margin": c2 - c1, "best cost": -c1}


def mixtures(student, sureness: dict, full, gt, valid, rng, cost) -> dict:
    """> 3 px of the student with the full network's answer at its q least sure pixels by each
    measure of ``sureness`` (and at q random pixels), for each q of SHARES."""
    size = student.size
    out = {}
    for q in SHARES:
        n = int(round(q * size))
        row = {}
        for name in MEASURES:
            chosen = np.zeros(size, bool)
            if name == "random":
                chosen[rng.choice(size, n, replace=False)] = True
            else:
                chosen[np.argsort(sureness[name], axis=None, kind="stable")[:n]] = True
            mix = np.where(chosen.reshape(student.shape), full, student)
            row[name] = float(evaluate(mix, gt, valid)["bad3"])
            if name in ("confidence", "cost margin"):
                row[f"tiles {name}"] = tile_shares(chosen.reshape(student.shape), cost)
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
        pred = runs[("student", (h, w))][0]
        cost = stereojax.stages(s.left, s.right, pred.config, pred.model)["cost"]
        sureness = {"confidence": sc, **cost_measures(cost)}
        row = {"frame": f, "size": [w, h], "student": float(evaluate(sd, s.gt, s.gt_valid)["bad3"]),
               "full": float(evaluate(fd, s.gt, s.gt_valid)["bad3"]), "student_s": st, "full_s": ft,
               "models": {"student": sl, "full": fl},
               "mix": mixtures(sd, sureness, fd, s.gt, s.gt_valid, rng, cost)}
        rows.append(row)
        print(f, {k: row[k] for k in ("student", "full")}, row["mix"], flush=True)
        write(rows)


def write(rows):
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "cascade_premise.json").write_text(json.dumps({"frames": rows, "shares": SHARES, "measures": MEASURES},
                                                         indent=1))
    mean = lambda get: float(np.mean([get(r) for r in rows]))       # noqa: E731
    s, f = mean(lambda r: r["student"]), mean(lambda r: r["full"])
    lines = ["# Is the student wrong where it is unsure? (issue 38's premise)", "",
             "`experiments/investigations/cascade_premise.py`, one run on this machine (2 cores), KITTI 2015 "
             f"{rows[0]['frame']}–{rows[-1]['frame']} (selection fold). > 3 px, non-occluded ground truth (`disp_noc_0`). The full "
             "network's disparity replaces the student's at the q least confident (or q random) pixels, after "
             "the chain.", "",
             f"Student `{rows[0]['models']['student']}`: {s:.2f} %, {mean(lambda r: r['student_s']):.1f} s per frame "
             f"(the run, compiling apart); full `{rows[0]['models']['full']}`: {f:.2f} %, "
             f"{mean(lambda r: r['full_s']):.1f} s.", "",
             "> 3 px of the mixture, and in brackets the share of the student's excess error over the full "
             "network that it closes:", "",
             "| q | " + " | ".join(f"least sure by {m}" if m != "random" else "random" for m in MEASURES) + " |",
             "|---|" + "---|" * len(MEASURES), "| 0 (student) | " + " | ".join(f"{s:.2f}" for _ in MEASURES) + " |"]
    gap = max(s - f, 1e-9)
    for q in SHARES:
        cells = []
        for m in MEASURES:
            v = mean(lambda x: x["mix"][f"{q:g}"][m])
            cells.append(f"{v:.2f} ({100 * (s - v) / gap:.0f} %)")
        lines.append(f"| {100 * q:g} % | " + " | ".join(cells) + " |")
    lines.append("| 100 % (full) | " + " | ".join(f"{f:.2f}" for _ in MEASURES) + " |")
    lines += ["", f"The tower's share of work on tiles (rows x columns; halo of {HALO} px): the left tiles that "
              f"hold a chosen pixel and the right tiles that hold a match of one of its {K_FULL} best raw-cost "
              "disparities, against the whole tower on both images (1.0):", "",
              "| q | pixels by | " + " | ".join(f"{t[0]}x{t[1]}: left / right tiles, tower" for t in TILES) + " |",
              "|---|---|" + "---|" * len(TILES)]
    for q in SHARES:
        for m in ("confidence", "cost margin"):
            cells = []
            for t in TILES:
                key = f"{t[0]}x{t[1]}"
                get = lambda part: mean(lambda x: x["mix"][f"{q:g}"][f"tiles {m}"][key][part])   # noqa: E731
                cells.append(f"{100 * get('left'):.0f} / {100 * get('right'):.0f} %, {get('tower'):.2f}")
            lines.append(f"| {100 * q:g} % | {m} | " + " | ".join(cells) + " |")
    lines += ["", "Per frame (> 3 px): " + "; ".join(f"{r['frame']} student {r['student']:.2f}, full {r['full']:.2f}"
                                                   for r in rows) + "."]
    (OUT / "cascade_premise.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
