"""Which head evaluations does the learned chain need? Pruning schemes compared on KITTI 2015
training frames (the frames the shipped model trained on: the numbers rank schemes, they are
not a result; the chosen scheme is then scored on the validation frames 000021-000030).

Command:  .venv/bin/python experiments/investigations/prune_schemes.py [--frames 000001,000003,...]
              [--cache runs/prune_cache] [--out experiments/results/speed_schemes.md]
Running time here (2 cores): about 45 s per frame to cache the census top-16 candidates and
the head's cost at them (and at d0-2..d0+2), then about 4 s per frame and scheme.
Prints per scheme the head evaluations per pixel and the mean > 3 px error (noc GT) of the
full learned chain (``preset("learned")`` post-processing) on the frames.

A scheme builds the pruned volume from the cache, exactly as the chain does: fill 1 except at
  * ``top K``: the K best census candidates of every pixel;
  * ``top K + s x top K2``: also the K2 best for the share s of pixels with the poorest best
    head cost among their K (what ``cost.unsure_share`` / ``cost.unsure_candidates`` do);
  * ``window r``: d0 - r .. d0 + r around the census winner d0.
"""

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import jax
import jax.numpy as jnp

from stereojax import chain
from stereojax.matching_cost import learned as lc
from stereojax.inference.prepare import prepare_pair
from stereojax.inference.programs import chain_from_volume, disparity_grey
from stereojax.config import BandConfig, preset
from stereojax.data import DEFAULT_DATA, load_kitti2015
from stereojax.metrics import evaluate
from stereojax.models.registry import load_model, shipped_weights
from stereojax.models.nets import MatchNet

D, K = 228, 16
CFG = preset("learned", D)
SCHEMES = [("census",), ("top", 16), ("top", 8), ("top", 6), ("top", 4), ("window", 1), ("window", 2),
           ("top+", 4, 0.25, 16), ("top+", 4, 0.3, 12), ("top+", 5, 0.25, 12), ("top+", 6, 0.2, 16),
           ("top+", 8, 0.2, 16)]


def cache_frame(frame: str, folder: Path, model, data: str) -> Path:
    path = folder / f"{frame}.npz"
    if path.exists():
        return path
    net, v = model.net, model.variables
    s = load_kitti2015(Path(data) / "kitti2015" / "training", frame)
    gl, gr = (jnp.asarray(a) for a in prepare_pair(s.left, s.right, CFG))

    @jax.jit
    def compute(left, right):
        vol = chain.run(chain.CANDIDATE, chain.State(left, right),
                        lc.candidate_config(dataclasses.replace(CFG, band=BandConfig()))).vol.cost   # full range
        idx = jax.lax.top_k(-vol, K)[1].astype(jnp.int32)
        near = jnp.clip(idx[..., :1] + jnp.arange(-2, 3), 0, D - 1)
        fl, fr = lc.tower_features(net, v, left, right)
        cost = lc.head_at(MatchNet(net), v, fl, fr, jnp.concatenate([idx, near], -1), 4)
        return idx, cost

    idx, cost = compute(gl, gr)
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(path, cand=np.asarray(idx, np.uint8), head=np.asarray(cost[..., :K]),
             near_head=np.asarray(cost[..., K:]), gt=s.gt, gt_valid=s.gt_valid,
             left=np.asarray(gl), right=np.asarray(gr))
    return path


def build(z, scheme) -> np.ndarray:
    cand, head, near = z["cand"].astype(np.int64), z["head"], z["near_head"]
    h, w, _ = cand.shape
    vol = np.ones((h, w, D), np.float32)
    yy, xx = np.mgrid[:h, :w]
    if scheme[0] == "window":
        for j, o in enumerate(range(-2, 3)):
            if abs(o) <= scheme[1]:
                vol[yy, xx, np.clip(cand[..., 0] + o, 0, D - 1)] = near[..., j]
        return vol
    k1 = scheme[1]
    for k in range(k1):
        vol[yy, xx, cand[..., k]] = head[..., k]
    if scheme[0] == "top+":
        _, _, share, k2 = scheme
        chosen = np.argsort(-head[..., :k1].min(-1).ravel(), kind="stable")[:int(share * h * w)]
        ys, xs = np.unravel_index(chosen, (h, w))
        for k in range(k1, k2):
            vol[ys, xs, cand[ys, xs, k]] = head[ys, xs, k]
    return vol


def evals(scheme) -> float:
    if scheme[0] == "census":
        return 0.0
    if scheme[0] == "window":
        return 2 * scheme[1] + 1
    if scheme[0] == "top":
        return scheme[1]
    return scheme[1] + scheme[2] * (scheme[3] - scheme[1])


def label(scheme) -> str:
    return {"census": lambda: "census chain (no head)", "top": lambda: f"top {scheme[1]}",
            "window": lambda: f"window d0 +- {scheme[1]}",
            "top+": lambda: f"top {scheme[1]} + {scheme[2]:g} x top {scheme[3]}"}[scheme[0]]()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", default="000001,000003,000005,000007,000009,000011")
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    ap.add_argument("--cache", default="runs/prune_cache")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "results" / "speed_schemes.md"))
    args = ap.parse_args()
    model = load_model(shipped_weights("kitti2015"))
    frames = args.frames.split(",")
    paths = [cache_frame(f, Path(args.cache), model, args.data) for f in frames]
    post = jax.jit(lambda vol, a, b: chain_from_volume(vol, a, b, CFG).disparity)
    census = jax.jit(lambda a, b: disparity_grey(a, b, preset("census", D)))
    rows = []
    for scheme in SCHEMES:
        errs = []
        for p in paths:
            z = dict(np.load(p))
            a, b = jnp.asarray(z["left"]), jnp.asarray(z["right"])
            d = census(a, b) if scheme[0] == "census" else post(jnp.asarray(build(z, scheme)), a, b)
            errs.append(evaluate(np.asarray(d), z["gt"], z["gt_valid"])["bad3"])
        rows.append((label(scheme), evals(scheme), float(np.mean(errs)), errs))
        print(f"{rows[-1][0]:28s} {rows[-1][1]:5.2f} evaluations/pixel   > 3 px {rows[-1][2]:.3f} %", flush=True)
    lines = [f"# Pruning schemes of the learned head (KITTI 2015 training frames {', '.join(frames)})", "",
             "| scheme | head evaluations / pixel | > 3 px % (mean) | per frame |", "|---|---|---|---|"]
    lines += [f"| {r[0]} | {r[1]:g} | {r[2]:.3f} | {', '.join(f'{e:.2f}' for e in r[3])} |" for r in rows]
    lines += ["", f"Command: `python experiments/investigations/prune_schemes.py --frames {args.frames}`", ""]
    Path(args.out).write_text("\n".join(lines))
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
