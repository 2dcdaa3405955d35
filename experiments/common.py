"""Shared machinery of the experiment scripts (Tables 1-4, Figures 5-8): data splits, training
with reuse, and scoring of learned and classical methods in the full chain.

Every script takes ``--quick``: a tiny network trained for a few steps and one cropped frame per
data set, a smoke test of the whole path in well under a minute (``tests/system/test_experiments.py``
runs every script that way). Without ``--quick`` the scripts run the *experiment schedule*: the
shipped network (64 feature maps, downsize head) trained for ``--steps`` SGD steps (default
1000 of 150 + 150 + 150 patches, about 2 min on 2 cores) and scored in the chain of
``preset("learned")`` in pruned mode with ``--candidates`` (default 8) census candidates per
pixel (the dense head costs about 0.66 MFLOP per pixel and candidate, so K = 8 is about 12 s a
KITTI frame here; the exact head would be about 5 min). That schedule is a reduced one,
chosen so that 3 seeds x several variants fit in one CPU session; the numbers it gives compare
variants with each other, not with the paper's absolute numbers.

Trained models are cached in ``runs/experiments/<name>/`` (a killed script resumes where it
stopped, and Table 1 and the Delta sweep share their runs); each model's scores are cached next
to it in ``scores.json``, keyed by the evaluation set and chain.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

import stereojax  # noqa: E402
from stereojax.app.baselines import sgbm_disparity  # noqa: E402
from stereojax.data.datasets import DEFAULT_DATA, load_dataset, search_range  # noqa: E402
from stereojax.data.io import atomic_output, write_json  # noqa: E402
from stereojax.app.evaluation import evaluate_frames  # noqa: E402
from stereojax.metrics import mean_metrics  # noqa: E402
from stereojax.models.registry import load_model  # noqa: E402
from stereojax.learning.train import fit, train_preset  # noqa: E402

RESULTS = ROOT / "experiments" / "results"
RUNS = ROOT / "runs" / "experiments"

MIDDLEBURY_TRAIN = ["Aloe_opencv", "Cones_2003Q", "Reindeer_2006H", "Teddy_2003Q", "Tsukuba_2001", "Venus_2001"]
#: Middlebury test scenes of the experiments: the four small 2001/2003 scenes (0.6 Mpixel in
#: all; the larger Reindeer, Motorcycle and Aloe would triple the scoring time of every model)
MIDDLEBURY_TEST = ["Cones_2003Q", "Teddy_2003Q", "Tsukuba_2001", "Venus_2001"]

#: data splits: (dataset, frames) per role. Full mode: KITTI 2015 000001-000020 train /
#: 000021-000030 test (the shared data's suggested split); Middlebury: six scenes train,
#: Motorcycle held out (and all seven are unseen by a KITTI model).
FULL = {
    "train": {"kitti2015": [f"{i:06d}" for i in range(1, 21)], "middlebury": MIDDLEBURY_TRAIN},
    "val": {"kitti2015": [f"{i:06d}" for i in range(21, 31)], "middlebury": ["Motorcycle_MiddEval3Q"]},
    "test": {"kitti2015": [f"{i:06d}" for i in range(21, 31)], "kitti2012": ["000000"],
             "middlebury": MIDDLEBURY_TEST},
}
QUICK = {
    "train": {"kitti2015": ["000001", "000002"], "middlebury": ["Venus_2001"]},
    "val": {"kitti2015": ["000021"], "middlebury": ["Tsukuba_2001"]},
    "test": {"kitti2015": ["000021"], "kitti2012": ["000000"], "middlebury": ["Tsukuba_2001"]},
}
#: quick mode scores a bottom-centre crop of each KITTI frame (road and cars) with 48 disparities
QUICK_CROP = (128, 320)
QUICK_KITTI_DISP = 48

LABELS = {"kitti2015": "KITTI 2015", "kitti2012": "KITTI 2012", "middlebury": "Middlebury"}


def add_common_args(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    ap.add_argument("--quick", action="store_true", help="tiny smoke-test mode (seconds to a minute)")
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="shared data root (default ../shared/data)")
    ap.add_argument("--steps", type=int, help="SGD steps per model (default 1000; quick 12)")
    ap.add_argument("--candidates", type=int, default=8,
                    help="pruned mode: census candidates per pixel for dense heads (0 = exact)")
    ap.add_argument("--kitti-frames", type=int,
                    help="score only the first N KITTI 2015 test frames (default: all 10)")
    ap.add_argument("--out", default=str(RESULTS), help="results folder")
    ap.add_argument("--runs", default=str(RUNS), help="folder of cached trained models")
    return ap


@dataclasses.dataclass(frozen=True)
class Setup:
    """Resolved mode of one experiment script (see the module docstring)."""

    quick: bool
    data: Path
    steps: int
    candidates: int
    kitti_frames: int | None
    out: Path
    runs: Path

    @classmethod
    def from_args(cls, args) -> "Setup":
        steps = args.steps or (12 if args.quick else 1000)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        return cls(bool(args.quick), Path(args.data), steps, 8 if args.quick else args.candidates,
                   args.kitti_frames, out, Path(args.runs) / ("quick" if args.quick else "full"))

    @property
    def splits(self) -> dict:
        return QUICK if self.quick else FULL

    @property
    def tag(self) -> str:
        return "quick" if self.quick else f"steps{self.steps}"

    # ---- data --------------------------------------------------------------------------------

    def frames(self, role: str, dataset: str) -> list[str]:
        ids = self.splits[role][dataset]
        if role == "test" and dataset == "kitti2015" and self.kitti_frames:
            ids = ids[: self.kitti_frames]
        return ids

    def samples(self, role: str, dataset: str) -> list:
        # KITTI 2015: non-occluded GT; Middlebury and KITTI 2012 (only disp_occ is shared): all pixels
        gt = "noc" if dataset == "kitti2015" else "occ"
        out = [load_sample(str(self.data), dataset, f, gt) for f in self.frames(role, dataset)]
        if self.quick and role == "test" and dataset.startswith("kitti"):
            out = [s.crop(*QUICK_CROP) for s in out]
        return out

    def max_disp(self, dataset: str, sample) -> int:
        if self.quick and dataset.startswith("kitti"):
            return QUICK_KITTI_DISP
        return search_range(dataset, sample)

    # ---- training ----------------------------------------------------------------------------

    def train_config(self, head: str, loss: str, delta: float, seed: int):
        if self.quick:
            return train_preset("tiny", head=head, loss=loss, delta=delta, seed=seed, steps=self.steps,
                                val_every=self.steps, checkpoint_every=self.steps)
        return train_preset("cpu", head=head, loss=loss, delta=delta, seed=seed, steps=self.steps,
                            checkpoint_every=max(self.steps // 4, 1), val_every=self.steps, log_every=50)

    def train(self, dataset: str, head: str = "downsize", loss: str = "relaxed", delta: float = 0.05,
              seed: int = 0) -> Path:
        """Train (or reuse) one model; returns its run folder (checkpoint + train_summary.json)."""
        cfg = self.train_config(head, loss, delta, seed)
        run = self.runs / f"{dataset}_{head}_{loss}_d{delta:g}_s{seed}_{self.tag}"
        done = run / "train_summary.json"
        if done.is_file() and json.loads(done.read_text()).get("steps") == cfg.steps:
            return run
        print(f"  training {run.name} ({cfg.steps} steps)", flush=True)
        info = {"data": {"dataset": dataset, "frames": self.frames("train", dataset),
                         "val_frames": self.frames("val", dataset)}}
        fit(cfg, self.samples("train", dataset), self.samples("val", dataset), run, resume=True,
            progress=False, info=info)
        return run

    # ---- scoring -----------------------------------------------------------------------------

    def chain(self, max_disp: int, head: str):
        """The learned chain (``preset("learned")``) with this setup's pruning: the head on the K
        best census candidates of every pixel, not adaptive (cosine: exact)."""
        base = stereojax.preset("learned", max_disp)
        k = 0 if head == "cosine" else min(self.candidates, max_disp)
        cost = dataclasses.replace(base.cost, candidates=k, unsure_share=0.0, unsure_candidates=0)
        return dataclasses.replace(base, cost=cost).validate()

    def score_model(self, run: Path, dataset: str) -> dict:
        """Scores of a trained model on the test frames of ``dataset`` (cached in the run folder)."""
        key = f"{dataset}:{','.join(self.frames('test', dataset))}:k{self.candidates}"
        cache = run / "scores.json"
        scores = json.loads(cache.read_text()) if cache.is_file() else {}
        if key in scores:
            return scores[key]
        model = load_model(run / "checkpoint.msgpack")
        result = self.score(dataset, lambda s, md: stereojax.disparity(
            s.left, s.right, self.chain(md, model.net.head), params=model))
        scores[key] = result
        write_json(cache, scores)
        return result

    def score(self, dataset: str, predict) -> dict:
        """Run ``predict(sample, max_disp) -> (disparity[, est_valid])`` on the test frames of
        ``dataset`` (:func:`stereojax.app.evaluation.evaluate_frames`); returns per-frame and mean
        KITTI measures and the warm seconds per frame (frames of a size seen before in this
        process; the first of each size compiles)."""
        result = evaluate_frames(self.samples("test", dataset), {"m": predict},
                                 lambda s: self.max_disp(dataset, s))
        rows = [{"frame": r["frame"], "max_disp": r["max_disp"], **r["m"]} for r in result["frames"]]
        return {"mean": mean_metrics(rows), "frames": rows, "seconds_warm": result["mean"]["m"]["seconds_warm"],
                "seconds_first": rows[0]["seconds"]}


def census_predict(s, md):
    return stereojax.disparity(s.left, s.right, stereojax.preset("census", md))


def sgbm_predict(s, md):
    return sgbm_disparity(s.left, s.right, num_disp=md, pad=True)


@lru_cache(maxsize=64)
def load_sample(data: str, dataset: str, frame: str, gt: str):
    items = load_dataset(data, dataset, frames=[frame], gt=gt)
    return items[0][1]()


def shrink(rgb: np.ndarray, scale: float) -> np.ndarray:
    """Area-averaged downscale of a panel (scale >= 1: unchanged)."""
    import cv2

    if scale >= 1:
        return rgb
    h, w = rgb.shape[:2]
    return cv2.resize(rgb, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


# ---- numbers and tables ------------------------------------------------------------------------

def mean_std(values) -> tuple[float, float]:
    vals = [float(v) for v in values]
    return float(np.mean(vals)), (statistics.stdev(vals) if len(vals) > 1 else 0.0)


def pm(values, digits: int = 2) -> str:
    """'mean ± std' of a list of numbers (sample standard deviation over seeds)."""
    m, s = mean_std(values)
    return f"{m:.{digits}f} ± {s:.{digits}f}"


def write_outputs(setup: Setup, name: str, data: dict, markdown: str) -> None:
    """``<out>/<name>.json`` (with the mode and command) and ``<out>/<name>.md``, atomically;
    quick mode writes ``<name>_quick.*`` so that it never overwrites the full results."""
    stem = f"{name}_quick" if setup.quick else name
    script = Path(sys.argv[0]).resolve()
    shown = script.relative_to(ROOT) if ROOT in script.parents else script
    command = " ".join(["python", str(shown), *sys.argv[1:]])
    meta = {"command": command, "quick": setup.quick, "steps": setup.steps,
            "candidates": setup.candidates, "kitti_frames": setup.kitti_frames}
    write_json(setup.out / f"{stem}.json", {**meta, **data})
    with atomic_output(setup.out / f"{stem}.md") as tmp:
        Path(tmp).write_text(markdown.rstrip() + f"\n\nCommand: `{command}`\n")
    print(markdown)
    print(f"-> {setup.out / stem}.json, .md")


def md_table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)
