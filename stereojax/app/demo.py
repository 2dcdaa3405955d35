"""``make demo``: the built-in real pair through the chain, its outputs and its errors."""

from __future__ import annotations

from pathlib import Path

from stereojax.app.evaluation import evaluate_frames
from stereojax.app.outputs import color_scale, write_confidence, write_prediction
from stereojax.data import io
from stereojax.data.io import write_json
from stereojax.inference.predictor import Predictor
from stereojax.progress import Phases


def run_demo(sample, run, out: Path) -> dict:
    """Disparity, depth, point cloud and error map of ``sample`` (with ground truth and
    calibration) by ``run`` (:class:`stereojax.models.registry.Resolved`, its max_disp the sample's),
    written into ``out``, each step shown on stdout. Returns the frame's scores."""
    max_disp = run.config.max_disp
    print(f"built-in sample: {sample.name} {sample.left.shape[1]}x{sample.left.shape[0]}, "
          f"{max_disp} disparities, {run.chosen_line}")
    phases = Phases()
    phases.start("loading the model" if run.method == "learned" else "preparing")
    model = run.model()
    phases.done()
    kept = {}

    def with_confidence(s, md):
        predictor = Predictor(run.config.with_max_disp(md), model, confidence=True)
        (disp, conf), timings = predictor.timed(s.left, s.right, phases)
        kept["confidence"] = conf
        return disp, timings

    result = evaluate_frames([sample], {"pipeline": with_confidence}, max_disp,
                             on_frame=lambda row, s, disparities: kept.update(disparities))
    disp, m = kept["pipeline"], result["frames"][0]["pipeline"]
    phases.start("writing disparity, confidence, depth, point cloud and error map")
    written = write_prediction(out, "", disp, sample.calib, sample.left, ply=True,
                               color_max=color_scale(disp, sample.gt, sample.gt_valid))
    written += write_confidence(out, "", kept["confidence"])
    io.write_png(out / "left.png", sample.left)
    io.write_error_map(out / "error.png", disp, sample.gt, sample.gt_valid)
    write_json(out / "metrics.json", {**m, "method": run.config.cost.method, "max_disp": max_disp})
    phases.done()
    print(f">2 px {m['bad2']:.2f} %   >3 px {m['bad3']:.2f} %   >4 px {m['bad4']:.2f} %   "
          f">5 px {m['bad5']:.2f} %   EPE {m['epe']:.2f} px   ({m['seconds']:.1f} s, "
          f"+ {m['compile_s']:.1f} s compiling)")
    print(f"-> {out} ({', '.join(written + ['left.png', 'error.png', 'metrics.json'])})")
    return m
