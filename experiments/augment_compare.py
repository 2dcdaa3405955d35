"""Does MC-CNN-style patch augmentation help? Measured on the KITTI model-selection fold of
experiments/PROTOCOL.md, over seeds, in the manner of the paper's Table 1.

Command:  .venv/bin/python experiments/augment_compare.py [--steps 8000] [--seeds 0 1]
              [--out experiments/results] [--runs runs/augment] [--quick]
Each model (the shipped architecture: 64 feature maps, downsize head, relaxed loss, the `cpu`
preset's schedule compressed to --steps) trains on KITTI 2015 000001-000015 with and without
``--augment`` (sampling.AUGMENT_MCCNN) and is scored on 000016-000020 (noc GT, > 3 px) in the
chain of ``preset("learned")`` (the pruned adaptive head, preset settings). The patch-level
validation error on 000016-000020 is given too. The validation frames 000021-000030 are not
touched. Running time here (2 cores): about 7 min per model at 8000 steps, then ~20 s per frame.
Trained models are kept in --runs (a killed run resumes); --quick: a tiny smoke test.
"""

import argparse
import json
import sys
from pathlib import Path


from common import (DEFAULT_DATA, QUICK_CROP, RESULTS, ROOT, load_sample, md_table, mean_std,  # noqa: E402
                    pm)

import stereojax  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.metrics import evaluate  # noqa: E402
from stereojax.models.registry import load_model  # noqa: E402
from stereojax.learning.train import fit, train_preset, with_augmentation  # noqa: E402

TRAIN = [f"{i:06d}" for i in range(1, 16)]
SELECT = [f"{i:06d}" for i in range(16, 21)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=8000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--runs", default=str(ROOT / "runs" / "augment"))
    ap.add_argument("--quick", action="store_true", help="tiny network, 2+1 frames, cropped: a smoke test")
    args = ap.parse_args()
    train_ids, select_ids = (TRAIN[:2], SELECT[:1]) if args.quick else (TRAIN, SELECT)

    def samples(ids):
        out = [load_sample(args.data, "kitti2015", f, "noc") for f in ids]
        return [s.crop(*QUICK_CROP) for s in out] if args.quick else out

    train, select = samples(train_ids), samples(select_ids)
    rows, table = {}, []
    for aug in (False, True):
        for seed in args.seeds:
            name = f"{'aug' if aug else 'plain'}_s{seed}_{'quick' if args.quick else args.steps}"
            run = Path(args.runs) / name
            if args.quick:
                cfg = train_preset("tiny", seed=seed, steps=args.steps if args.steps != 8000 else 12)
            else:
                cfg = train_preset("cpu", seed=seed, steps=args.steps, checkpoint_every=1000,
                                   val_every=args.steps, log_every=100)
            if aug:
                cfg = with_augmentation(cfg)
            done = run / "train_summary.json"
            if not (done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps):
                print(f"training {name} ({cfg.steps} steps)", flush=True)
                fit(cfg, train, select, run, resume=True, progress=False,
                    info={"data": {"dataset": "kitti2015", "frames": train_ids, "val_frames": select_ids}})
            summary = json.loads(done.read_text())
            model = load_model(run / "checkpoint.msgpack")
            errs = []
            for s in select:
                md = 48 if args.quick else 228
                disp = stereojax.disparity(s.left, s.right, stereojax.preset("learned", md), params=model)
                errs.append(evaluate(disp, s.gt, s.gt_valid)["bad3"])
            rows[name] = {"augment": aug, "seed": seed, "bad3_per_frame": errs,
                          "bad3": sum(errs) / len(errs), "patch_val_error": summary["validation"]["error"],
                          "train_seconds": summary["seconds"], "samples_per_s": summary["samples_per_s"]}
            print(f"{name}: > 3 px {rows[name]['bad3']:.2f} %, patch error "
                  f"{100 * rows[name]['patch_val_error']:.2f} %", flush=True)
    for aug in (False, True):
        sel = [r for r in rows.values() if r["augment"] == aug]
        table.append(["MC-CNN augmentation" if aug else "none", pm([r["bad3"] for r in sel]),
                      pm([100 * r["patch_val_error"] for r in sel]),
                      ", ".join(f"{r['bad3']:.2f}" for r in sel)])
    diff = mean_std([r["bad3"] for r in rows.values() if r["augment"]])[0] - \
        mean_std([r["bad3"] for r in rows.values() if not r["augment"]])[0]
    md = (f"# Patch augmentation, KITTI 2015 selection fold\n\nTrained on {train_ids[0]}-{train_ids[-1]}, "
          f"scored on {select_ids[0]}-{select_ids[-1]} (noc GT, `preset(\"learned\")` chain: pruned adaptive head, preset settings), "
          f"{cfg.steps} steps, seeds {args.seeds}; mean ± std over seeds.\n\n"
          + md_table(["augmentation", "> 3 px %", "patch val. error %", "per seed > 3 px"], table)
          + f"\n\nDifference (augmented - none): {diff:+.2f} points.\n")
    stem = "augment_compare_quick" if args.quick else "augment_compare"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / f"{stem}.json", {"steps": cfg.steps, "seeds": args.seeds, "train": train_ids,
                                      "select": select_ids, "models": rows, "difference": diff})
    (out / f"{stem}.md").write_text(md + f"\nCommand: `python experiments/augment_compare.py {' '.join(sys.argv[1:])}`\n")
    print(md)


if __name__ == "__main__":
    main()
