"""``make demo``: the built-in real pair through the chain, its outputs and its errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from stereojax.app.evaluation import evaluate_frames
from stereojax.app.outputs import color_scale, write_confidence, write_prediction
from stereojax.data import io
from stereojax.data.io import write_json
from stereojax.inference.predictor import Predictor
from stereojax.progress import Phases


def run_demo(sample, run, out: Path, kernels_line: str | None = None) -> dict:
    """Disparity, depth, point cloud and error map of ``sample`` (with ground truth and
    calibration) by ``run`` (:class:`stereojax.models.registry.Resolved`, its max_disp the sample's),
    written into ``out``, each step shown on stdout (``kernels_line``, the kernels in words, right
    after the first line). Returns the frame's scores."""
    max_disp = run.config.max_disp
    print(f"built-in sample: {sample.name} {sample.left.shape[1]}x{sample.left.shape[0]}, "
          f"{max_disp} disparities, {run.chosen_line}")
    if kernels_line:
        print(kernels_line)
    phases = Phases()
    phases.start("loading the model" if run.method == "learned" else "preparing")
    model = run.model()
    phases.done()
    kept = {}

    def with_confidence(s, md):
        predictor = Predictor(run.config.with_max_disp(md), model, confidence=True, cascade=run.cascade_arg())
        (disp, conf), timings = predictor.timed(s.left, s.right, phases)
        kept["confidence"] = conf
        return disp, timings

    result = evaluate_frames([sample], {"pipeline": with_confidence}, max_disp,
                             on_frame=lambda row, s, disparities: kept.update(disparities))
    disp, m = kept["pipeline"], result["frames"][0]["pipeline"]
    phases.start("writing disparity, confidence, depth, point cloud and error map")
    written = write_prediction(out, "", disp, sample.calib, sample.left, ply=True,
                               color_max=color_scale(disp, sample.gt, sample.gt_valid), confidence=kept["confidence"])
    written += write_confidence(out, "", kept["confidence"])
    io.write_png(out / "left.png", sample.left)
    io.write_error_map(out / "error.png", disp, sample.gt, sample.gt_valid)
    io.write_png(out / "error_legend.png", io.error_legend())
    io.write_png(out / "overview.png", overview(out, m))
    write_json(out / "metrics.json", {**m, "method": run.config.cost.method, "max_disp": max_disp})
    phases.done()
    print(f">2 px {m['bad2']:.2f} %   >3 px {m['bad3']:.2f} %   >4 px {m['bad4']:.2f} %   "
          f">5 px {m['bad5']:.2f} %   EPE {m['epe']:.2f} px   ({m['seconds']:.1f} s, "
          f"+ {m['compile_s']:.1f} s compiling)")
    print(f"-> {out} ({', '.join(written + ['left.png', 'error.png', 'error_legend.png', 'overview.png', 'metrics.json'])})")
    return m


def overview(out: Path, scores: dict, width: int = 360) -> np.ndarray:
    """``u8[H, W, 3]``: the demo's outputs in one picture, each captioned with its scale: the left
    image, the colour disparity, the colour depth and the error map (from the files in ``out``)."""

    disp_scale = json.loads((out / "disparity_color.json").read_text())
    depth_scale = json.loads((out / "depth_color.json").read_text())
    left = io.read_image(out / "left.png")
    left = left if left.ndim == 3 else np.repeat(left[..., None], 3, axis=2)
    panels = [(left, "left image"),
              (io.read_image(out / "disparity_color.png"), f"disparity: blue 0 .. red {disp_scale['max']:.0f} px"),
              (io.read_image(out / "depth_color.png"),
               f"depth: red {depth_scale['near']:.1f} .. blue {depth_scale['far']:.1f} m, grey unsure"),
              (io.read_image(out / "error.png"), f"error: orange-red > 3 px ({scores['bad3']:.2f} %)")]
    tiles = []
    for img, caption in panels:
        h = round(img.shape[0] * width / img.shape[1])
        tile = cv2.resize(img[..., :3], (width, h), interpolation=cv2.INTER_AREA)
        strip = np.full((22, width, 3), 255, np.uint8)
        cv2.putText(strip, caption, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.concatenate([strip, tile]))
    return np.concatenate([np.concatenate(tiles[:2], axis=1), np.concatenate(tiles[2:], axis=1)])
