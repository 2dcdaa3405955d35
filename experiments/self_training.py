"""Self-training on the unlabeled KITTI pairs (protocol: experiments/PROTOCOL.md, "Self-training").

1. Label: the shipped chain (`best` = `kitti2015` with its card, confidence on) runs on every
   pair of ``--data``/unlabeled/kitti; the pixels whose confidence is at least the pair's median
   are kept, ``--per-pair`` of them drawn at random (seed 0), with their disparity
   (RUNS/labels/<id>.npz; a pair already labelled is not run again).
2. Train: the shipped model fine-tuned ``--steps`` steps (cpu preset, ``--lr``, decay 0.1 from
   75 %) on the GT of KITTI 2015 000001-000020 together with the pseudo-labels (RUNS/student/;
   a finished run is not trained again, an interrupted one resumes).
3. Score, once: the student and the teacher with the card's chain settings, and OpenCV SGBM
   (left-padded), on KITTI 2015 000021-000030 (non-occluded GT), KITTI 2015 000001 and KITTI 2012
   000000 (all-pixel GT), in one run.

Command:  .venv/bin/python experiments/self_training.py [--data ../shared/data] [--steps 15000]
              [--lr 0.005] [--per-pair 30000] [--runs runs/self_training] [--out experiments/results]
              [--quick]
Running time here (2 cores): about 16 min of labelling, 18 min of training, 8 min of scoring.
Writes OUT/self_training.{md,json}.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from common import DEFAULT_DATA, ROOT, md_table  # noqa: E402

import stereojax  # noqa: E402
from stereojax.data.datasets import StereoSample, load_dataset, load_pair, search_range  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.data.pairs import folder_pairs  # noqa: E402
from stereojax.app.evaluation import chain_method, evaluate_frames, sgbm_method  # noqa: E402
from stereojax.models.registry import learned_config, load_model, weights_path  # noqa: E402
from stereojax.learning.train import fit, train_preset  # noqa: E402

TEACHER = "kitti2015"
KEYS = ("bad2", "bad3", "d1", "epe")


def unlabeled_pairs(data: Path) -> list[tuple[str, Path, Path]]:
    """(id, left, right) of the unlabeled KITTI pairs, matched by file name."""
    root = data / "unlabeled" / "kitti"
    if not (root / "left").is_dir() or not (root / "right").is_dir():
        sys.exit(f"self_training: no unlabeled pairs at {root} (left/ and right/)")
    return folder_pairs(root / "left", root / "right")


def label(pairs, teacher, folder: Path, per_pair: int, crop, max_disp) -> None:
    """Pseudo-labels of every pair (the confident half, ``per_pair`` drawn), written once."""
    folder.mkdir(parents=True, exist_ok=True)
    todo = [p for p in pairs if not (folder / f"{p[0]}.npz").is_file()]
    for name, left, right in tqdm(todo, desc="labelling", unit="pair", file=sys.stderr):
        s = crop(load_pair(left, right))
        cfg = learned_config(TEACHER, max_disp or search_range("kitti2015", s, None))
        disp, conf = stereojax.Predictor(cfg, teacher, confidence=True)(s.left, s.right)
        keep = np.flatnonzero((conf >= np.median(conf)).ravel())
        rng = np.random.default_rng(0)
        pick = np.sort(rng.choice(keep, size=min(per_pair, keep.size), replace=False))
        ys, xs = np.unravel_index(pick, disp.shape)
        tmp = folder / f".{name}.npz"
        np.savez(tmp, y=ys.astype(np.int32), x=xs.astype(np.int32), d=disp[ys, xs].astype(np.float32),
                 shape=np.array(disp.shape), median_confidence=np.median(conf))
        tmp.replace(folder / f"{name}.npz")


def pseudo_sample(name, left, right, labels: Path, crop) -> StereoSample:
    s = crop(load_pair(left, right))
    z = np.load(labels / f"{name}.npz")
    gt = np.zeros(tuple(z["shape"]), np.float32)
    gt[z["y"], z["x"]] = z["d"]
    valid = np.zeros(gt.shape, bool)
    valid[z["y"], z["x"]] = True
    return StereoSample(name=f"pseudo_{name}", left=s.left, right=s.right, gt=gt, gt_valid=valid & (gt > 0))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--steps", type=int, default=15000)
    ap.add_argument("--lr", type=float, default=0.005)
    ap.add_argument("--per-pair", type=int, default=30000)
    ap.add_argument("--runs", default=str(ROOT / "runs" / "self_training"))
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    ap.add_argument("--quick", action="store_true", help="smoke test: 2 pairs, 2 steps, 1 frame each, crops")
    args = ap.parse_args()
    data, runs = Path(args.data), Path(args.runs)
    pairs = unlabeled_pairs(data)[:2] if args.quick else unlabeled_pairs(data)
    crop = (lambda s: s.crop(128, 320)) if args.quick else (lambda s: s)
    quick_disp = 64 if args.quick else None
    teacher = load_model(weights_path(TEACHER))
    t0 = time.perf_counter()
    labels_dir = runs / ("labels_quick" if args.quick else "labels")
    label(pairs, teacher, labels_dir, args.per_pair, crop, quick_disp)
    label_s = time.perf_counter() - t0

    gt_frames = ["000001"] if args.quick else [f"{i:06d}" for i in range(1, 21)]
    train = [crop(load()) for _, load in load_dataset(data, "kitti2015", gt_frames, gt="noc")]
    n_gt = int(sum(s.gt_valid.sum() for s in train))
    train += [pseudo_sample(n, l, r, labels_dir, crop) for n, l, r in pairs]
    n_pseudo = int(sum(s.gt_valid.sum() for s in train)) - n_gt
    steps = 2 if args.quick else args.steps
    cfg = train_preset("cpu", steps=steps, lr=args.lr, checkpoint_every=1000, val_every=10 ** 9, log_every=50)
    run = runs / ("student_quick" if args.quick else f"student_{steps}")
    done = run / "train_summary.json"
    t0 = time.perf_counter()
    if not (done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps):
        print(f"fine-tuning {TEACHER} on {n_gt} GT + {n_pseudo} pseudo-labelled pixels ({steps} steps)", flush=True)
        fit(cfg, train, None, run, resume=True, progress=True, init=teacher,
            info={"data": {"dataset": "kitti2015", "frames": gt_frames, "val_frames": [],
                           "pseudo_labelled": [p[0] for p in pairs], "per_pair": args.per_pair},
                  "init": TEACHER, "recipe": "self-training, experiments/self_training.py"})
    train_s = time.perf_counter() - t0
    del train
    student = load_model(run / "checkpoint.msgpack")

    card = learned_config(TEACHER)
    methods = {"student": chain_method(card, student), "teacher": chain_method(card, teacher),
               "sgbm": sgbm_method(pad=True)}
    sets = [("KITTI 2015 000021-000030", "kitti2015", ["000021"] if args.quick else
             [f"{i:06d}" for i in range(21, 31)], "noc"),
            ("KITTI 2015 000001 (a training frame)", "kitti2015", ["000001"], "occ"),
            ("KITTI 2012 000000", "kitti2012", ["000000"], "occ")]
    rows = []
    for title, ds, frames, gt in sets:
        items = [crop(load()) for _, load in load_dataset(data, ds, frames, gt=gt)]
        result = evaluate_frames(items, methods, lambda s: quick_disp or search_range(ds, s, None), progress=title)
        rows.append({"set": title, "gt": gt, "frames": frames, "mean": result["mean"],
                     "per_frame": [{"frame": r["frame"], **{m: r[m]["bad3"] for m in methods}}
                                   for r in result["frames"]]})
        print(title, {m: round(result["mean"][m]["bad3"], 2) for m in methods}, flush=True)

    labels = {"student": "self-trained student", "teacher": f"shipped `{TEACHER}` (teacher)",
              "sgbm": "OpenCV SGBM, left-padded"}
    table = [[r["set"], "non-occluded" if r["gt"] == "noc" else "all"]
             + [f"{r['mean'][m]['bad2']:.2f} / {r['mean'][m]['bad3']:.2f}" for m in methods] for r in rows]
    md = ("# Self-training on the unlabeled KITTI pairs (> 2 px / > 3 px %)\n\n"
          f"The shipped `{TEACHER}` chain labelled {len(pairs)} unlabeled pairs (the more confident half of each "
          f"pair's pixels, {args.per_pair} drawn per pair: {n_pseudo} pseudo-labels beside {n_gt} GT pixels of "
          f"KITTI 2015 {gt_frames[0]}-{gt_frames[-1]}); the student is `{TEACHER}` fine-tuned {steps} steps at lr "
          f"{args.lr} on both, run with the teacher's card settings. Protocol: experiments/PROTOCOL.md.\n\n"
          + md_table(["frames", "GT"] + [labels[m] for m in methods], table) + "\n\n"
          f"Labelling {label_s / 60:.1f} min, training {train_s / 60:.1f} min (2 CPU cores).\n")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "self_training" + ("_quick" if args.quick else "")
    write_json(out / f"{stem}.json", {"quick": args.quick, "command": " ".join(sys.argv), "steps": steps,
                                      "lr": args.lr, "per_pair": args.per_pair, "pairs": len(pairs),
                                      "gt_pixels": n_gt, "pseudo_pixels": n_pseudo, "label_seconds": label_s,
                                      "train_seconds": train_s, "student": str(run / "checkpoint.msgpack"),
                                      "labels": str(labels_dir), "pseudo_labelled": [p[0] for p in pairs],
                                      "sets": rows})
    (out / f"{stem}.md").write_text(md + f"\nCommand: `python experiments/self_training.py {' '.join(sys.argv[1:])}`\n")
    print(md)


if __name__ == "__main__":
    main()
