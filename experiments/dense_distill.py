"""Dense distillation on the band chain (issue 26): students that learn the shipped full KITTI
model's cost at every disparity of each pixel's band, and the speed/accuracy curve of the
protocol's points (experiments/PROTOCOL.md, "Dense distillation").

Command:  .venv/bin/python experiments/dense_distill.py        (make dense-distill)
Running time here (2 cores): about 6 s per frame for the teacher's targets (75 frames, cached in
runs/dense_targets/, a killed run keeps the finished frames), about 12 min to train each student
(10 000 steps, cached in runs/full/dense/<name>, resumable), then about 2 min to score each point
(bench frame, 000016-000020, 000021-000030). Writes experiments/results/dense_distill.{json,md}
and the curve dense_distill.png: architecture, band K, head evaluations per pixel, GFLOP per frame,
warm seconds on the bench frame (KITTI 2015 000021), > 3 px on the selection fold (decides) and on
the validation frames (reported), beside the full network, the census chain and OpenCV SGBM.

--quick: a tiny student trained a few steps on the targets of two cropped frames, scored on a crop.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from common import QUICK_CROP, Setup, add_common_args, load_sample, md_table, write_outputs
from compressed import FRAMES, QUICK_FRAMES, TIE_POINTS, TIME_LIMIT_S, score

from stereojax.app.bench import warm_chain
from stereojax.learning.dense_distill import cache_targets, load_targets
from stereojax.app.evaluation import chain_method, evaluate_frames, sgbm_method
from stereojax.data.images import as_grey
from stereojax.models.registry import learned_config, load_model, shipped_weights
from stereojax.models.nets import NetConfig, network_flops
from stereojax.learning.train import fit, train_preset

#: students: (name, tower maps, head widths, start from, learning rate[, tower layers (default 4)])
STUDENTS = [
    ("f16_w64-32_dense", 16, (64, 32), "kitti2015_compact", 0.005),
    ("f32_w128-64_dense", 32, (128, 64), None, 0.02),
    # second round (PROTOCOL, 'Dense distillation'): head widths and tower depth
    ("f16_w32-16_dense", 16, (32, 16), None, 0.02),
    ("f16_l3_w64-32_dense", 16, (64, 32), None, 0.02, 3),
]
#: chain points of the curve: (label, student, head evaluations per pixel, band K)
POINTS = [
    ("f16_w64-32_dense, 16 evals", "f16_w64-32_dense", 16, 48),
    ("f16_w64-32_dense, 8 evals", "f16_w64-32_dense", 8, 48),
    ("f16_w64-32_dense, 16 evals, K 32", "f16_w64-32_dense", 16, 32),
    ("f32_w128-64_dense, 16 evals", "f32_w128-64_dense", 16, 48),
    ("f16_w32-16_dense, 16 evals", "f16_w32-16_dense", 16, 48),
    ("f16_l3_w64-32_dense, 16 evals", "f16_l3_w64-32_dense", 16, 48),
    ("kitti2015_compact (shipped, patch distillation), 16 evals", "kitti2015_compact", 16, 48),
]
STEPS = 10000
PIXELS = 12000
BEST_LIMIT = 4.03 + 0.05      # protocol: the banded full network + 0.05 points
QUICK_DISP = 48


def unlabeled(data: Path) -> list[tuple[str, Path, Path]]:
    from stereojax.data.pairs import folder_pairs

    root = data / "unlabeled" / "kitti"
    return folder_pairs(root / "left", root / "right") if (root / "left").is_dir() else []


def target_frames(setup: Setup, frames) -> list:
    """(name, load) of the frames the teacher labels: the training frames and the unlabeled pairs."""
    from stereojax.data.datasets import load_pair

    out = []
    for f in frames["train"]:
        def load(f=f):
            s = load_sample(str(setup.data), "kitti2015", f, "noc")
            s = s.crop(*QUICK_CROP) if setup.quick else s
            return as_grey(s.left, "left"), as_grey(s.right, "right")
        out.append((f"kitti2015_{f}", load))
    for name, lp, rp in ([] if setup.quick else unlabeled(setup.data)):
        def load(lp=lp, rp=rp):
            s = load_pair(lp, rp)
            return as_grey(s.left, "left"), as_grey(s.right, "right")
        out.append((f"unlabeled_{Path(name).stem}", load))
    return out


def chain(max_disp: int, evals: int, k: int):
    """The `kitti2015` card with ``evals`` head evaluations per pixel and bands of ``k``."""
    cfg = learned_config("kitti2015", max_disp)
    return dataclasses.replace(cfg, cost=dataclasses.replace(cfg.cost, candidates=min(evals, k), unsure_share=0.0,
                                                             unsure_candidates=0),
                               band=dataclasses.replace(cfg.band, width=min(k, max_disp - 1))).validate()


def train_student(setup, frames, dense, name, features, widths, init, lr, layers: int = 4) -> Path:
    net = NetConfig(features=features, layers=layers, widths=tuple(widths)).validate()
    if setup.quick:
        cfg = train_preset("tiny", net=net, steps=setup.steps, val_every=setup.steps, checkpoint_every=setup.steps,
                           dense=1.0, dense_batch=8)
    else:
        cfg = train_preset("cpu", net=net, steps=setup.steps, lr=lr, dense=1.0, dense_batch=64)
    run = setup.runs / "dense" / name
    done = run / "train_summary.json"
    if done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps:
        return run
    print(f"  training {name} ({cfg.steps} steps, dense distillation{', from ' + init if init else ''})", flush=True)
    load = lambda role: [load_sample(str(setup.data), "kitti2015", f, "noc") for f in frames[role]]  # noqa: E731
    start = None
    if init and not setup.quick:
        start = load_model(shipped_weights(init))
    info = {"data": {"dataset": "kitti2015", "frames": frames["train"], "val_frames": frames["select"],
                     "dense_targets": "kitti2015 band targets, training frames + unlabeled pairs"},
            "init": init, "dense_from": "kitti2015"}
    fit(cfg, load("train"), load("select"), run, resume=True, progress=False, info=info, init=start, dense=dense)
    return run


FINAL_STEPS = 90000           # protocol: at least the teacher's schedule


def final_run(setup: Setup, args, teacher) -> None:
    """The protocol's last step: the chosen point's student trained on all 20 labelled frames and
    the unlabeled pairs for FINAL_STEPS, scored once on 000021-000030 against BEST_LIMIT."""
    chosen = json.loads((setup.out / "dense_distill.json").read_text())
    point = next(p for p in POINTS if p[0] == chosen["chosen"])
    label, name, evals, k = point
    spec = next(st for st in STUDENTS if st[0] == name)
    frames = {"train": [f"{i:06d}" for i in range(1, 21)], "select": [f"{i:06d}" for i in range(16, 21)],
              "val": FRAMES["val"]}
    folder = setup.runs / "dense_targets" / "kitti2015_K48"
    files = cache_targets(target_frames(setup, frames), teacher, learned_config("kitti2015", 228), folder,
                          args.pixels)
    dense = load_targets(files)
    steps = args.steps or FINAL_STEPS
    final = Setup(setup.quick, setup.data, steps, setup.candidates, setup.kitti_frames, setup.out,
                  setup.runs / "final")
    run = train_student(final, frames, dense, name, *spec[1:])
    model = load_model(run / "checkpoint.msgpack")
    cfg = chain(228, evals, k)
    val = [load_sample(str(setup.data), "kitti2015", f, "noc") for f in frames["val"]]
    bench = val[0]
    secs = warm_chain(bench.left, bench.right, cfg, model, repeats=2)["warm_s"]
    r_val = score(val, chain_method(cfg, model), 228)
    data = {"point": label, "student": name, "steps": steps, "targets": {"frames": len(files), "pixels": dense.size},
            "seconds": secs, "val": r_val["mean"]["bad3"], "val_d1": r_val["mean"]["d1"], "val_frames": r_val["frames"],
            "best_limit": BEST_LIMIT, "becomes_best": r_val["mean"]["bad3"] <= BEST_LIMIT, "run": str(run)}
    text = "\n".join([
        "# Dense distillation: the chosen student after the protocol's long run", "",
        f"{label}: trained {steps} steps on KITTI 2015 000001-000020 (GT patches) and the teacher's band "
        f"similarities at {dense.size} pixels of {len(files)} frames (those 20 and the unlabeled pairs). "
        f"Validation 000021-000030: > 3 px {data['val']:.2f} %, D1 {data['val_d1']:.2f} %; warm {secs:.2f} s on "
        f"the bench frame. Bound for `best`: {BEST_LIMIT:.2f} % -> "
        f"{'becomes best' if data['becomes_best'] else 'does not become best'}.",
    ])
    write_outputs(final, "dense_distill_final", data, text)


def main():
    ap = add_common_args(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    ap.add_argument("--pixels", type=int, default=PIXELS, help="target pixels per frame")
    ap.add_argument("--final", action="store_true", help="the protocol's last step for the chosen point: train on "
                    "all 20 labelled frames and the unlabeled pairs (90 000 steps), score 000021-000030")
    args = ap.parse_args()
    if args.final:
        setup = Setup.from_args(args)
        return final_run(setup, args, load_model(shipped_weights("kitti2015")))
    if args.steps is None and not args.quick:
        args.steps = STEPS
    setup = Setup.from_args(args)
    frames = QUICK_FRAMES if setup.quick else FRAMES
    md = QUICK_DISP if setup.quick else 228
    teacher = load_model(shipped_weights("kitti2015"))
    teacher_cfg = chain(md, 16, 16 if setup.quick else 48)
    teacher_cfg = learned_config("kitti2015", md) if not setup.quick else teacher_cfg
    folder = setup.runs / "dense_targets" / f"kitti2015_K{teacher_cfg.band.width}"
    files = cache_targets(target_frames(setup, frames), teacher, teacher_cfg, folder,
                          200 if setup.quick else args.pixels)
    dense = load_targets(files)
    print(f"  {dense.size} target pixels of {len(files)} frames, K = {dense.width}", flush=True)

    def samples(role):
        out = [load_sample(str(setup.data), "kitti2015", f, "noc") for f in frames[role]]
        return [s.crop(*QUICK_CROP) for s in out] if setup.quick else out

    sel, val = samples("select"), samples("val")
    bench = val[0]
    h, w = bench.left.shape[:2]
    points = POINTS[:4:3] if setup.quick else POINTS                         # quick: two points
    used = {p[1] for p in points}
    models = {"kitti2015_compact": load_model(shipped_weights("kitti2015_compact"))}
    for name, features, widths, init, lr, *layers in (st for st in STUDENTS if st[0] in used):
        if setup.quick:
            features, widths = 4, (8, 4)
        models[name] = load_model(train_student(setup, frames, dense, name, features, widths, init, lr, *layers)
                                  / "checkpoint.msgpack")
    rows = []
    for label, name, evals, k in points:
        if setup.quick:
            k = min(k, 16)
        model, cfg = models[name], chain(md, evals, k)
        predict = chain_method(cfg, model)
        secs = warm_chain(bench.left, bench.right, cfg, model, repeats=2)["warm_s"]
        r_sel, r_val = score(sel, predict, md), score(val, predict, md)
        rows.append({"name": label, "student": name, "features": model.net.features, "layers": model.net.layers,
                     "widths": list(model.net.widths),
                     "band_k": cfg.band.width, "evals_per_pixel": cfg.cost.candidates,
                     "gflop": network_flops(model.net, h, w, cfg.cost.candidates) / 1e9, "seconds": secs,
                     "select": r_sel["mean"]["bad3"], "val": r_val["mean"]["bad3"], "val_d1": r_val["mean"]["d1"],
                     "select_frames": r_sel["frames"], "val_frames": r_val["frames"]})
        print(f"  {label}: {rows[-1]['gflop']:.3g} GFLOP, {secs:.2f} s, > 3 px select {rows[-1]['select']:.2f} %, "
              f"val {rows[-1]['val']:.2f} %", flush=True)
    # the anchors of the curve, timed in the same run
    full_cfg = learned_config("kitti2015", md)
    c = full_cfg.cost
    evals = c.candidates + c.unsure_share * (c.unsure_candidates - c.candidates)
    full = {"name": "full network (shipped kitti2015)", "gflop": network_flops(teacher.net, h, w, evals) / 1e9,
            "seconds": warm_chain(bench.left, bench.right, full_cfg, teacher, repeats=1)["warm_s"],
            "val": score(val, chain_method(full_cfg, teacher), md)["mean"]["bad3"]}
    import stereojax

    census_cfg = stereojax.preset("census", md)
    census = {"name": "census chain", "seconds": warm_chain(bench.left, bench.right, census_cfg, None, repeats=2)["warm_s"],
              "val": score(val, chain_method(census_cfg), md)["mean"]["bad3"]}
    r_sgbm = evaluate_frames(val, {"sgbm": sgbm_method(pad=True)}, md)
    sgbm = {"name": "OpenCV StereoSGBM", "val": r_sgbm["mean"]["sgbm"]["bad3"],
            "seconds": float(np.median([r["sgbm"]["seconds"] for r in r_sgbm["frames"]]))}
    fast = [r for r in rows if r["seconds"] <= TIME_LIMIT_S]
    chosen = None
    if fast:
        low = min(r["select"] for r in fast)
        chosen = min([r for r in fast if r["select"] <= low + TIE_POINTS], key=lambda r: r["seconds"])
    data = {"rows": rows, "full": full, "census": census, "sgbm": sgbm, "chosen": chosen["name"] if chosen else None,
            "rules": {"time_limit_s": TIME_LIMIT_S, "tie_points": TIE_POINTS, "best_limit": BEST_LIMIT},
            "targets": {"frames": len(files), "pixels": dense.size, "band_k": dense.width}, "frames": frames,
            "max_disp": md}
    table = [[r["name"], f"tower {r['features']}{'' if r.get('layers', 4) == 4 else ' x ' + str(r['layers']) + ' layers'}, "
              f"head {'-'.join(map(str, r['widths']))}", str(r["band_k"]),
              str(r["evals_per_pixel"]), f"{r['gflop']:.3g}", f"{r['seconds']:.2f}", f"{r['select']:.2f}",
              f"{r['val']:.2f}"] for r in rows]
    table += [[full["name"], "tower 64, head 512-384-256-128", "48", f"{evals:g}", f"{full['gflop']:.3g}",
               f"{full['seconds']:.2f}", "(trained on them)", f"{full['val']:.2f}"],
              [census["name"], "-", "48", "-", "-", f"{census['seconds']:.2f}", "-", f"{census['val']:.2f}"],
              [sgbm["name"], "-", "-", "-", "-", f"{sgbm['seconds']:.3f}", "-", f"{sgbm['val']:.2f}"]]
    _plot(setup, rows, [full, census, sgbm])
    where = "a crop of " if setup.quick else ""
    text = "\n".join([
        "# Dense distillation on the band chain: speed against accuracy (KITTI 2015, 2 CPU cores)", "",
        f"Students trained on the GT patches of {frames['train'][0]}-{frames['train'][-1]} plus the teacher's "
        f"band similarities at {dense.size} pixels of {len(files)} frames (those frames and the unlabeled pairs), "
        f"{setup.steps} steps; the `kitti2015` card with the given head evaluations and band K. Seconds: warm, "
        f"whole chain, on {where}the bench frame {bench.name} ({w}x{h}, {md} disparities), all in one run. "
        "> 3 px: non-occluded GT; the selection fold decides, the validation frames are reported "
        "(experiments/PROTOCOL.md, 'Dense distillation').", "",
        md_table(["point", "network", "K", "head evals / pixel", "GFLOP / frame", "warm s", "> 3 px % select",
                  "> 3 px % val"], table), "",
        f"Choice on the selection fold (≤ {TIME_LIMIT_S:g} s, ties within {TIE_POINTS} points to the faster): "
        f"**{chosen['name'] if chosen else 'none'}**. It becomes `best` only after the protocol's long run on "
        f"all 20 labelled frames, if its validation error is at most {BEST_LIMIT:.2f} %.", "",
        "![speed against accuracy](dense_distill.png)" if not setup.quick else "",
    ])
    write_outputs(setup, "dense_distill", data, text)


#: the students' colours: none of the anchors' (red, green, grey)
STUDENT_COLOURS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:cyan")


def _plot(setup, rows, anchors) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.2, 4.6))
    markers = "ovD^<>phX*"
    for i, r in enumerate(rows):          # one marker per point, named in the legend (labels would overlap)
        ax.scatter([r["seconds"]], [r["val"]], marker=markers[i % len(markers)], c=STUDENT_COLOURS[i % 6],
                   label=r["name"].replace(" (shipped, patch distillation)", " (shipped)"))
    for a, colour in zip(anchors, ("tab:red", "tab:green", "tab:gray")):
        ax.scatter([a["seconds"]], [a["val"]], c=colour, marker="s", label=a["name"])
    anchors_file = Path(setup.out) / "anchors.json"          # make bench-anchors: CNES Pandora, its own run
    if anchors_file.is_file() and not setup.quick:
        secs = json.loads(anchors_file.read_text()).get("pandora_s")
        if isinstance(secs, (int, float)):
            ax.axvline(float(secs), color="tab:purple", ls="--", lw=1,
                       label=f"CNES Pandora MC-CNN, bench frame ({float(secs):.1f} s, its own run)")
    ax.set_xscale("log")
    ax.set_xlabel("warm seconds per KITTI frame (2 CPU cores, log)")
    ax.set_ylabel("> 3 px error, % (KITTI 2015 000021-000030)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    name = "dense_distill_quick.png" if setup.quick else "dense_distill.png"
    fig.savefig(Path(setup.out) / name, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
