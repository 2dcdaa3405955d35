"""A compressed matching network (issue 16): the speed/accuracy curve of narrower networks,
trained directly or distilled from the shipped full KITTI model, and the choice by the rules
of experiments/PROTOCOL.md ("A compressed network").

Command:  .venv/bin/python experiments/compressed.py        (make compressed)
Running time here (2 cores): about 3 min to train each direct candidate and 20 min for a
distilled one (30 000 steps; cached in runs/full/compressed/<name>, a killed run resumes), then
about 2 min to score each candidate (bench frame, 000016-000020, 000021-000030) and 4 min for
the full model. Prints one row per network and writes experiments/results/compressed.{json,md}:
architecture, FLOP per frame, warm seconds on the bench frame (KITTI 2015 000021), > 3 px on the
selection fold 000016-000020 (decides) and on the validation frames 000021-000030 (reported),
and the choice the protocol makes.

--quick: tiny networks trained a few steps, scored on a crop of one frame (a smoke test).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from common import QUICK_CROP, Setup, load_sample, add_common_args, md_table, write_outputs

from stereojax.app.bench import warm_chain
from stereojax.app.evaluation import chain_method, evaluate_frames, sgbm_method
from stereojax.metrics import mean_metrics
from stereojax.models.registry import learned_config, load_model, shipped_weights
from stereojax.models.nets import NetConfig, network_flops
from stereojax.learning.train import fit, train_preset

#: the candidates of the protocol: (name, tower feature maps, head widths, distilled)
CANDIDATES = [
    ("f16_w64-32", 16, (64, 32), False),
    ("f16_w32-16", 16, (32, 16), False),
    ("f32_w128-64", 32, (128, 64), False),
    ("f16_w64-32_distill", 16, (64, 32), True),
]
STEPS = 30000
CANDIDATES_PER_PIXEL = 16
TIME_LIMIT_S = 6.0            # protocol: a candidate must run the bench frame in at most this
TIE_POINTS = 0.05             # ... and within this many points the faster one wins
BEST_LIMIT = 3.92 + 0.15      # the full model's validation error + the allowed loss
FRAMES = {"train": [f"{i:06d}" for i in range(1, 16)], "select": [f"{i:06d}" for i in range(16, 21)],
          "val": [f"{i:06d}" for i in range(21, 31)]}
QUICK_FRAMES = {"train": ["000001", "000002"], "select": ["000016"], "val": ["000021"]}
QUICK_DISP = 48


def student_config(setup: Setup, features: int, widths, distill: bool):
    net = NetConfig(features=features, widths=tuple(widths)).validate()
    if setup.quick:
        return train_preset("tiny", net=net, steps=setup.steps, val_every=setup.steps,
                            checkpoint_every=setup.steps, distill=1.0 if distill else 0.0)
    # the cpu preset as `stereojax train --preset cpu --features F --widths ...` makes it
    return train_preset("cpu", net=net, steps=setup.steps, distill=1.0 if distill else 0.0)


def train_student(setup: Setup, frames, name, features, widths, distill, teacher) -> Path:
    cfg = student_config(setup, features, widths, distill)
    run = setup.runs / "compressed" / name
    done = run / "train_summary.json"
    if done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps:
        return run
    print(f"  training {name} ({cfg.steps} steps{', distilled' if distill else ''})", flush=True)
    load = lambda role: [load_sample(str(setup.data), "kitti2015", f, "noc") for f in frames[role]]  # noqa: E731
    info = {"data": {"dataset": "kitti2015", "frames": frames["train"], "val_frames": frames["select"]}}
    if distill:
        info["distill_from"] = "kitti2015"
    fit(cfg, load("train"), load("select"), run, resume=True, progress=False, info=info,
        teacher=teacher if distill else None)
    return run


def chain_for(model_name_or_none, max_disp: int):
    """The protocol's chain: the full KITTI model's searched settings, the head on the 16 best
    census candidates of every pixel (None: the full model's own card, as shipped)."""
    cfg = learned_config("kitti2015", max_disp)
    if model_name_or_none is None:
        return cfg
    k = min(CANDIDATES_PER_PIXEL, max_disp)
    return dataclasses.replace(cfg, cost=dataclasses.replace(cfg.cost, candidates=k, unsure_share=0.0,
                                                             unsure_candidates=0)).validate()


def score(samples, predict, max_disp: int) -> dict:
    """``predict(sample, max_disp)`` scored on the samples (:func:`stereojax.app.evaluation.evaluate_frames`)."""
    result = evaluate_frames(samples, {"m": predict}, max_disp)
    rows = [{"frame": r["frame"], **r["m"]} for r in result["frames"]]
    return {"mean": mean_metrics(rows), "frames": rows}


def choose(rows: list[dict]) -> dict | None:
    """The protocol's choice among the compressed candidates (rows with 'select' and 'seconds')."""
    fast = [r for r in rows if r["seconds"] <= TIME_LIMIT_S]
    if not fast:
        return None
    low = min(r["select"] for r in fast)
    near = [r for r in fast if r["select"] <= low + TIE_POINTS]
    return min(near, key=lambda r: r["seconds"])


def main():
    ap = add_common_args(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    ap.add_argument("--skip-full", action="store_true", help="do not score the full model (its row stays empty)")
    args = ap.parse_args()
    if args.steps is None and not args.quick:
        args.steps = STEPS
    setup = Setup.from_args(args)
    frames = QUICK_FRAMES if setup.quick else FRAMES
    teacher = load_model(shipped_weights("kitti2015"))

    def samples(role):
        out = [load_sample(str(setup.data), "kitti2015", f, "noc") for f in frames[role]]
        return [s.crop(*QUICK_CROP) for s in out] if setup.quick else out

    sel, val = samples("select"), samples("val")
    md = QUICK_DISP if setup.quick else 228
    bench = val[0]       # KITTI 2015 000021, the frame of make bench (cropped in quick mode)
    h, w = bench.left.shape[:2]
    rows = []
    for name, features, widths, distill in CANDIDATES:
        if setup.quick:
            features, widths = 4, (8, 4)
        run = train_student(setup, frames, name, features, widths, distill, teacher)
        model = load_model(run / "checkpoint.msgpack")
        cfg = chain_for(name, md)

        predict = chain_method(cfg, model)

        secs = warm_chain(bench.left, bench.right, cfg, model, repeats=2)["warm_s"]
        r_sel, r_val = score(sel, predict, md), score(val, predict, md)
        summary = json.loads((run / "train_summary.json").read_text())
        row = {"name": name, "features": model.net.features, "widths": list(model.net.widths),
               "distilled": distill, "run": str(run), "evals_per_pixel": cfg.cost.candidates,
               "gflop": network_flops(model.net, h, w, cfg.cost.candidates) / 1e9, "seconds": secs,
               "select": r_sel["mean"]["bad3"], "val": r_val["mean"]["bad3"],
               "val_d1": r_val["mean"]["d1"], "select_frames": r_sel["frames"], "val_frames": r_val["frames"],
               "train_seconds": summary["seconds"], "train_samples_per_s": summary["samples_per_s"]}
        rows.append(row)
        print(f"  {name}: {row['gflop']:.3g} GFLOP, {secs:.2f} s, > 3 px select {row['select']:.2f} %, "
              f"val {row['val']:.2f} %", flush=True)
    full = None
    if not args.skip_full:
        cfg = chain_for(None, md)
        c = cfg.cost
        evals = c.candidates + c.unsure_share * (c.unsure_candidates - c.candidates)
        secs = warm_chain(bench.left, bench.right, cfg, teacher, repeats=1)["warm_s"]
        r_val = score(val, chain_method(cfg, teacher), md)
        full = {"name": "full (shipped kitti2015)", "features": teacher.net.features,
                "widths": list(teacher.net.widths), "evals_per_pixel": evals,
                "gflop": network_flops(teacher.net, h, w, evals) / 1e9, "seconds": secs,
                "val": r_val["mean"]["bad3"], "val_d1": r_val["mean"]["d1"], "val_frames": r_val["frames"]}
        print(f"  full model: {full['gflop']:.0f} GFLOP, {secs:.2f} s, val {full['val']:.2f} %", flush=True)
    r_sgbm = evaluate_frames(val, {"sgbm": sgbm_method(pad=True)}, md)
    sgbm = {"val": r_sgbm["mean"]["sgbm"]["bad3"],
            "seconds": float(np.median([r["sgbm"]["seconds"] for r in r_sgbm["frames"]]))}
    chosen = choose(rows)
    becomes_best = bool(chosen and chosen["val"] <= BEST_LIMIT)
    data = {"rows": rows, "full": full, "sgbm": sgbm, "chosen": chosen["name"] if chosen else None,
            "becomes_best": becomes_best, "rules": {"time_limit_s": TIME_LIMIT_S, "tie_points": TIE_POINTS,
                                                     "best_limit": BEST_LIMIT},
            "frames": frames, "max_disp": md}
    table = []
    for r in rows + ([full] if full else []):
        arch = f"tower {r['features']} maps, head {'-'.join(map(str, r['widths']))}"
        table.append([r["name"], arch + (", distilled" if r.get("distilled") else ""),
                      f"{r['evals_per_pixel']:g}", f"{r['gflop']:.3g}", f"{r['seconds']:.2f}",
                      f"{r['select']:.2f}" if "select" in r else "(trained on them)", f"{r['val']:.2f}",
                      f"{r['val_d1']:.2f}"])
    table.append(["OpenCV StereoSGBM (left-padded)", "-", "-", "-", f"{sgbm['seconds']:.3f}", "-",
                  f"{sgbm['val']:.2f}", "-"])
    where = "a crop of" if setup.quick else ""
    text = "\n".join([
        "# Compressed matching networks: speed against accuracy (KITTI 2015, 2 CPU cores)", "",
        f"Students trained on {frames['train'][0]}-{frames['train'][-1]} ({setup.steps} steps), chain settings of "
        f"the full KITTI model with the head on {CANDIDATES_PER_PIXEL} census candidates per pixel. Seconds: "
        f"warm, whole chain, on {where} the bench frame {bench.name} ({w}x{h}, {md} disparities), all in one run. "
        "> 3 px: non-occluded GT, mean over frames; the selection fold "
        f"{frames['select'][0]}-{frames['select'][-1]} decides, the validation frames "
        f"{frames['val'][0]}-{frames['val'][-1]} are reported (experiments/PROTOCOL.md).", "",
        md_table(["network", "architecture", "head evals / pixel", "GFLOP / frame", "warm s",
                  "> 3 px % select", "> 3 px % val", "D1 % val"], table), "",
        f"Choice (lowest selection error among those ≤ {TIME_LIMIT_S:g} s, ties within {TIE_POINTS} points "
        f"to the faster): **{chosen['name'] if chosen else 'none'}**; validation "
        f"{chosen['val'] if chosen else float('nan'):.2f} % against the limit {BEST_LIMIT:.2f} % for `best`: "
        f"{'becomes best' if becomes_best else 'does not become best'}.", "",
        "GFLOP: tower of both views, the head's split first layer per pixel and view, and the head "
        "layers after it at every evaluated candidate (`stereojax.models.nets.network_flops`); the census "
        "candidate chain, CBCA and SGM are not network FLOP.",
    ])
    write_outputs(setup, "compressed", data, text)


if __name__ == "__main__":
    main()
