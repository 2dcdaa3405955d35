"""Disparity error of a trained network in the full chain, beside the census chain, on KITTI 2015.

Command:  .venv/bin/python experiments/investigations/learned_eval.py WEIGHTS [--frames 000021,000022]
                [--candidates 0|K] [--unsure-share 0.2 --unsure-candidates 16] [--p1 0.5 --p2 8.0 --cbca 2]
                [--out experiments/results/learned_kitti2015.json]
Running time here (2 cores): exact mode ~4-5 min per KITTI frame (the downsize head is about
70 TFLOP per frame), pruned mode with K candidates about K / 228 of that, census ~2 s.
Prints per frame the > 3 px error (non-occluded GT, dense output) of both chains and the
seconds per frame, and writes them to --out.
"""

import argparse
import dataclasses
from pathlib import Path

import stereojax
from stereojax.data.datasets import DEFAULT_DATA, load_dataset
from stereojax.data.io import write_json
from stereojax.app.evaluation import chain_method, evaluate_frames


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("weights")
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    ap.add_argument("--frames", default="000021,000022,000023")
    ap.add_argument("--candidates", type=int, default=0, help="0 = exact head; K = pruned mode")
    ap.add_argument("--unsure-share", type=float, default=0.0,
                    help="adaptive pruned mode: share of pixels that get --unsure-candidates")
    ap.add_argument("--unsure-candidates", type=int, default=0)
    ap.add_argument("--p1", type=float, default=0.5)
    ap.add_argument("--p2", type=float, default=8.0)
    ap.add_argument("--cbca", type=int, default=2)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "results" / "learned_kitti2015.json"))
    args = ap.parse_args()
    model = stereojax.load_model(args.weights)
    base = stereojax.preset("learned", 228)
    cfg = dataclasses.replace(
        base, cost=dataclasses.replace(base.cost, candidates=args.candidates, unsure_share=args.unsure_share,
                                       unsure_candidates=args.unsure_candidates),
        cbca=dataclasses.replace(base.cbca, iterations_before=args.cbca),
        sgm=dataclasses.replace(base.sgm, p1=args.p1, p2=args.p2)).validate()

    def show(row, sample, disparities):
        print(f"{row['frame']}: learned {row['learned']['bad3']:.2f} % ({row['learned']['seconds']:.0f} s)   "
              f"census {row['census']['bad3']:.2f} % ({row['census']['seconds']:.1f} s)", flush=True)

    items = load_dataset(args.data, "kitti2015", args.frames.split(","), gt="noc")
    result = evaluate_frames(items, {"learned": chain_method(cfg, model),
                                     "census": chain_method(stereojax.preset("census"))}, 228, on_frame=show)
    summary = result["mean"]
    print(f"mean > 3 px: learned {summary['learned']['bad3']:.2f} %, census {summary['census']['bad3']:.2f} %")
    write_json(Path(args.out), {"weights": str(args.weights), "config": cfg.to_dict(), "frames": result["frames"],
                                "mean": summary, "note": "seconds exclude compilation (compile_s)"})


if __name__ == "__main__":
    main()
