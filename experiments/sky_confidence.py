"""Is saturated, textureless sky reported as a reliable surface? (issue 55, item 3)

Command:  .venv/bin/python experiments/sky_confidence.py [--frames 000001-000030] [--texture-full 0.25]

The sky is marked by a simple rule that the chain never sees: grey >= 250 (saturated), the 7x7
standard deviation below 2 grey levels (textureless) and in the top 40 % of the rows (above the
horizon). Over the frames, with `--method best`'s model and settings (`kitti2015`), the share of
those pixels that keep a disparity under `--min-confidence 0.3` and the share marked in
`depth_reliable.png` (disparity >= 10 px and confidence >= 0.3). `--texture-full 0` runs the chain
without the confidence's texture term (the confidence before issue 55).
-> experiments/results/sky_confidence[_notexture].{json,md}
"""

import argparse
import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np

from common import DEFAULT_DATA, ROOT, md_table  # noqa: E402

import stereojax  # noqa: E402
from stereojax.app.outputs import RELIABLE_MIN_CONFIDENCE, blank_unconfident, depth_reliable  # noqa: E402
from stereojax.data.datasets import load_kitti2015, parse_frames  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.models.registry import learned_config, load_model, shipped_weights  # noqa: E402

MIN_CONFIDENCE = 0.3
TARGET_SHARE = 1.0


def sky_rule(left) -> np.ndarray:
    g = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY).astype(np.float32) if left.ndim == 3 else left.astype(np.float32)
    mean = cv2.blur(g, (7, 7))
    std = np.sqrt(np.maximum(cv2.blur(g * g, (7, 7)) - mean * mean, 0))
    rows = np.arange(g.shape[0])[:, None] < 0.4 * g.shape[0]
    return (g >= 250) & (std < 2) & rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", default="000001-000030")
    ap.add_argument("--texture-full", type=float, default=None, help="refine.texture_full (default: the card's)")
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    args = ap.parse_args()
    cfg, model = learned_config("kitti2015"), load_model(shipped_weights("kitti2015"))
    if args.texture_full is not None:
        cfg = dataclasses.replace(cfg, refine=dataclasses.replace(cfg.refine, texture_full=args.texture_full))
    predict = stereojax.Predictor(cfg.validate(), model, confidence=True)
    rows, kept_all, rel_all, sky_all = [], 0, 0, 0
    for frame in parse_frames(args.frames):
        s = load_kitti2015(Path(args.data) / "kitti2015" / "training", frame, "noc")
        disp, conf = predict(s.left, s.right)
        sky = sky_rule(s.left)
        shown = blank_unconfident(disp, conf, MIN_CONFIDENCE)
        kept = sky & np.isfinite(shown) & (shown > 0)
        reliable = sky & depth_reliable(shown, conf)
        rows.append({"frame": s.name, "sky": int(sky.sum()), "kept": int(kept.sum()), "reliable": int(reliable.sum())})
        kept_all, rel_all, sky_all = kept_all + int(kept.sum()), rel_all + int(reliable.sum()), sky_all + int(sky.sum())
        print(f"{s.name}: {sky.sum()} sky pixels, {kept.sum()} keep a disparity, {reliable.sum()} reliable", flush=True)
    share = 100 * kept_all / max(sky_all, 1)
    met = share <= TARGET_SHARE and rel_all == 0
    tag = "" if args.texture_full is None else ("_notexture" if args.texture_full == 0 else f"_tf{args.texture_full:g}")
    md = ("# Saturated, textureless sky under `--min-confidence 0.3` (KITTI 2015, `best`)\n\n"
          f"Rule: grey >= 250, 7x7 std < 2, top 40 % of the rows. texture_full = {cfg.refine.texture_full:g} "
          f"(0 = the confidence before issue 55). Reliable: disparity >= 10 px and confidence >= "
          f"{RELIABLE_MIN_CONFIDENCE}.\n\n"
          + md_table(["frame", "sky pixels", "keep a disparity", "in depth_reliable.png"],
                     [[r["frame"], r["sky"], r["kept"], r["reliable"]] for r in rows]
                     + [["**all**", sky_all, f"{kept_all} ({share:.2f} %)", rel_all]])
          + f"\n\nTarget: at most {TARGET_SHARE:g} % keep a disparity and none is reliable: "
          f"**{'met' if met else 'missed'}**.\n\nCommand: `python experiments/sky_confidence.py "
          f"{' '.join(sys.argv[1:])}`\n")
    out = Path(args.out)
    write_json(out / f"sky_confidence{tag}.json", {"frames": rows, "sky": sky_all, "kept": kept_all,
                                                   "kept_share": share, "reliable": rel_all, "target_met": met,
                                                   "texture_full": cfg.refine.texture_full})
    (out / f"sky_confidence{tag}.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
