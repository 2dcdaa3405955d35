"""The field's reference pipeline beside stereojax and OpenCV SGBM, on the bench frame, in one run.

Command:  make bench-anchors     (optional, not part of make test; it creates .venv-anchors with
          torch 2.13.0 (CPU build), pandora, pandora-plugin-libsgm, libsgm, mccnn and
          pandora-plugin-mccnn, then runs this script with the stereojax environment)
          .venv/bin/python experiments/bench_anchors.py --anchors-python .venv-anchors/bin/python
Running time here (2 cores): about 2 min (Pandora twice, each shipped KITTI model three times, SGBM).
Writes experiments/results/anchors.{json,md}: warm seconds per frame of CNES Pandora with its
MC-CNN matching cost (the MC-CNN-fast weights that the plugin ships, trained on Middlebury) and
libsgm, of `stereojax --method best`, and of OpenCV StereoSGBM, all on KITTI 2015 000021
(1242x375, 228 disparities). `make bench` then quotes Pandora's time beside its own rows.

Pandora's configuration: one grey band, disparities as x_right - x_left in [-228, 0], MC-CNN
cost (11x11 window), SGM with the MC-CNN-fast penalties, WTA, vfit sub-pixel, median 3x3, and
the cross-check with interpolated_disparity "sgm" (the "mc-cnn" mode can crash at the image
borders). Its disparity is scored against the GT too, so the speed is that of a working run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from stereojax.data.datasets import DEFAULT_DATA

ROOT = Path(__file__).resolve().parents[1]

PANDORA_CHILD = r'''
import json, sys, time
import numpy as np
from pandora import import_plugin, run
from pandora.check_configuration import check_conf
from pandora.img_tools import create_dataset_from_inputs
from pandora.state_machine import PandoraMachine
import pandora
import_plugin()
left, right, max_disp = sys.argv[1], sys.argv[2], int(sys.argv[3])
user = {
    "input": {"left": {"img": left, "disp": [-max_disp, 0]}, "right": {"img": right}},
    "pipeline": {
        "matching_cost": {"matching_cost_method": "mc_cnn", "window_size": 11, "subpix": 1},
        "optimization": {"optimization_method": "sgm", "penalty": {"penalty_method": "mc_cnn_fast_penalty"}},
        "disparity": {"disparity_method": "wta", "invalid_disparity": "NaN"},
        "refinement": {"refinement_method": "vfit"},
        "filter": {"filter_method": "median", "filter_size": 3},
        "validation": {"validation_method": "cross_checking_accurate", "interpolated_disparity": "sgm"},
    },
}
times, disp = [], None
for _ in range(2):
    t0 = time.perf_counter()
    machine = PandoraMachine()
    cfg = check_conf(json.loads(json.dumps(user)), machine)
    img_l = create_dataset_from_inputs(input_config=cfg["input"]["left"])
    cfg["input"]["right"]["disp"] = [-cfg["input"]["left"]["disp"][1], -cfg["input"]["left"]["disp"][0]]
    img_r = create_dataset_from_inputs(input_config=cfg["input"]["right"])
    out_l, _ = run(machine, img_l, img_r, cfg)
    times.append(time.perf_counter() - t0)
    disp = out_l["disparity_map"].values
np.save(sys.argv[4], -disp.astype(np.float32))       # x_right - x_left -> our d >= 0
from importlib.metadata import version
print(json.dumps({"seconds": times, "version": version("pandora")}))
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anchors-python", required=True, help="python of the environment with Pandora")
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--frame", default="000021")
    ap.add_argument("--max-disp", type=int, default=228)
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    args = ap.parse_args()

    from stereojax.app.baselines import sgbm_disparity
    from stereojax.app.bench import learned_setup, sgbm_timings, warm_chain
    from stereojax.data import load_kitti2015
    from stereojax.data.io import atomic_output, write_json
    from stereojax.metrics import evaluate

    s = load_kitti2015(Path(args.data) / "kitti2015" / "training", args.frame)
    md = args.max_disp
    sgbm_before = sgbm_timings(s.left, s.right, md)["padded"]
    with tempfile.TemporaryDirectory() as tmp:
        grey = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im for im in (s.left, s.right)]
        lp, rp, dp = Path(tmp) / "left.png", Path(tmp) / "right.png", Path(tmp) / "disp.npy"
        cv2.imwrite(str(lp), grey[0])
        cv2.imwrite(str(rp), grey[1])
        print("running Pandora (MC-CNN + libsgm) twice ...", flush=True)
        proc = subprocess.run([args.anchors_python, "-c", PANDORA_CHILD, str(lp), str(rp), str(md), str(dp)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"Pandora failed: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else proc.returncode}")
        pandora = json.loads(proc.stdout.strip().splitlines()[-1])
        d_pandora = np.load(dp)
    valid = np.isfinite(d_pandora) & (d_pandora >= 0)
    m_pandora = evaluate(np.where(valid, d_pandora, -1.0), s.gt, s.gt_valid, est_valid=valid)

    ours = {}
    for which in ("best", "kitti2015_compact"):
        model, cfg, name = learned_setup(which, md)
        t = warm_chain(s.left, s.right, cfg, model)
        ours[which] = {"name": name, "seconds": t["warm_s"], "bad3": evaluate(t["disparity"], s.gt, s.gt_valid)["bad3"]}
    sgbm_after = sgbm_timings(s.left, s.right, md)["padded"]
    sgbm_s = float(np.median([sgbm_before, sgbm_after]))
    d_sgbm, v_sgbm = sgbm_disparity(s.left, s.right, num_disp=md, pad=True)
    m_sgbm = evaluate(d_sgbm, s.gt, s.gt_valid, est_valid=v_sgbm)

    result = {"frame": f"KITTI 2015 {args.frame}", "shape": list(s.left.shape[:2]), "max_disp": md,
              "pandora_version": pandora["version"], "pandora_runs_s": pandora["seconds"],
              "pandora_s": pandora["seconds"][-1], "best_s": ours["best"]["seconds"], "best_model": ours["best"]["name"],
              "compact_s": ours["kitti2015_compact"]["seconds"], "sgbm_s": sgbm_s,
              "bad3": {"pandora": m_pandora["bad3"], "best": ours["best"]["bad3"],
                       "kitti2015_compact": ours["kitti2015_compact"]["bad3"], "sgbm": m_sgbm["bad3"]},
              "note": "warm: Pandora's second run in its process (the first loads torch and the weights); "
                      "stereojax's compiled chain, median of 3; SGBM median of before and after"}
    out = Path(args.out)
    write_json(out / "anchors.json", result)
    rows = [("CNES Pandora " + pandora["version"] + " (MC-CNN-fast Middlebury weights + libsgm)", result["pandora_s"],
             m_pandora["bad3"]),
            (f"stereojax `--method best` ({ours['best']['name']})", ours["best"]["seconds"], ours["best"]["bad3"]),
            ("stereojax `--weights kitti2015_compact`", ours["kitti2015_compact"]["seconds"],
             ours["kitti2015_compact"]["bad3"]),
            ("OpenCV StereoSGBM (3-way, left-padded)", sgbm_s, m_sgbm["bad3"])]
    text = "\n".join([
        f"# Reference pipelines on {result['frame']} ({s.left.shape[1]}x{s.left.shape[0]}, {md} disparities, "
        "2 CPU cores), one run", "",
        "| method | warm s / frame | × SGBM | > 3 px % (this frame, noc) |", "|---|---|---|---|",
        *[f"| {n} | {t:.2f} | {t / sgbm_s:.0f}x | {b:.2f} |" for n, t, b in rows], "",
        f"Pandora's runs: {', '.join(f'{t:.1f}' for t in pandora['seconds'])} s (first, then warm). "
        "Pandora's configuration is in `experiments/bench_anchors.py`; its non-disparity pixels "
        "(cross-check failures it does not fill) are filled by KITTI's background interpolation.",
        "", "Command: `make bench-anchors`", ""])
    with atomic_output(out / "anchors.md") as tmp:
        Path(tmp).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
