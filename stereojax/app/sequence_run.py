"""``stereojax predict --sequence``: an ordered set of pairs as a stream
(:class:`stereojax.inference.sequence.Sequence`), with the batch's outputs, resume, lock and
signals (:func:`stereojax.app.batch.predict_batch_locked`), and a video of the result.

The frames run in order on one device. A frame skipped because an earlier run completed it, or
a gap in the order, restarts the stream (the next computed frame runs without a prior; its
record says so). After the frames, ``sequence.mp4`` (or ``sequence.png``, an animated PNG,
where OpenCV has no MP4 codec) shows each frame's left image above its colour disparity, at
``fps`` frames per second, with one colour scale for the whole sequence; ``summary.json`` holds
each frame's record (``per_frame[i]["sequence"]``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import cv2
import numpy as np

from stereojax.app.batch import frame_work, predict_batch_locked
from stereojax.app.outputs import folder_lock, output_folder
from stereojax.data import io
from stereojax.data.images import to_u8
from stereojax.devices import current_device
from stereojax.errors import ConfigError
from stereojax.inference.sequence import PriorSettings, Sequence


class SequenceHolder:
    """The stream behind a batch's frames: one :class:`Sequence` per method, reset at a gap."""

    def __init__(self, pairs, settings: PriorSettings | None = None):
        self.order = {name: i for i, (name, _, _) in enumerate(pairs)}
        self.settings = settings or PriorSettings()
        self.seq, self.key, self.last, self.current = None, None, None, None

    def push(self, run, sample):
        """(the :class:`~stereojax.inference.sequence.Frame` of this frame, seconds compiling)."""
        key = (run.description, run.config)
        if self.seq is None or key != self.key:
            self.seq = Sequence(run.config, run.model(), self.settings, current_device(), run.cascade_arg())
            self.key = key
        i = self.order.get(self.current)
        gap = self.last is not None and (i is None or i != self.last + 1)
        if gap:
            self.seq.reset()
        self.last = i
        h, w = np.shape(sample.left)[:2]
        compile_s = self.seq.compile(h, w)
        frame = self.seq.push(sample.left, sample.right)
        if gap and frame.record.get("fallback") == "first frame":
            frame.record["fallback"] = "the previous frame was not computed in this run (resumed or missing): no prior"
        return frame, compile_s


def predict_sequence(pairs, out: Path, resolve, opts: dict, fps: float = 10.0, overwrite: bool = False,
                     verify: bool = False, unmatched=None, announced=None, settings: PriorSettings | None = None):
    """The pairs, in their order, as one stream into ``out/<name>/`` (as a batch), then the video;
    ``summary.json`` as a batch's with each frame's sequence record. Returns the summary."""
    if opts.get("disp_range") is not None:
        raise ConfigError("--sequence takes its limits from the previous frame; it runs without --disp-range")
    if not fps > 0:
        raise ConfigError(f"--fps must be positive, got {fps}")
    holder = SequenceHolder(pairs, settings)
    seq_opts = {**opts, "sequence": holder}

    def mapper(items):
        for pair in items:
            holder.current = pair[0]
            yield frame_work(pair, out, resolve, seq_opts)

    with folder_lock(output_folder(out), "predict"):
        summary = predict_batch_locked(pairs, out, resolve, seq_opts, [current_device()], overwrite, verify, unmatched,
                                       announced, mapper=mapper, workers=1, where="a sequence: frames in order, "
                                       "each with the previous frame's disparity as its prior")
    video = write_video(out, pairs, fps)
    if video is not None:
        print(f"stereojax predict: video -> {video}", file=sys.stderr)
    return summary


def write_video(out: Path, pairs, fps: float) -> Path | None:
    """``out/sequence.mp4`` (else an animated ``out/sequence.png``) of every computed frame: the
    left image above the colour disparity, one colour scale (the largest of the frames' 99.5th
    percentiles). None when no frame is there."""
    frames = [(name, left) for name, left, _ in pairs if (out / name / "disparity.pfm").is_file()]
    if not frames:
        return None
    disps = [io.read_pfm(out / name / "disparity.pfm") for name, _ in frames]
    top = max(float(np.percentile(d[np.isfinite(d)], 99.5)) if np.isfinite(d).any() else 1.0 for d in disps)
    panels = []
    for (name, left_p), d in zip(frames, disps):
        left = to_u8(io.read_image(left_p))
        left = np.repeat(left[..., None], 3, -1) if left.ndim == 2 else left
        color = io.colorize_disparity(np.where(np.isfinite(d), d, 0.0), max(top, 1.0))
        if color.shape[:2] != left.shape[:2]:
            color = cv2.resize(color, (left.shape[1], left.shape[0]), interpolation=cv2.INTER_NEAREST)
        panels.append(np.concatenate([left, color.astype(np.uint8)], 0))
    h = max(p.shape[0] for p in panels)
    w = max(p.shape[1] for p in panels)
    panels = [np.pad(p, ((0, h - p.shape[0]), (0, w - p.shape[1]), (0, 0))) for p in panels]
    # written under a hidden name and renamed once complete: a killed run leaves no half video
    tmp = out / f".sequence.partial-{os.getpid()}.mp4"
    try:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
        if writer.isOpened():
            for p in panels:
                writer.write(cv2.cvtColor(p, cv2.COLOR_RGB2BGR))
            writer.release()
            if tmp.is_file() and tmp.stat().st_size > 0:
                os.replace(tmp, out / "sequence.mp4")
                return out / "sequence.mp4"
        from PIL import Image          # an animated PNG where OpenCV writes no MP4

        tmp = tmp.with_suffix(".png")
        images = [Image.fromarray(p) for p in panels]
        images[0].save(tmp, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
        os.replace(tmp, out / "sequence.png")
        return out / "sequence.png"
    finally:
        for leftover in (tmp, tmp.with_suffix(".mp4")):
            leftover.unlink(missing_ok=True)
