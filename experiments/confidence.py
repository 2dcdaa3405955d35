"""Is the confidence map useful? Sparsification curves on KITTI 2015 (issue "every pixel counts").

For every frame, the ground-truth pixels are sorted by the chain's confidence (most confident
first) and the > 3 px error of the most confident x % is measured, x = 10, 20, ..., 100; the same
for an *oracle* order (by the true error) and a *random* order. The curves are averaged over the
frames; the area under each (mean over x) is reported: the closer the confidence's area to the
oracle's, and the further below the random one, the more useful the map.

``--variants`` also scores the two terms of the confidence alone (the cost margin, the
left-right agreement) to choose the combination; that is done on training frames
(``--frames 000001,000003,000005,000007,000009``) and the chosen map is then measured once on the
validation frames 000021-000030 (the default).

Command:  .venv/bin/python experiments/confidence.py [--frames 000021-000030] [--variants]
          [--data ../shared/data] [--out experiments/results]
Running time here: about 30 s per frame (the chain keeps its volumes to give every term).
Writes OUT/confidence_<frames>.{json,md} and OUT/figures/confidence_<frames>.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import stereojax
from stereojax.validation import confidence_measure
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, parse_frames
from stereojax.data.io import write_json
from stereojax.models.registry import resolve

FRACTIONS = np.arange(1, 11) / 10
THRESHOLD = 3.0


def curve(order_key: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Error % of the first x of the pixels sorted by ``order_key`` descending, x in FRACTIONS."""
    order = np.argsort(-order_key, kind="stable")
    cum = np.cumsum(bad[order])
    n = len(bad)
    return np.array([100.0 * cum[max(int(round(f * n)), 1) - 1] / max(int(round(f * n)), 1) for f in FRACTIONS])


def terms(st: dict, lr_tolerance: float) -> dict:
    """The confidence of the chain and its two terms alone, from the kept stages."""
    import jax.numpy as jnp

    full = np.asarray(st["confidence"])
    margin = np.asarray(confidence_measure.confidence(jnp.asarray(st["cost_final"]), jnp.asarray(st["disp_wta"]), None))
    lr = np.where(margin > 0, full / np.maximum(margin, 1e-12), 0.5)
    return {"confidence": full, "margin": margin, "left-right": lr}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="000021-000030")
    ap.add_argument("--variants", action="store_true", help="also the margin and the left-right term alone")
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--quick", action="store_true", help="smoke test: one frame, a 128x320 crop")
    args = ap.parse_args()
    if args.quick:
        args.frames = "000021"
    frames = parse_frames(args.frames)
    run = resolve("best", None, None, 1242, 375, "kitti2015", 228)
    rng = np.random.default_rng(0)
    curves: dict[str, list] = {}
    for frame_id, load in load_dataset(args.data, "kitti2015", frames, gt="noc"):
        s = load().crop(128, 320) if args.quick else load()
        st = stereojax.stages(s.left, s.right, run.config, run.model())
        gv = s.gt_valid
        err = np.abs(st["disparity"] - s.gt)[gv]
        bad = (err > THRESHOLD).astype(np.float64)
        final = st.get("confidence_texture", st["confidence"])     # after the texture term, when on
        maps = terms(st, run.config.refine.lr_tolerance) if args.variants else {"confidence": final}
        per = {name: curve(m[gv], bad) for name, m in maps.items()}
        per["oracle"] = curve(-err, bad)
        per["random"] = curve(rng.random(len(bad)), bad)
        for name, c in per.items():
            curves.setdefault(name, []).append(c)
        print(f"{frame_id}: all {100 * bad.mean():.2f} %, most confident half "
              f"{per['confidence'][4]:.2f} %, oracle {per['oracle'][4]:.2f} %", flush=True)
    mean = {name: np.mean(cs, axis=0) for name, cs in curves.items()}
    area = {name: float(c.mean()) for name, c in mean.items()}
    tag = args.frames.replace(",", "_") + ("_quick" if args.quick else "")
    out = Path(args.out)
    write_json(out / f"confidence_{tag}.json", {"frames": frames, "model": run.description, "threshold_px": THRESHOLD,
                                                "fractions": FRACTIONS.tolist(),
                                                "curves": {k: v.tolist() for k, v in mean.items()}, "area": area})
    head = "| order | " + " | ".join(f"{int(f * 100)} %" for f in FRACTIONS) + " | area |"
    lines = [f"# Sparsification on KITTI 2015 {args.frames} (> 3 px, non-occluded GT, `{run.description}`)", "",
             "Error of the most confident x % of the ground-truth pixels, mean over the frames; area = mean over x.", "",
             head, "|---" * (len(FRACTIONS) + 2) + "|"]
    for name, c in mean.items():
        lines.append(f"| {name} | " + " | ".join(f"{v:.2f}" for v in c) + f" | {area[name]:.2f} |")
    lines += ["", f"![sparsification](figures/confidence_{tag}.png)", "",
              f"Command: `python experiments/confidence.py --frames {args.frames}{' --variants' if args.variants else ''}`", ""]
    (out / f"confidence_{tag}.md").write_text("\n".join(lines))
    _plot(mean, area, out / "figures" / f"confidence_{tag}.png", args.frames)
    print("\n".join(lines))


def _plot(mean, area, path: Path, frames: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=120)
    for name, c in mean.items():
        ax.plot(FRACTIONS * 100, c, marker="o", ms=3, label=f"{name} (area {area[name]:.2f})",
                ls="--" if name in ("oracle", "random") else "-")
    ax.set_xlabel("most confident pixels kept, %")
    ax.set_ylabel("> 3 px error of those, %")
    ax.set_title(f"Sparsification, KITTI 2015 {frames}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()
