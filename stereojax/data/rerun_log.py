"""Logging results to the Rerun viewer (``rerun-sdk``, an optional extra: ``pip install "stereojax[viewer]"``).

Per frame: the left image, disparity and confidence, depth with the left camera as a pinhole, and
the coloured point cloud. A sequence logs its frames on the ``frame`` timeline, with the stream's
prior and fallbacks as text events; a batch logs each frame under its name. The result is an
``.rrd`` file (``rerun FILE.rrd`` or https://app.rerun.io opens it) or, with ``serve``, Rerun's
web viewer.

Entities (under ``world/``): ``camera`` (Pinhole; the rectified left camera), ``camera/image``,
``camera/depth`` (DepthImage, metres), ``disparity``, ``confidence`` (images), ``points``
(Points3D, metres, the same points as points.ply), ``events`` (TextLog).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stereojax.errors import ConfigError

INSTALL = 'pip install "stereojax[viewer]"  (or: pip install rerun-sdk)'


def rerun_module():
    """The ``rerun`` module, or a one-line :class:`ConfigError` with the install command."""
    try:
        import rerun
    except ImportError:
        raise ConfigError(f"--rerun needs the Rerun viewer's package rerun-sdk, which is not installed: "
                          f"{INSTALL}") from None
    return rerun


class RerunLog:
    """One Rerun recording: to an ``.rrd`` file (``path``) and/or Rerun's web viewer (``serve``)."""

    def __init__(self, path=None, serve: bool = False, name: str = "stereojax"):
        rr = rerun_module()
        if path is None and not serve:
            raise ConfigError("a Rerun log needs a file (--rerun FILE.rrd) or --rerun-serve")
        if path is not None and Path(path).suffix != ".rrd":
            raise ConfigError(f"--rerun takes a file ending in .rrd, got {str(path)!r}")
        self.rr, self.path = rr, None if path is None else Path(path)
        self.rec = rr.RecordingStream(name)
        self.url = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        if serve:       # the gRPC server keeps the log for viewers that connect late; the web viewer reads it
            sinks = [rr.GrpcServerSink()] + ([rr.FileSink(str(self.path))] if self.path is not None else [])
            self.rec.set_sinks(*sinks)
            self.url = "rerun+http://127.0.0.1:9876/proxy"
            rr.serve_web_viewer(open_browser=False, connect_to=self.url)
        else:
            self.rec.save(str(self.path))
        self.rec.log("world", rr.ViewCoordinates.RDF, static=True)   # x right, y down, z forward (OpenCV)

    def frame(self, name: str, left, disparity, confidence=None, depth=None, calib=None, points=None,
              colors=None, index: int | None = None, events=()) -> None:
        """Log one frame: on the ``frame`` timeline at ``index`` (a sequence), under ``world/`` when
        ``name`` is None (one pair), else under ``world/<name>/`` (a batch: each frame its own tree)."""
        rr, rec = self.rr, self.rec
        if index is not None:
            rec.set_time("frame", sequence=int(index))
        root = "world" if index is not None or name is None else f"world/{_entity(name)}"
        h, w = np.shape(disparity)[:2]
        if calib is not None:
            cx = calib.cx if calib.cx is not None else (w - 1) / 2
            cy = calib.cy if calib.cy is not None else (h - 1) / 2
            rec.log(f"{root}/camera", rr.Pinhole(focal_length=float(calib.focal), principal_point=[cx, cy],
                                                 width=w, height=h))
        rec.log(f"{root}/camera/image", rr.Image(np.ascontiguousarray(left)))
        rec.log(f"{root}/disparity", rr.DepthImage(np.nan_to_num(np.asarray(disparity, np.float32), nan=0.0),
                                                   meter=1.0))
        if confidence is not None:
            rec.log(f"{root}/confidence", rr.Image(np.clip(np.asarray(confidence) * 255, 0, 255).astype(np.uint8)))
        if depth is not None:
            rec.log(f"{root}/camera/depth", rr.DepthImage(np.asarray(depth, np.float32), meter=1.0))
        if points is not None and len(points):
            rec.log(f"{root}/points", rr.Points3D(np.asarray(points, np.float32),
                                                  colors=None if colors is None else np.asarray(colors, np.uint8)))
        for text in events:
            rec.log("events" if root == "world" else f"{root}/events", rr.TextLog(str(text)))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


def _entity(name: str) -> str:
    """A frame name as one entity path part."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in str(name)) or "frame"


def log_rerun(path, frames, serve: bool = False) -> Path | None:
    """Python: log ``frames`` (dicts with the arguments of :meth:`RerunLog.frame`: name, left,
    disparity, and optionally confidence, depth, calib, points, colors, index, events) to an
    ``.rrd`` file and/or the web viewer; returns the file's path."""
    log = RerunLog(path, serve)
    try:
        for f in frames:
            log.frame(**f)
    finally:
        log.close()
    return log.path


def log_outputs(log: RerunLog, folder, name: str | None, calib=None, index: int | None = None, events=(),
                to_original=None, left_path=None, max_depth: float | None = None) -> None:
    """Log one frame from what predict wrote into ``folder``: the left image (``left_rectified.png``
    when the pair was rectified, else ``left_path``, else ``left``'s file from ``frame.json``),
    disparity, confidence, depth and the coloured point cloud (from the disparity and ``calib``, as
    far as points.ply goes: ``max_depth``, else the calibration's measurable depth)."""
    from stereojax.data import depth as depth_mod, io

    folder = Path(folder)
    disp = io.read_pfm(folder / "disparity.pfm")
    conf = np.load(folder / "confidence.npy") if (folder / "confidence.npy").is_file() else None
    depth = np.load(folder / "depth.npy") if (folder / "depth.npy").is_file() else None
    left = None
    if (folder / "left_rectified.png").is_file():          # a rectified pair: the image matched
        left = io.read_image(folder / "left_rectified.png")
    elif left_path is not None:
        left = io.read_image(left_path)
    elif (folder / "frame.json").is_file():                # a batch frame: its recorded input
        import json

        src = json.loads((folder / "frame.json").read_text()).get("left", {}).get("path")
        left = io.read_image(src) if src and Path(src).is_file() else None
    if left is None:
        left = np.zeros(disp.shape, np.uint8)
    points = colors = None
    if calib is not None:
        far = max_depth if max_depth is not None else depth_mod.measurable_depth(calib)     # as points.ply
        points, colors = depth_mod.point_cloud(np.where(np.isfinite(disp), disp, 0), left, calib, max_depth=far)
        if to_original is not None:
            points = to_original(points)
    log.frame(name, left, disp, conf, depth, calib, points, colors, index, events)
