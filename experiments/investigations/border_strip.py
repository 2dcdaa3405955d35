"""The out-of-view strip (x - d < 0, the match outside the right image): which cost to give it,
measured on training frames only (issue "every pixel counts").

Frames with all-pixel ground truth that a shipped model trained on: KITTI 2015 000001 (the only
KITTI 2015 frame with disp_occ; `kitti2015` model and chain) and the Middlebury scenes Cones,
Teddy, Reindeer, Venus, Tsukuba (`middlebury` model and chain). Each frame's learned volume is
computed once (`Predictor.volume`); the rest of the chain then runs on it with the out-of-view
entries as they are ("replicate": compared with the right image's first column) or set to
``min + share * (mean - min)`` of the pixel's in-view costs (`cost.neutral_border`). OpenCV
SGBM (left-padded) is scored beside. > 3 px, all ground-truth pixels, and within the strip.

Command:  .venv/bin/python experiments/investigations/border_strip.py [--data ../shared/data]
(about 5 min here) -> experiments/results/border.{json,md}
"""

import argparse
import dataclasses
from pathlib import Path

import numpy as np

import stereojax
from stereojax.app.baselines import sgbm_disparity
from stereojax.matching_cost.classical import neutral_border
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, search_range
from stereojax.data.io import write_json
from stereojax.metrics import evaluate
from stereojax.models.registry import resolve
from stereojax.inference.programs import Volume

FRAMES = [("kitti2015", "000001")] + [("middlebury", n) for n in
                                      ("Cones_2003Q", "Teddy_2003Q", "Reindeer_2006H", "Venus_2001", "Tsukuba_2001")]
SHARES = (0.0, 0.25, 0.5, 0.75)
OUT = Path(__file__).resolve().parents[1] / "results"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    variants = ["replicate"] + [f"neutral {a:g}" for a in SHARES]
    rows = []
    for ds, frame in FRAMES:
        s = load_dataset(args.data, ds, [frame], gt="occ")[0][1]()
        md = search_range(ds, s, None)
        run = resolve("best", None, None, s.left.shape[1], s.left.shape[0], ds, md)
        cfg = dataclasses.replace(run.config, cost=dataclasses.replace(run.config.cost, border="replicate")).validate()
        predictor = stereojax.Predictor(cfg, run.model())
        vol = predictor.volume(s.left, s.right)
        strip = s.gt_valid & (np.arange(s.gt.shape[1])[None, :] - s.gt < 0)
        row = {"frame": f"{ds} {frame}", "model": run.description, "strip_px": int(strip.sum()),
               "gt_px": int(s.gt_valid.sum())}
        d_cv, v_cv = sgbm_disparity(s.left, s.right, num_disp=md, pad=True)
        row["sgbm"] = evaluate(d_cv, s.gt, s.gt_valid, est_valid=v_cv)["bad3"]
        for name in variants:
            cost = vol.cost if name == "replicate" else np.asarray(neutral_border(vol.cost, float(name.split()[1])))
            disp = predictor.from_volume(Volume(cost, vol.left, vol.right, vol.valid))
            row[name] = evaluate(disp, s.gt, s.gt_valid)["bad3"]
            row[name + " strip"] = evaluate(disp, s.gt, strip)["bad3"] if strip.any() else None
        rows.append(row)
        print(row, flush=True)
    mean = {v: float(np.mean([r[v] for r in rows])) for v in ["sgbm"] + variants}
    write_json(OUT / "border.json", {"frames": rows, "mean": mean})
    lines = ["# The out-of-view strip: replicate against neutral costs (training frames, all-pixel GT)", "",
             "> 3 px % of all ground-truth pixels (in brackets: of the pixels whose match lies outside the right "
             "image). Each shipped model in its own chain; only the out-of-view entries of its volume change.", "",
             "| frame | strip px | SGBM | " + " | ".join(variants) + " |", "|---" * (3 + len(variants)) + "|"]
    for r in rows:
        cells = [f"{r[v]:.2f}" + (f" ({r[v + ' strip']:.1f})" if r[v + " strip"] is not None else "") for v in variants]
        lines.append(f"| {r['frame']} | {r['strip_px']} | {r['sgbm']:.2f} | " + " | ".join(cells) + " |")
    lines.append("| **mean** | | " + f"{mean['sgbm']:.2f} | " + " | ".join(f"**{mean[v]:.2f}**" for v in variants) + " |")
    lines += ["", "Command: `python experiments/investigations/border_strip.py`", ""]
    (OUT / "border.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
