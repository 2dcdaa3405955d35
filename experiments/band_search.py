"""Choose the band settings (width K, coarse scale, widening) on KITTI 2015 *training* frames.

For each candidate band setting and each frame: how often the true disparity lies in the
pixel's band (non-occluded GT; occluded too where ``disp_occ`` exists), and the > 3 px error
and warm time of a chain (census, or a shipped model with its card) beside the full-range
chain, all in one run. The rule that picks the setting is in experiments/PROTOCOL.md ("Bands").

    python experiments/band_search.py --frames 000001-000019:2 --method census
    python experiments/band_search.py --method kitti2015_compact --bands 32/2/1/3/3
    python experiments/band_search.py --method kitti2015_compact --bands 48/2/1/3/3 24/2/1/3/3@0

A band written ``.../margin@N`` also sets the learned chain's ``cost.candidates`` to N (0: the
head at every disparity of the band, without the census candidate chain); without ``@`` the
card's own candidates are kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import Predictor, chain, preset
from stereojax.config import BandConfig
from stereojax.data import load_kitti2015
from stereojax.data.datasets import DEFAULT_DATA
from stereojax.metrics import evaluate

RESULTS = Path(__file__).resolve().parent / "results"
#: width / scale / radius / unsure_radius / margin
DEFAULT_BANDS = ("0", "24/2/1/3/3", "32/2/1/3/3", "32/2/2/4/4", "48/2/1/3/3", "32/4/1/3/3")


def parse_band(text: str) -> BandConfig:
    parts = [int(p) for p in text.partition("@")[0].split("/")]
    if parts == [0]:
        return BandConfig(width=0)
    width, scale, radius, unsure, margin = parts
    return BandConfig(width=width, scale=scale, radius=radius, unsure_radius=unsure, margin=margin)


def with_band(base, text: str):
    """The chain ``base`` with the band of ``text`` (and its ``@N`` candidates, if any)."""
    cfg = dataclasses.replace(base, band=parse_band(text))
    _, at, cands = text.partition("@")
    if at:
        cfg = dataclasses.replace(cfg, cost=dataclasses.replace(cfg.cost, candidates=int(cands)))
    return cfg.validate()


def frames_arg(text: str) -> list[str]:
    span, _, step = text.partition(":")
    a, _, b = span.partition("-")
    return [f"{i:06d}" for i in range(int(a), int(b or a) + 1, int(step or 1))]


def chain_for(method: str, max_disp: int):
    if method in ("census", "sad"):
        return preset(method, max_disp), None
    from stereojax.models.registry import learned_config, load_model, shipped_weights

    return learned_config(method, max_disp), load_model(shipped_weights(method))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--frames", default="000001-000019:2")
    ap.add_argument("--method", default="census")
    ap.add_argument("--bands", nargs="+", default=list(DEFAULT_BANDS))
    ap.add_argument("--max-disp", type=int, default=228)
    ap.add_argument("--out", default=None)
    ap.add_argument("--tag", default="", help="appended to the output name")
    args = ap.parse_args(argv)
    root = Path(args.data) / "kitti2015" / "training"
    frames = frames_arg(args.frames)
    samples = [load_kitti2015(root, f) for f in frames]
    base, model = chain_for(args.method, args.max_disp)
    rows = []
    for text in args.bands:
        band = parse_band(text)
        cfg = with_band(base, text)
        predict = Predictor(cfg, model)
        bands_fn = jax.jit(lambda a, b, c=cfg: chain.bands(a, b, c))
        cover, errs, secs = [], [], []
        predict(samples[0].left, samples[0].right)                       # compile
        for s in samples:
            t0 = time.perf_counter()
            disp = predict(s.left, s.right)
            secs.append(time.perf_counter() - t0)
            errs.append(evaluate(disp, s.gt, s.gt_valid)["bad3"])
            if cfg.banded:
                gl, gr = predict.prepare(s.left, s.right)
                off = np.asarray(bands_fn(jnp.asarray(gl), jnp.asarray(gr))[0])
                inside = (s.gt >= off - 0.5) & (s.gt <= off + band.width - 0.5)
                cover.append(float(inside[s.gt_valid].mean() * 100))
        row = {"band": text, "candidates": cfg.cost.candidates if cfg.cost.method == "learned" else None,
               "width": band.width, "scale": band.scale, "radius": band.radius,
               "unsure_radius": band.unsure_radius, "margin": band.margin,
               "coverage_pct": float(np.mean(cover)) if cover else 100.0,
               "coverage_min_pct": float(np.min(cover)) if cover else 100.0,
               "bad3_pct": float(np.mean(errs)), "warm_s": float(np.median(secs)),
               "per_frame_bad3": dict(zip(frames, map(float, errs)))}
        rows.append(row)
        print(f"{text:>12}  coverage {row['coverage_pct']:6.2f} % (min {row['coverage_min_pct']:6.2f})  "
              f"> 3 px {row['bad3_pct']:5.2f} %  {row['warm_s']:.2f} s", flush=True)
    out = Path(args.out) if args.out else RESULTS / f"band_search_{args.method}{args.tag}"
    out.with_suffix(".json").write_text(json.dumps(
        {"method": args.method, "frames": frames, "max_disp": args.max_disp, "rows": rows}, indent=2))
    lines = [f"# Band settings on KITTI 2015 training frames ({args.method})", "",
             f"Frames {', '.join(frames)} (training frames; experiments/PROTOCOL.md, 'Bands'), non-occluded GT, "
             f"{args.max_disp} disparities; band = width/scale/radius/unsure radius/margin (0 = full range); "
             "coverage = share of GT pixels whose true disparity lies in the pixel's band; "
             "`@N`: the learned head at N census candidates per pixel (`@0`: at every disparity of the band); "
             "`python experiments/band_search.py` on this 2-core CPU, one run.", "",
             "| band | head candidates / pixel | coverage % | worst frame coverage % | > 3 px % | warm s / frame |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        cands = "–" if r["candidates"] is None else (f"{r['candidates']} (census chain)" if r["candidates"]
                                                     else f"{r['width']} (every band disparity)")
        lines.append(f"| {r['band']} | {cands} | {r['coverage_pct']:.2f} | {r['coverage_min_pct']:.2f} | "
                     f"{r['bad3_pct']:.2f} | {r['warm_s']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
