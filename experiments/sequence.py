"""Issue 39: streams. What the previous frame's disparity buys the next frame, and what a wrong
one costs, for the census chain, the compact model and `best`.

1. The six real two-frame KITTI sequences in ``../shared/data/unlabeled/kitti``
   (``k15test_00000{0..4}_10/_11``, ``k15sense_000010_10/_11``): the second frame's time with the
   first frame's disparity as its prior (:class:`stereojax.inference.sequence.Sequence`) against
   per-frame prediction in the same run, and their agreement (share of pixels more than 3 px apart).
2. A synthetic scene cut: the first frame of one sequence, then the second frame of another; the
   fallback must catch it.
3. KITTI 2015 validation frames 000021-000030 (ground truth): > 3 px without a prior, with a
   prior from the same frame's own disparity moved 3 px to the right (camera motion), and with
   a wrong prior (the next frame's disparity).

Command:  .venv/bin/python experiments/sequence.py [--methods census,kitti2015_compact,best]
-> experiments/results/sequence.{json,md}, sequence_example.png
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from stereojax.config import preset
from stereojax.data.datasets import DEFAULT_DATA, load_kitti2015
from stereojax.data.io import read_image
from stereojax.inference.sequence import PriorSettings, Sequence
from stereojax.metrics import evaluate
from stereojax.models.registry import resolve

OUT = Path(__file__).resolve().parent / "results"
SEQUENCES = [f"k15test_{i:06d}" for i in range(5)] + ["k15sense_000010"]
VALIDATION = [f"{i:06d}" for i in range(21, 31)]
SHIFT = 3


def sequence_for(method: str, w: int, h: int, settings: PriorSettings) -> Sequence:
    if method == "census":
        return Sequence(preset("census"), None, settings)
    run = resolve("best", weights=None if method == "best" else method, width=w, height=h, dataset="kitti2015")
    return Sequence(run.config, run.model(), settings)


def timed(fn, *args, **kw):
    t = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t


def real_sequences(seq: Sequence, root: Path) -> list:
    rows = []
    for name in SEQUENCES:
        l0, r0 = (read_image(root / side / f"{name}_10.png") for side in ("left", "right"))
        l1, r1 = (read_image(root / side / f"{name}_11.png") for side in ("left", "right"))
        seq.compile(*l0.shape[:2])
        per_frame, t_plain = timed(seq.full, l1, r1)
        seq.reset()
        seq.push(l0, r0)
        f1 = seq.push(l1, r1)
        (d_plain, c_plain), d_seq = per_frame, f1.disparity
        apart = np.abs(d_seq - d_plain) > 3
        sure = c_plain >= 0.5
        rows.append({"sequence": name, "size": [l0.shape[1], l0.shape[0]], "per_frame_s": t_plain,
                     "sequence_s": f1.record["seconds"], "ratio": f1.record["seconds"] / t_plain,
                     "disagree_3px": float(np.mean(apart) * 100),
                     "disagree_3px_confident": float(np.mean(apart[sure]) * 100) if sure.any() else 0.0,
                     "record": f1.record})
        tqdm.write(f"  {name}: {rows[-1]}")
    return rows


def scene_cuts(seq: Sequence, root: Path) -> list:
    rows = []
    for a, b in zip(SEQUENCES, SEQUENCES[1:] + SEQUENCES[:1]):
        l0, r0 = (read_image(root / side / f"{a}_10.png") for side in ("left", "right"))
        l1, r1 = (read_image(root / side / f"{b}_11.png") for side in ("left", "right"))
        seq.reset()
        seq.push(l0, r0)
        f = seq.push(l1, r1)
        rows.append({"first": a, "second": b, "record": f.record, "caught": not f.record.get("used_prior", False)})
        tqdm.write(f"  cut {a} -> {b}: {f.record}")
    return rows


def shifted(a: np.ndarray, dx: int) -> np.ndarray:
    out = np.roll(a, dx, axis=1)
    out[:, :dx] = a[:, :1]
    return out


#: the prior settings measured: the defaults (the config's 48-wide band, the coarse pass always) and a
#: fast one (a 32-wide band placed by the prior, no coarse pass where 80 % of the pixels have a prior)
VARIANTS = {"default": PriorSettings(),
            "fast: K 32, no coarse pass": PriorSettings(band_width=32, skip_coarse_share=0.8)}


def validation(seq: Sequence, root: Path, frames=VALIDATION) -> list:
    rows = []
    samples = {f: load_kitti2015(root, f) for f in frames}
    for i, f in enumerate(frames):
        s = samples[f]
        seq.compile(*s.left.shape[:2])
        (d0, c0), t0 = timed(seq.full, s.left, s.right)
        own = seq.predict(s.left, s.right, (shifted(d0, SHIFT), shifted(c0, SHIFT)), {})
        other = samples[frames[(i + 1) % len(frames)]]
        if other.left.shape != s.left.shape:
            other = None
        if other is not None:
            (dw, cw) = seq.full(other.left, other.right)
            wrong = seq.predict(s.left, s.right, (dw, cw), {})
        score = lambda d: float(evaluate(d, s.gt, s.gt_valid)["bad3"])   # noqa: E731
        row = {"frame": f, "plain": score(d0), "plain_s": t0, "shifted_prior": score(own.disparity),
               "shifted_record": own.record}
        if other is not None:
            row.update(wrong_prior=score(wrong.disparity), wrong_record=wrong.record)
        rows.append(row)
        tqdm.write(f"  {f}: {row}")
    return rows


def summarise(results: dict) -> str:
    lines = ["# Streams: the previous frame's disparity as the next frame's prior (issue 39)", "",
             "`experiments/sequence.py`, one run on this machine (2 CPU cores). Settings: "
             f"{results['settings']}.", "",
             "## The six real KITTI two-frame sequences: second frame with the prior against per-frame", "",
             "| method | per-frame s | with prior s | ratio | > 3 px apart (%) | of the confident pixels (%) | prior share "
             "| mean limit width (px) | coarse pass skipped | fallbacks |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for m, r in results["methods"].items():
        rows = r["sequences"]
        fb = sum(1 for x in rows if not x["record"].get("used_prior"))
        lines.append(f"| {m} | {np.mean([x['per_frame_s'] for x in rows]):.2f} | "
                     f"{np.mean([x['sequence_s'] for x in rows]):.2f} | {np.mean([x['ratio'] for x in rows]):.2f} | "
                     f"{np.mean([x['disagree_3px'] for x in rows]):.2f} | "
                     f"{np.mean([x.get('disagree_3px_confident', 0) for x in rows]):.2f} | "
                     f"{np.mean([x['record'].get('prior_share', 0) for x in rows]) * 100:.1f} % | "
                     f"{np.mean([x['record'].get('mean_limit_width', 0) for x in rows]):.1f} | "
                     f"{sum(1 for x in rows if x['record'].get('coarse_pass') is False)} of {len(rows)} | "
                     f"{fb} of {len(rows)} |")
    lines += ["", "## Synthetic scene cuts (first frame of one sequence, second frame of the next)", "",
              "| method | caught | how |", "|---|---|---|"]
    for m, r in results["methods"].items():
        if "cuts" not in r:
            continue
        cuts = r["cuts"]
        how = sorted({str(c["record"].get("fallback")).split(":")[0] for c in cuts})
        lines.append(f"| {m} | {sum(c['caught'] for c in cuts)} of {len(cuts)} | {', '.join(how)} |")
    lines += ["", f"## KITTI 2015 000021–000030, > 3 px: no prior, the frame's own disparity moved {SHIFT} px, "
              "another frame's disparity", "",
              "| method | no prior | own, moved | wrong prior | wrong prior caught |", "|---|---|---|---|---|"]
    for m, r in results["methods"].items():
        v = r["validation"]
        wrong = [x for x in v if "wrong_prior" in x]
        caught = sum(1 for x in wrong if not x["wrong_record"].get("used_prior"))
        lines.append(f"| {m} | {np.mean([x['plain'] for x in v]):.2f} | {np.mean([x['shifted_prior'] for x in v]):.2f} | "
                     f"{np.mean([x['wrong_prior'] for x in wrong]):.2f} | {caught} of {len(wrong)} |")
    lines += ["", "## The issue's targets", ""]
    for m, r in results["methods"].items():
        rows, v = r.get("sequences"), r.get("validation")
        if not rows or not v:
            continue
        ratio, apart = np.mean([x["ratio"] for x in rows]), np.mean([x["disagree_3px"] for x in rows])
        plain = np.mean([x["plain"] for x in v])
        own = np.mean([x["shifted_prior"] for x in v]) - plain
        wrong = np.mean([x["wrong_prior"] for x in v if "wrong_prior" in x]) - plain
        met = lambda ok: "met" if ok else "**not met**"     # noqa: E731
        lines.append(f"* {m}: later frames ≤ 0.6× the per-frame time at ≤ 1 % disagreement: {ratio:.2f}× at "
                     f"{apart:.2f} % — {met(ratio <= 0.6 and apart <= 1)}; own prior moved, wrong prior ≤ +0.1 "
                     f"points: {own:+.2f} / {wrong:+.2f} — {met(own <= 0.1 and wrong <= 0.1)}.")
    lines += ["", "The thresholds of the wrong-prior checks (`min_agree` 0.97, `max_pinned` 0.025) were chosen on "
              "KITTI 2015 training frames 000001–000015 (`python experiments/sequence.py --calibrate` -> "
              "sequence_calibration.json: the own prior moved 3 px reached agreement ≥ 0.989 and pinned ≤ 0.021 "
              "there; another frame's 0.66–0.99), before these runs. The radius, margins and band settings were "
              "set after a first look at the six sequences (a radius of 6 px, 10 % and 2 px pinned 6–15 % of "
              "the prior pixels and fell back on 5 of 6), so the sequence rows are not held out. Nor are the "
              "validation rows: the rule that a pixel needs its own confident neighbourhood (`own_radius` 2) was "
              "added after `kitti2015_compact` lost 0.95 points on 000023 without it (an object unsure in the "
              "previous frame took the limits of the confident background around it; +0.13 over the ten frames)."]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--methods", default="census,kitti2015_compact")
    ap.add_argument("--parts", default="sequences,cuts,validation")
    ap.add_argument("--calibrate", action="store_true", help="only the own / wrong prior test, on the training "
                    "frames 000001-000015 (where the fallback thresholds are chosen) -> sequence_calibration.json")
    args = ap.parse_args()
    unl = Path(args.data) / "unlabeled" / "kitti"
    kitti = Path(args.data) / "kitti2015" / "training"
    if args.calibrate:
        seq = sequence_for("census", 1242, 375, VARIANTS["default"])
        rows = validation(seq, kitti, [f"{i:06d}" for i in range(1, 16)])
        (OUT / "sequence_calibration.json").write_text(json.dumps(rows, indent=1, default=float))
        return
    path = OUT / "sequence.json"
    results = json.loads(path.read_text()) if path.is_file() else {"methods": {}}
    results["settings"] = {k: dataclasses.asdict(v) for k, v in VARIANTS.items()}
    parts = args.parts.split(",")
    for m in tqdm(args.methods.split(","), desc="methods"):
        for variant, settings in VARIANTS.items():
            seq = sequence_for(m, 1242, 375, settings)
            r = results["methods"].setdefault(m if variant == "default" else f"{m}, {variant}", {})
            if "sequences" in parts:
                r["sequences"] = real_sequences(seq, unl)
            if "cuts" in parts and variant == "default":
                r["cuts"] = scene_cuts(seq, unl)
            if "validation" in parts:
                r["validation"] = validation(seq, kitti)
            path.write_text(json.dumps(results, indent=1, default=float))
    (OUT / "sequence.md").write_text(summarise(results))
    print(summarise(results))


if __name__ == "__main__":
    main()
