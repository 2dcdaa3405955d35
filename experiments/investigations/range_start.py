"""Why a range that holds the scene cost accuracy (issue 55, item 1): [a, b) against [0, b), with the
range's start as it was (the right image moved by a, its first column repeated) and as it is now
(the pair without the a left columns that no disparity of the range can match,
:func:`stereojax.inference.prepare.range_pair`), per scene and with one chain setting toggled at a time.

[a, b): the ground truth's minimum (floored; KITTI: at most 8) up to its maximum, the span rounded up
to 16, so it holds every ground-truth pixel. Error: > 3 px on every ground-truth pixel for Middlebury
(``evaluate``, as ``stereojax evaluate --gt occ``), non-occluded for KITTI 2015; "raw" scores a
disparity of exactly 0 as 0 (``evaluate`` takes 0 for "no estimate" and interpolates it, which only
[0, b) can output); "strip" is the part of the difference from pixels whose true match lies left of
the right image (x < d), "in view" the rest (raw, in points of all pixels).

Command:  .venv/bin/python experiments/investigations/range_start.py   (about 10 min here)
-> experiments/results/range_start.{json,md}
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from stereojax.config import StereoConfig
from stereojax.data.datasets import DEFAULT_DATA, load_kitti2015, load_middlebury
from stereojax.inference.predictor import Predictor
from stereojax.inference.prepare import shift_right_image
from stereojax.metrics import evaluate
from stereojax.models.registry import resolve

OUT = Path(__file__).resolve().parents[1] / "results"
SCENES = ["Reindeer_2006H", "Baby1_2006H", "Bowling2_2006T", "Midd1_2006T", "Cones_2003Q", "Aloe_2006H",
          "000021", "000022", "000023"]
METHODS = ["census", "kitti2015_compact"]
#: one factor at a time, on Reindeer
TOGGLES = {
    "census": [{}, {"band.width": 0}, {"cost.border": "neutral"}, {"cost.border": "worst"},
               {"cost.border": "neutral", "band.width": 0}, {"band.scale": 1},
               {"sgm.p1": 0.225, "sgm.p2": 3.6}, {"sgm.p1": 0.9, "sgm.p2": 14.4}, {"sgm.adaptive": False},
               {"refine.lr_check": False}, {"band.width": 0, "refine.right_from_left": False},
               {"refine.median_size": 0, "refine.subpixel": False}],
    "kitti2015_compact": [{}, {"band.width": 0}, {"cost.border": "replicate"}],
}


def load(data: Path, scene: str):
    if scene.isdigit():
        return load_kitti2015(data / "kitti2015" / "training", scene, gt="noc"), "kitti2015"
    return load_middlebury(data / "middlebury" / scene), "middlebury"


def holding_range(sample, dataset: str) -> tuple[int, int]:
    g = sample.gt[sample.gt_valid]
    lo = math.floor(float(g.min()))
    if dataset == "kitti2015":
        lo = min(lo, 8)
    return lo, lo + 16 * math.ceil((math.floor(float(g.max())) + 1 - lo) / 16)


def with_overrides(cfg: StereoConfig, changes: dict) -> StereoConfig:
    d = cfg.to_dict()
    for key, value in changes.items():
        *path, last = key.split(".")
        node = d
        for p in path:
            node = node[p]
        node[last] = value
    return StereoConfig.from_dict(d)


def predict(cfg, model, sample, rng, how: str) -> np.ndarray:
    """The disparity over ``rng``: "cut" (stereojax now), "moved" (the range start before issue 55:
    the chain over b - a disparities on the left image and the right one moved by a)."""
    a, b = rng
    if how == "moved" and a > 0:
        return Predictor(cfg, model, disp_range=(0, b - a))(sample.left, shift_right_image(np.asarray(sample.right), a)) \
            + np.float32(a)
    return Predictor(cfg, model, disp_range=rng)(sample.left, sample.right)


def score(disp, sample) -> dict:
    v = sample.gt_valid
    x = np.arange(disp.shape[1])[None, :]
    strip = v & (x < sample.gt)
    bad = np.abs(disp - sample.gt) > 3
    n = v.sum()
    return {"bad3": float(evaluate(disp, sample.gt, v)["bad3"]), "raw": float(100 * bad[v].sum() / n),
            "strip": float(100 * bad[strip].sum() / n), "in_view": float(100 * bad[v & ~strip].sum() / n)}


def compare(cfg, model, sample, rng) -> dict:
    zero = score(predict(cfg, model, sample, (0, rng[1]), "cut"), sample)
    out = {"zero": zero}
    for how in ("moved", "cut"):
        s = score(predict(cfg, model, sample, rng, how), sample)
        out[how] = {**s, **{f"d_{k}": s[k] - zero[k] for k in ("bad3", "raw", "strip", "in_view")}}
    return out


def resolved(method: str, sample, dataset: str):
    h, w = np.shape(sample.left)[:2]
    if method.startswith("kitti2015"):
        return resolve("learned", weights=method, width=w, height=h, dataset=dataset)
    return resolve(method, width=w, height=h, dataset=dataset)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--scenes", default=",".join(SCENES))
    args = ap.parse_args()
    data = Path(args.data)
    rows, toggles = [], []
    for method in args.methods.split(","):
        for scene in args.scenes.split(","):
            sample, dataset = load(data, scene)
            res = resolved(method, sample, dataset)
            rng = holding_range(sample, dataset)
            r = {"method": method, "scene": scene, "range": list(rng), **compare(res.config, res.model(), sample, rng)}
            rows.append(r)
            print(method, scene, rng, {k: round(r[k]["d_bad3"], 3) for k in ("moved", "cut")}, flush=True)
            if scene == "Reindeer_2006H":
                for changes in TOGGLES.get(method, []):
                    t = {"method": method, "scene": scene, "range": list(rng), "changes": changes,
                         **compare(with_overrides(res.config, changes), res.model(), sample, rng)}
                    toggles.append(t)
                    print("  ", changes, {k: round(t[k]["d_bad3"], 3) for k in ("moved", "cut")}, flush=True)
            write(rows, toggles)


def write(rows, toggles):
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "range_start.json").write_text(json.dumps({"scenes": rows, "toggles": toggles}, indent=1))
    lines = ["# A range that holds the scene against [0, b) (issue 55, item 1)", "",
             "`experiments/investigations/range_start.py`, one run on this machine (2 cores, shared with a "
             "training run). > 3 px (%): all ground-truth pixels (Middlebury), non-occluded (KITTI). *moved*: "
             "the range's start before issue 55 (the right image moved by a); *cut*: now (the a left columns "
             "left out). Differences [a, b) − [0, b) in points; raw: a disparity of 0 scored as 0; strip / in "
             "view: the raw difference from pixels whose true match lies left of the right image / the rest.", "",
             "| method | scene | [a, b) | [0, b) | moved − [0, b) | cut − [0, b) | cut raw | cut strip | cut in view |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c = r["cut"]
        lines.append(f"| {r['method']} | {r['scene']} | {r['range'][0]}..{r['range'][1]} | {r['zero']['bad3']:.2f} | "
                     f"{r['moved']['d_bad3']:+.2f} | {c['d_bad3']:+.2f} | {c['d_raw']:+.2f} | {c['d_strip']:+.2f} | "
                     f"{c['d_in_view']:+.2f} |")
    for method in dict.fromkeys(r["method"] for r in rows):
        for part, pick in (("Middlebury", lambda s: not s.isdigit()), ("KITTI", str.isdigit)):
            sel = [r for r in rows if r["method"] == method and pick(r["scene"])]
            if sel:
                lines.append(f"| {method} | **mean, {part}** | | {np.mean([r['zero']['bad3'] for r in sel]):.2f} | "
                             f"{np.mean([r['moved']['d_bad3'] for r in sel]):+.2f} | "
                             f"{np.mean([r['cut']['d_bad3'] for r in sel]):+.2f} | | | |")
    lines += ["", "One factor at a time on Reindeer_2006H, [5, 101):", "",
              "| method | changed | [0, b) | moved − [0, b) (raw) | cut − [0, b) (raw) | cut strip | cut in view |",
              "|---|---|---|---|---|---|---|"]
    for t in toggles:
        m, c = t["moved"], t["cut"]
        lines.append(f"| {t['method']} | {json.dumps(t['changes']) if t['changes'] else 'none'} | {t['zero']['bad3']:.2f} | "
                     f"{m['d_bad3']:+.2f} ({m['d_raw']:+.2f}) | {c['d_bad3']:+.2f} ({c['d_raw']:+.2f}) | "
                     f"{c['d_strip']:+.2f} | {c['d_in_view']:+.2f} |")
    (OUT / "range_start.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
