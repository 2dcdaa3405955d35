"""What a person sees while a pair is computed: the compile and compute phases timed apart, and a
progress bar over the strips of a tiled frame. The predictor itself prints nothing.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from stereojax.inference import tiling
from stereojax.inference.compile_cache import bucket_shape
from stereojax.progress import Phases


def timed(predictor, left, right, phases=None, pixel_range=None) -> tuple[np.ndarray, dict]:
    """(disparity, timings) of a pair computed by ``predictor``, compilation timed apart: ``timings`` has ``seconds``
    (the run), ``compile_s`` (0 when this process had compiled the chain already), the
    ``bucket`` [H, W] and the ``device``. ``phases``: a :class:`stereojax.progress.Phases`
    that shows each step (default: silent). ``pixel_range``: as in :meth:`Predictor.__call__ <stereojax.inference.predictor.Predictor.__call__>`."""

    phases = phases or Phases(quiet=True)
    device = predictor.device
    limits = predictor.limits(pixel_range, np.shape(left))
    rows = predictor.strip_rows(left)
    if rows is not None:
        h, w = np.shape(left)[:2]
        n = len(tiling.strips(h, rows, tiling.SEAM_OVERLAP))
        out, secs = in_strips_shown(predictor, left, right, rows, n, phases, limits)
        shape = bucket_shape(rows, w)
        return out, {"seconds": secs, "compile_s": 0.0, "bucket": [int(shape[0]), int(shape[1])],
                     "device": str(device), "strips": n, "strip_rows": rows}
    gl, gr = predictor.prepare(left, right)
    shape = bucket_shape(*gl.shape)
    compile_s = 0.0
    limited = limits is not None
    if not predictor.is_compiled(*gl.shape, limited=limited):
        phases.start(f"compiling the {predictor.config.cost.method} chain for {shape[1]}x{shape[0]} "
                     f"(size bucket of {gl.shape[1]}x{gl.shape[0]}), {predictor.config.max_disp} disparities")
        predictor.compiled(*gl.shape, limited=limited)
        compile_s = phases.done()
    phases.start(f"computing the disparity of {gl.shape[1]}x{gl.shape[0]}")
    disp = predictor.run(gl, gr, limits)
    secs = phases.done()
    return disp, {"seconds": secs, "compile_s": compile_s, "bucket": [int(shape[0]), int(shape[1])],
                  "device": str(device)}


def in_strips_shown(predictor, left, right, rows: int, n: int, phases, limits=None):
    """:meth:`~stereojax.inference.predictor.Predictor.in_strips` with a progress bar over the strips (the time left) unless ``phases``
    is quiet; (disparity, seconds)."""
    h, w = np.shape(left)[:2]
    t0 = time.perf_counter()
    if phases.quiet:
        return predictor.in_strips(left, right, rows, limits=limits), time.perf_counter() - t0
    print(f"stereojax: computing the disparity of {w}x{h} in {n} strips of {rows} rows (the whole frame would "
          "not fit the memory limit; --tile off refuses it)", flush=True)
    with tqdm(total=n, desc="strips", unit="strip", file=sys.stderr, dynamic_ncols=True) as bar:
        out = predictor.in_strips(left, right, rows, on_strip=lambda: bar.update(1), limits=limits)
    return out, time.perf_counter() - t0
