"""Searching a learned model's chain settings on one's own frames (``stereojax tune``), and the
search the experiments use (experiments/search_chain.py): the model's cost volume of every frame is
computed once and cached, then a coordinate search over the settings that come after it (CBCA, SGM,
refinement), each setting scored on the cached volumes. The result is written as the model's card
(``NAME.json`` beside ``NAME.msgpack``, its ``"chain"`` entry), which ``--method best`` and
``--weights`` then run with.
"""

from __future__ import annotations

import dataclasses
import datetime
import time

from stereojax.app.evaluation import evaluate_frames
from stereojax.config import StereoConfig
from stereojax.inference.predictor import Predictor
from stereojax.inference.programs import disparity_from_volume

#: the sections of a StereoConfig a card's "chain" entry may override
SECTIONS = ("cost", "cbca", "sgm", "refine", "band")

#: (section, field, values tried); the shipped value is always among the candidates
SPACE = [
    ("sgm", "p1", [0.25, 0.35, 0.5, 0.7, 1.0]),
    ("sgm", "p2", [4.0, 6.0, 8.0, 11.0, 15.0]),
    ("cbca", "iterations_before", [0, 1, 2, 3, 4]),
    ("cbca", "iterations_after", [0, 1, 2]),
    ("cbca", "tau", [10.0, 15.0, 20.0, 30.0]),
    ("cbca", "arm_length", [3, 5, 7, 9]),
    ("sgm", "q1", [1.5, 3.0, 4.5]),
    ("sgm", "q2", [3.0, 6.0, 10.0]),
    ("sgm", "grad_threshold", [8.0, 15.0, 25.0]),
    ("refine", "lr_tolerance", [0.5, 1.0, 2.0, 3.0]),
    ("refine", "median_size", [0, 3, 5, 7]),
]

#: a smaller space for data sets of many sizes (Middlebury: every scene size and disparity range
#: is a program of its own, so each setting costs a compilation per scene)
SPACE_SMALL = [
    ("sgm", "p1", [0.25, 0.35, 0.5, 0.7, 1.0]),
    ("sgm", "p2", [4.0, 6.0, 8.0, 11.0, 15.0]),
    ("cbca", "iterations_before", [0, 1, 2, 3, 4]),
    ("refine", "lr_tolerance", [0.5, 1.0, 2.0, 3.0]),
    ("refine", "median_size", [0, 3, 5, 7]),
]

#: around a setting already searched (``--start card``): one step either way of every value the
#: KITTI search chose, P1 and P2 beyond the ends of SPACE's lists (the first search stopped at
#: P1 = 1.0 and P2 = 4.0, the top and the bottom of its lists)
SPACE_LOCAL = [
    ("sgm", "p1", [0.7, 1.0, 1.5, 2.0]),
    ("sgm", "p2", [3.0, 4.0, 5.0, 6.0]),
    ("cbca", "iterations_before", [0, 1, 2]),
    ("cbca", "tau", [7.0, 10.0, 15.0]),
    ("cbca", "arm_length", [5, 7]),
    ("sgm", "q2", [6.0, 10.0, 15.0]),
    ("refine", "lr_tolerance", [1.0, 2.0]),
    ("refine", "median_size", [5, 7, 9]),
]

SPACES = {"full": SPACE, "small": SPACE_SMALL, "local": SPACE_LOCAL}


def with_value(cfg: StereoConfig, section: str, name: str, value) -> StereoConfig:
    sub = dataclasses.replace(getattr(cfg, section), **{name: value})
    try:
        return dataclasses.replace(cfg, **{section: sub}).validate()
    except Exception:          # e.g. p2 < p1: not a valid setting
        return None


def cache_volumes(samples, model, base: StereoConfig, max_disp) -> dict:
    """The learned volume of every sample, computed once (:meth:`stereojax.Predictor.volume`):
    ``{"model", "samples", "max_disp": {name: D}, "volumes": {name: Volume}}``.
    max_disp(sample) -> disparities."""
    cache = {"model": model, "samples": list(samples), "max_disp": {}, "volumes": {}}
    t0 = time.perf_counter()
    for s in cache["samples"]:
        md = cache["max_disp"][s.name] = max_disp(s)
        cache["volumes"][s.name] = Predictor(base.with_max_disp(md), model).volume(s.left, s.right)
        print(f"volume {s.name} ({s.left.shape[1]}x{s.left.shape[0]}, {md} disparities): "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
    return cache


def score(cache, cfg: StereoConfig, threshold: str = "bad3") -> tuple[float, list[float]]:
    """Mean error (``threshold``: bad2, bad3, ... or "bad2+bad3" for their mean; on the sample's
    GT) of the chain ``cfg`` run on the cached volumes, and the per-frame errors."""
    def from_volume(s, md):
        return Predictor(cfg.with_max_disp(md), cache["model"]).from_volume(cache["volumes"][s.name])

    rows = evaluate_frames(cache["samples"], {"chain": from_volume}, lambda s: cache["max_disp"][s.name])["frames"]
    errs = [float(sum(r["chain"][k] for k in threshold.split("+")) / len(threshold.split("+"))) for r in rows]
    # every setting is a new program: drop the old ones (a search of ~75 KITTI-sized programs
    # kept in memory ended in "LLVM compilation error: Cannot allocate memory" here)
    disparity_from_volume.clear_cache()
    return float(sum(errs) / len(errs)), errs


def coordinate_search(cache, base: StereoConfig, space=SPACE, rounds: int = 2, threshold: str = "bad3",
                      on_trial=None):
    """Each parameter of ``space`` in turn takes its best value (lowest mean error over the
    cached frames), ``rounds`` times over (stopping early when nothing changes).
    Returns (best config, its error, the shipped config's error, the log of every trial).
    on_trial(best, best_err, start_err, log): called after every trial (to save progress)."""
    log, seen = [], {}

    def trial(cfg, what):
        key = cfg.to_json()
        if key not in seen:
            t = time.perf_counter()
            seen[key] = score(cache, cfg, threshold)
            log.append({"setting": what, threshold: seen[key][0], "per_frame": seen[key][1],
                        "seconds": time.perf_counter() - t})
            print(f"{seen[key][0]:6.3f}  {time.perf_counter() - t:5.1f}s  {what}", flush=True)
        return seen[key][0]

    best = base
    best_err = start_err = trial(best, "start")
    for rnd in range(rounds):
        changed = False
        for section, name, values in space:
            for v in values:
                cand = with_value(best, section, name, v)
                if cand is None or cand == best:
                    continue
                err = trial(cand, f"round {rnd + 1}: {section}.{name} = {v}  (on {changes(base, best) or 'preset'})")
                if err < best_err - 1e-6:
                    best, best_err, changed = cand, err, True
                if on_trial is not None:
                    on_trial(best, best_err, start_err, log)
        if not changed:
            break
    return best, best_err, start_err, log


def overrides(a: StereoConfig, b: StereoConfig) -> dict:
    """The fields where b differs from a as StereoConfig overrides ({"sgm": {"p1": 1.0}, ...}),
    the form of a model card's "chain" entry."""
    out: dict = {}
    for section in SECTIONS:
        for f in dataclasses.fields(getattr(a, section)):
            va, vb = getattr(getattr(a, section), f.name), getattr(getattr(b, section), f.name)
            if va != vb:
                out.setdefault(section, {})[f.name] = list(vb) if isinstance(vb, tuple) else vb
    return out


def changes(a: StereoConfig, b: StereoConfig) -> str:
    """The fields where b differs from a, as 'sgm.p1=0.7, ...'."""
    out = []
    for section in SECTIONS:
        for f in dataclasses.fields(getattr(a, section)):
            va, vb = getattr(getattr(a, section), f.name), getattr(getattr(b, section), f.name)
            if va != vb:
                out.append(f"{section}.{f.name}={vb}")
    return ", ".join(out)



def tune(weights, samples, max_disp, space: str = "small", rounds: int = 1, threshold: str = "bad3",
         write: bool = True, on_trial=None) -> dict:
    """Search the chain settings of the learned model ``weights`` (a checkpoint) on ``samples``
    (StereoSamples with ground truth; max_disp(sample) -> its disparities), starting from the
    settings it runs with now (its card, else the learned preset), and write the best as its card
    (:func:`stereojax.models.registry.write_card`) when ``write``. Returns ``{"start", "best",
    "changes", "overrides", "card", "trials"}`` (errors in % of ``threshold``)."""
    from stereojax.config import preset
    from stereojax.models.registry import learned_config, load_model, write_card

    if space not in SPACES:
        raise ValueError(f"space must be one of {sorted(SPACES)}, got {space!r}")
    model = load_model(weights)
    base = learned_config(weights)
    cache = cache_volumes(samples, model, base, max_disp)
    best, best_err, start_err, log = coordinate_search(cache, base, SPACES[space], rounds, threshold, on_trial)
    names = [s.name for s in cache["samples"]]
    over = overrides(preset("learned"), best)
    card = None
    if write:
        card = write_card(weights, over, chain_from=f"searched by stereojax tune on {len(names)} frames "
                          f"({', '.join(names[:6])}{', ...' if len(names) > 6 else ''}) on "
                          f"{datetime.date.today().isoformat()}: {threshold} {start_err:.2f} -> {best_err:.2f} %",
                          tuned={"frames": names, "threshold": threshold, "space": space, "rounds": rounds,
                                 "start": start_err, "best": best_err, "changes": changes(base, best)})
    return {"start": start_err, "best": best_err, "changes": changes(base, best), "overrides": over,
            "card": card, "trials": log}
