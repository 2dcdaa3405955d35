"""Exact head against the pruned adaptive head, both with the KITTI model's searched chain
settings, on bottom-centre crops (200x640) of KITTI 2015 000022 and 000026 (a measurement, not
a choice: nothing is picked from it).

Command:  .venv/bin/python experiments/investigations/exact_vs_pruned.py [--data ../shared/data]
(about 4 min here: the exact head is ~100 s per crop) -> experiments/results/exact_vs_pruned.json
"""

import argparse
import dataclasses
import json
from pathlib import Path

from stereojax.data.datasets import DEFAULT_DATA, load_dataset
from stereojax.data.io import write_json
from stereojax.app.evaluation import chain_method, evaluate_frames
from stereojax.models.registry import learned_config, load_model, shipped_weights

OUT = Path(__file__).resolve().parents[1] / "results" / "exact_vs_pruned.json"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    model = load_model(shipped_weights("kitti2015"))
    pruned = learned_config("kitti2015", 228)
    exact = dataclasses.replace(pruned, cost=dataclasses.replace(pruned.cost, candidates=0)).validate()
    items = load_dataset(args.data, "kitti2015", ["000022", "000026"], gt="noc")
    crops = [load().crop(200, 640) for _, load in items]
    # compilation is timed apart, so every frame's seconds are those of a warm chain
    result = evaluate_frames(crops, {"pruned": chain_method(pruned, model), "exact": chain_method(exact, model)},
                             228, progress="exact vs pruned")
    out = {r["frame"]: {m: {"bad3": r[m]["bad3"], "seconds": r[m]["seconds"]} for m in ("pruned", "exact")}
           for r in result["frames"]}
    write_json(OUT, out)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
