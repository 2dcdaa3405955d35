"""Middlebury with folds: every dev scene scored by a model and chain settings that never saw it
(issue "accuracy", part 4; protocol in experiments/PROTOCOL.md).

Command:  .venv/bin/python experiments/middlebury_folds.py [--steps 3000] [--lr 0.005] [--rounds 1]
              [--out experiments/results] [--runs runs/middlebury_folds] [--quick]
Per fold: fine-tune the KITTI 2015 model --init (default the shipped one; it saw no Middlebury scene) on the GT of the
other folds' scenes (all-pixel GT, the `cpu` preset's sampler and batch, --steps SGD steps at
--lr with the preset's late decay); search the learned chain's settings on those training
scenes' cached volumes (experiments/search_chain.py, a smaller space; Aloe, 1282x1110 with 234
disparities, is left out of the search for time, not of the training); then score the fold's
held-out scenes with `--method best`'s pruned adaptive head and the searched settings. OpenCV
StereoSGBM (left-padded) and the census chain are scored on the same scenes in the same run.
Writes OUT/middlebury_folds_neutral.{md,json} (middlebury_folds.* with --border replicate). Running time here (2 cores): about 18 min per fold.

--student (issue 26; experiments/PROTOCOL.md, "The Middlebury student of issue 26"): per fold the
teacher is fine-tuned as above (its search and scoring are skipped), its band similarities are
cached at STUDENT_PIXELS pixels of each banded training scene (runs/.../fold*_targets, resumable),
and the shipped `kitti2015_compact` is fine-tuned on the GT patches plus those targets, its chain
settings searched and its held-out scenes scored beside census and SGBM ->
OUT/middlebury_folds_student.{md,json}.

--cascade Q[,Q...] (issue 38, item 4; PROTOCOL.md, "The Middlebury cascade of issue 38"): as
--student, and each held-out scene is also scored by the cascade (the fold student everywhere, the
fold teacher's head at the share Q of least-confident pixels; stereojax.matching_cost.cascade) at
every Q, with the student's searched settings, and by the fold teacher with the preset settings
(the full network's time in the same run) -> OUT/middlebury_folds_cascade.{md,json}.
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np


from common import DEFAULT_DATA, ROOT, load_sample, md_table  # noqa: E402
from search_chain import SPACE_SMALL as SPACE, cache_volumes, changes, coordinate_search  # noqa: E402

import stereojax  # noqa: E402
from stereojax.data.datasets import search_range  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.app.evaluation import chain_method, evaluate_frames, sgbm_method  # noqa: E402
from stereojax.learning.dense_distill import cache_targets, load_targets  # noqa: E402
from stereojax.data.images import as_grey  # noqa: E402
from stereojax.models.registry import load_model, shipped_weights, weights_path  # noqa: E402
from stereojax.learning.train import fit, train_preset  # noqa: E402
from stereojax.matching_cost.cascade import Cascade  # noqa: E402

#: three folds, balanced by pixels; every scene is held out exactly once
FOLDS = [["Aloe_opencv", "Venus_2001"],
         ["Reindeer_2006H", "Cones_2003Q", "Tsukuba_2001"],
         ["Motorcycle_MiddEval3Q", "Teddy_2003Q"]]
NO_SEARCH = {"Aloe_opencv"}
#: --quick: the scenes are cropped to this many rows x columns (bottom centre)
QUICK_SCENE = (160, 224)
KEYS = ("bad2", "bad3", "bad4", "epe")
#: the student of --student: the shipped compact KITTI model, fine-tuned per fold
STUDENT_INIT = "kitti2015_compact"
STUDENT_PIXELS = 20000
#: the fold record of the full network (middlebury_folds_neutral.md): the student's bar
STUDENT_BAR = 4.58
#: --cascade: the full network's head evaluations per re-scored pixel (as on KITTI)
CASCADE_CANDIDATES = 16


def cascade_shares(text: str) -> list[float]:
    """--cascade's value: comma-separated shares q in (0, 1], checked before any fold is trained."""
    try:
        shares = [float(q) for q in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"takes shares like 0.05,0.1,0.2, got {text!r}") from None
    if not all(0.0 < q <= 1.0 for q in shares):
        raise argparse.ArgumentTypeError(f"each share q must lie in (0, 1], got {text!r}")
    return shares


def cascade_key(q: float) -> str:
    """The name of the cascade at share q in the record's methods."""
    return f"cascade {100 * q:g} %"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--lr", type=float, default=0.005)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--init", default="kitti2015",
                    help="the common pre-trained model every fold starts from: a shipped name or a "
                         "checkpoint (the recorded run used the 50 000-step KITTI model, which "
                         "`make train` writes to runs/kitti2015_downsize/checkpoint.msgpack)")
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    ap.add_argument("--runs", default=str(ROOT / "runs" / "middlebury_folds"))
    ap.add_argument("--quick", action="store_true", help="tiny smoke test: 2 small scenes, 2 steps, 1 setting")
    ap.add_argument("--student", action="store_true",
                    help="issue 26: score a compact student distilled from each fold's teacher (see above)")
    ap.add_argument("--border", default="neutral", choices=["replicate", "neutral"],
                    help="cost.border of the learned chain (the out-of-view strip, neutral as in the shipped cards; "
                         "replicate is written as middlebury_folds.*, the earlier record)")
    ap.add_argument("--cascade", type=cascade_shares, default=None,
                    help="issue 38: also score the cascade at these shares q of re-scored pixels, e.g. "
                         "0.05,0.1,0.2,0.4 (implies --student)")
    args = ap.parse_args()
    if args.cascade:
        args.student = True
    folds = [["Tsukuba_2001"], ["Venus_2001"]] if args.quick else FOLDS
    space = SPACE[:1] if args.quick else SPACE
    if args.quick:      # a bottom-centre crop of each scene: the smoke test runs every step, at a smaller size
        load = lambda name: load_sample(args.data, "middlebury", name, "occ").crop(*QUICK_SCENE)  # noqa: E731
    else:
        load = lambda name: load_sample(args.data, "middlebury", name, "occ")  # noqa: E731
    base = stereojax.preset("learned")
    base = dataclasses.replace(base, cost=dataclasses.replace(base.cost, border=args.border)).validate()
    kitti = load_model(weights_path(args.init))
    init_tag = "" if args.init == "kitti2015" else "_" + Path(args.init).resolve().parent.name
    rows, fold_info = [], []
    for i, held in enumerate(folds):
        train_names = [n for f in folds for n in f if n not in held]
        run = Path(args.runs) / f"fold{i}_s{args.seed}_{'quick' if args.quick else args.steps}{init_tag}"
        cfg = train_preset("cpu", seed=args.seed, steps=2 if args.quick else args.steps, lr=args.lr,
                           checkpoint_every=500, val_every=10 ** 9, log_every=50)
        done = run / "train_summary.json"
        t0 = time.perf_counter()
        if not (done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps):
            print(f"fold {i}: fine-tuning on {', '.join(train_names)} ({cfg.steps} steps)", flush=True)
            fit(cfg, [load(n) for n in train_names], None, run, resume=True, progress=False, init=kitti,
                info={"data": {"dataset": "middlebury", "frames": train_names, "val_frames": []},
                      "init": args.init})
        model = load_model(run / "checkpoint.msgpack")
        train_s = time.perf_counter() - t0
        teacher = model
        if args.student:
            model, base_i, train_s, dense_info = fold_student(args, i, run, model, base, train_names, load)
        else:
            base_i, dense_info = base, {}
        search_names = [n for n in train_names if n not in NO_SEARCH]
        cache = cache_volumes([load(n) for n in search_names], model, base_i,
                              lambda s: search_range("middlebury", s, None))
        best, best_err, start_err, log = coordinate_search(cache, base_i, space, args.rounds, "bad2+bad3")
        del cache
        fold_info.append({"fold": i, "held_out": held, "train": train_names, "searched_on": search_names,
                          "search_start": start_err, "search_best": best_err, "changes": changes(base_i, best),
                          "train_seconds": train_s, "config": best.to_dict(), "trials": log, **dense_info})
        print(f"fold {i}: settings {changes(base_i, best) or 'preset'} ({start_err:.2f} -> {best_err:.2f} "
              "mean of > 2 / > 3 px on its training scenes)", flush=True)
        methods = {"learned": chain_method(best, model)}
        if args.cascade:        # the student with its preset settings was recorded by --student
            methods.update({cascade_key(q): chain_method(best, model, cascade=Cascade(
                teacher, q, CASCADE_CANDIDATES).check()) for q in args.cascade})
            methods["full_preset"] = chain_method(base, teacher)
        else:
            methods["learned_preset"] = chain_method(base_i, model)
        methods.update({"census": chain_method(stereojax.preset("census")), "sgbm": sgbm_method(pad=True)})
        result = evaluate_frames([load(name) for name in held], methods, lambda s: search_range("middlebury", s, None))
        for r in result["frames"]:
            row = {"scene": r["frame"], "fold": i, "max_disp": r["max_disp"], **{m: r[m] for m in methods}}
            rows.append(row)
            print(f"  {row['scene']}: learned {row['learned']['bad2']:.2f} / {row['learned']['bad3']:.2f}, "
                  f"SGBM {row['sgbm']['bad2']:.2f} / {row['sgbm']['bad3']:.2f} (> 2 / > 3 px %)", flush=True)

    who = "student" if args.student else "model"
    methods = [("learned", f"fine-tuned {who} + fold's searched settings"),
               ("learned_preset", f"fine-tuned {who}, preset settings"),
               ("census", "census chain"), ("sgbm", "OpenCV SGBM, left-padded")]
    if args.cascade:
        methods = ([("learned", "student + fold's searched settings")]
                   + [(cascade_key(q), f"cascade q = {100 * q:g} %") for q in args.cascade]
                   + [("full_preset", "fold teacher (full network), preset settings")] + methods[2:])
    mean = {m: {k: float(np.mean([r[m][k] for r in rows])) for k in KEYS} for m, _ in methods}

    def mean_s(m):
        return float(np.mean([r[m]["seconds"] for r in rows]))
    table = [[r["scene"], r["fold"], r["max_disp"]] + [f"{r[m]['bad2']:.2f} / {r[m]['bad3']:.2f}" for m, _ in methods]
             for r in rows]
    table.append(["**mean**", "", ""] + [f"**{mean[m]['bad2']:.2f} / {mean[m]['bad3']:.2f}**" for m, _ in methods])
    if args.cascade:
        table.append(["**mean warm s**", "", ""] + [f"{mean_s(m):.2f}" for m, _ in methods])
        title, verdict = cascade_title(args, cfg, mean, mean_s)
    elif args.student:
        title = ("# Middlebury with folds: the compact student of issue 26 (> 2 px / > 3 px %, all-pixel GT)\n\n"
                 f"Each scene scored by `{STUDENT_INIT}` fine-tuned on the other folds' scenes (GT patches, "
                 f"{cfg.steps} steps, lr {args.lr}) with dense distillation from that fold's teacher (`{args.init}` "
                 f"fine-tuned the same way; band similarities at {200 if args.quick else STUDENT_PIXELS} pixels of each banded training "
                 "scene), 16 head evaluations per pixel, its chain settings searched on the training scenes. "
                 f"Mean warm seconds per scene: student {mean_s('learned'):.2f} s, census {mean_s('census'):.2f} s, "
                 f"SGBM {mean_s('sgbm'):.3f} s (2 CPU cores, this run). Rule (PROTOCOL.md): the student becomes "
                 f"`best` for Middlebury if its mean > 3 px is at most {STUDENT_BAR:.2f} % (the full network's fold "
                 f"record): **{mean['learned']['bad3']:.2f} % -> "
                 f"{'it does' if mean['learned']['bad3'] <= STUDENT_BAR else 'it does not'}**.\n\n")
    else:
        title = ("# Middlebury dev scenes with folds (> 2 px / > 3 px %, all-pixel GT)\n\n"
                 f"Each scene scored by a model fine-tuned from the KITTI model `{args.init}` ({cfg.steps} steps, "
                 f"lr {args.lr}) on the other folds' scenes, with chain settings searched on those scenes; "
                 f"out-of-view strip of the learned chain: `cost.border {args.border}`.\n\n")
    md = (title
          + md_table(["scene", "fold", "disparities"] + [label for _, label in methods], table) + "\n\n"
          + "\n".join(f"* fold {f['fold']} (held out {', '.join(f['held_out'])}): settings "
                      f"{f['changes'] or 'the preset'} (searched on {', '.join(f['searched_on'])}: "
                      f"{f['search_start']:.2f} -> {f['search_best']:.2f})" for f in fold_info) + "\n")
    if args.cascade:
        stem = "middlebury_folds_cascade" + ("_quick" if args.quick else "")
    elif args.student:
        stem = "middlebury_folds_student" + ("_quick" if args.quick else "")
    elif args.quick:
        stem = "middlebury_folds_quick"
    else:   # replicate: the name of the earlier record
        stem = "middlebury_folds" + ("" if args.border == "replicate" else f"_{args.border}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / f"{stem}.json", {"steps": cfg.steps, "lr": args.lr, "seed": args.seed, "folds": fold_info,
                                      "scenes": rows, "mean": mean, "student": args.student,
                                      **({"student_bar": STUDENT_BAR,
                                          "becomes_best": mean["learned"]["bad3"] <= STUDENT_BAR,
                                          "seconds": {m: mean_s(m) for m, _ in methods}} if args.student else {}),
                                      **({"cascade": args.cascade, "candidates": CASCADE_CANDIDATES,
                                          "rule": verdict} if args.cascade else {})})
    (out / f"{stem}.md").write_text(md + f"\nCommand: `python experiments/middlebury_folds.py {' '.join(sys.argv[1:])}`\n")
    print(md)


def cascade_title(args, cfg, mean, mean_s):
    """--cascade: the record's title and the rule's verdict (PROTOCOL.md, "The Middlebury cascade
    of issue 38"): the smallest q at <= STUDENT_BAR mean > 3 px whose mean warm time is at most a
    third of the fold teacher's."""
    full_s = mean_s("full_preset")
    rows = [{"q": q, "bad3": mean[cascade_key(q)]["bad3"], "seconds": mean_s(cascade_key(q))}
            for q in sorted(args.cascade)]
    accurate = [r for r in rows if r["bad3"] <= STUDENT_BAR]
    chosen = accurate[0] if accurate else None
    passes = chosen is not None and chosen["seconds"] <= full_s / 3
    if chosen is None:
        sentence = (f"no q reaches {STUDENT_BAR:.2f} % (the best is {min(r['bad3'] for r in rows):.2f} %), "
                    "so `best` for non-road pairs stays the full network")
    elif passes:
        sentence = (f"q = {100 * chosen['q']:g} % reaches {chosen['bad3']:.2f} % in {chosen['seconds']:.2f} s, at most "
                    f"a third of the fold teacher's {full_s:.2f} s: `best` for non-road pairs becomes the cascade")
    else:
        sentence = (f"the smallest q at <= {STUDENT_BAR:.2f} % is {100 * chosen['q']:g} % ({chosen['bad3']:.2f} %), "
                    f"and it takes {chosen['seconds']:.2f} s against the allowed {full_s / 3:.2f} s (a third of the "
                    f"fold teacher's {full_s:.2f} s): it misses by {chosen['seconds'] - full_s / 3:.2f} s, so `best` "
                    "for non-road pairs stays the full network")
    title = ("# Middlebury with folds: the cascade of issue 38 (> 2 px / > 3 px %, all-pixel GT)\n\n"
             f"Per fold, the student of issue 26 (`{STUDENT_INIT}` fine-tuned {cfg.steps} steps with dense distillation "
             f"from the fold teacher, its chain settings searched on the training scenes) runs everywhere; at the share q "
             f"of its least-confident real pixels the fold teacher (`{args.init}` fine-tuned the same way) re-scores "
             f"its {CASCADE_CANDIDATES} best census candidates, and the student's chain runs once more on the mixed "
             "volume. The fold teacher with the learned preset settings gives the full network's time in this run "
             f"(its searched-settings fold record, {STUDENT_BAR:.2f} %, is the bar). Last row: mean warm seconds per "
             "scene (2 CPU cores, this run).\n\n"
             f"**The rule** (PROTOCOL.md, \"The Middlebury cascade of issue 38\"): {sentence}.\n\n")
    return title, {"chosen_q": chosen["q"] if chosen else None, "passes": passes, "full_seconds": full_s,
                   "allowed_seconds": full_s / 3, "curve": rows, "sentence": sentence}


def fold_student(args, i, teacher_run, teacher, base, train_names, load):
    """--student: the fold teacher's band targets on the training scenes, then the shipped compact
    model fine-tuned on their GT patches plus those targets. Returns (student, its base chain,
    training seconds, what the fold record says about the targets)."""
    t0 = time.perf_counter()
    width = 8 if args.quick else base.band.width        # quick: the small scenes are narrower than K = 48
    folder = teacher_run.parent / f"{teacher_run.name}_targets_K{width}"
    files = []
    for name in train_names:
        s = load(name)
        md = search_range("middlebury", s, None)
        if md <= width:                                 # not banded: GT patches only
            continue
        cfg = dataclasses.replace(base, max_disp=md, band=dataclasses.replace(base.band, width=width)).validate()
        files += cache_targets([(name, lambda s=s: (as_grey(s.left, "left"), as_grey(s.right, "right")))],
                               teacher, cfg, folder, 200 if args.quick else STUDENT_PIXELS, progress=False)
    dense = load_targets(files) if files else None
    compact = load_model(shipped_weights(STUDENT_INIT))
    cfg = train_preset("cpu", net=compact.net, seed=args.seed, steps=2 if args.quick else args.steps, lr=args.lr,
                       checkpoint_every=500, val_every=10 ** 9, log_every=50, dense=1.0 if files else 0.0,
                       dense_batch=8 if args.quick else 64)
    run = teacher_run.parent / f"{teacher_run.name}_student"
    done = run / "train_summary.json"
    if not (done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps):
        print(f"fold {i}: student {STUDENT_INIT} on {', '.join(train_names)} + "
              f"{dense.size if dense else 0} teacher target pixels ({cfg.steps} steps)", flush=True)
        fit(cfg, [load(n) for n in train_names], None, run, resume=True, progress=False, init=compact, dense=dense,
            info={"data": {"dataset": "middlebury", "frames": train_names, "val_frames": [],
                           "dense_targets": [f.stem for f in files]},
                  "init": STUDENT_INIT, "dense_from": str(teacher_run)})
    c = base.cost
    student_base = dataclasses.replace(base, cost=dataclasses.replace(c, candidates=16, unsure_share=0.0,
                                                                      unsure_candidates=0)).validate()
    info = {"student_init": STUDENT_INIT, "target_scenes": [f.stem for f in files],
            "target_pixels": dense.size if dense else 0, "target_k": width}
    return load_model(run / "checkpoint.msgpack"), student_base, time.perf_counter() - t0, info


if __name__ == "__main__":
    main()
