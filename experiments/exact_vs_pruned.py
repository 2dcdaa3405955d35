"""Exact head against the pruned adaptive head, both with the KITTI model's searched chain
settings, on bottom-centre crops (200x640) of KITTI 2015 000022 and 000026 (a measurement, not
a choice: nothing is picked from it).

Command:  .venv/bin/python experiments/exact_vs_pruned.py   (about 4 min here: the exact head is
~100 s per crop) -> experiments/results/exact_vs_pruned.json
"""
import dataclasses, json, time
from pathlib import Path
from common import _crop, _load
import stereojax
from stereojax.metrics import evaluate
from stereojax.models import learned_config, load_model, shipped_weights
model = load_model(shipped_weights("kitti2015"))
out = {}
for frame in ("000022", "000026"):
    s = _crop(_load(str(Path(__file__).resolve().parents[2] / "shared" / "data"), "kitti2015", frame, "noc"), 200, 640)
    pruned = learned_config("kitti2015", 228)
    exact = dataclasses.replace(pruned, cost=dataclasses.replace(pruned.cost, candidates=0)).validate()
    row = {}
    for name, cfg in (("pruned", pruned), ("exact", exact)):
        stereojax.disparity(s.left, s.right, cfg, params=model)          # compile
        t = time.perf_counter(); d = stereojax.disparity(s.left, s.right, cfg, params=model)
        row[name] = {"bad3": evaluate(d, s.gt, s.gt_valid)["bad3"], "seconds": time.perf_counter() - t}
    out[frame] = row
    print(frame, row, flush=True)
from stereojax.data.io import write_json
write_json(Path(__file__).resolve().parent / "results" / "exact_vs_pruned.json", out)
print(json.dumps(out))
