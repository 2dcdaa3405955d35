"""``stereojax predict --sequence``: an ordered set of pairs as a stream
(:class:`stereojax.inference.sequence.Sequence`), with the batch's outputs, resume, lock and
signals (:func:`stereojax.app.batch.predict_batch_locked`), and a video of the result.

The frames run in order on one device. A frame skipped because an earlier run completed it, or
a gap in the order, restarts the stream (the next computed frame runs without a prior; its
record says so). Each fallback (a scene cut, too little prior, a prior that disagrees with the
frame, a size change, a restart) is printed as one line when its frame finishes
(:func:`event_line`). After the frames, ``sequence.mp4`` (or ``sequence.png``, an animated PNG,
where OpenCV has no MP4 codec) shows each frame's name and what its prior did above its left
image, its colour disparity below, and a colour bar with the disparity scale, at ``fps`` frames
per second, with one colour scale for the whole sequence; ``sequence.json`` says the same in
words (:func:`write_video`). ``summary.json`` holds each frame's record
(``per_frame[i]["sequence"]``), the frames kept from an earlier run included (``"kept": true``).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from stereojax.app.batch import frame_work, predict_batch_locked
from stereojax.app.outputs import folder_lock, output_folder
from stereojax.data import io
from stereojax.data.images import to_u8
from stereojax.devices import current_device
from stereojax.errors import ConfigError
from stereojax.inference.sequence import PriorSettings, Sequence

#: the fallback of a frame that follows a frame this run did not compute
RESTART = "the previous frame was not computed in this run (resumed or missing): no prior"


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
            frame.record["fallback"] = RESTART
        return frame, compile_s


def event_line(name: str, record: dict | None) -> str | None:
    """The console line of a frame whose prior fell back (a scene cut, too little prior, a
    prior that disagrees, a size change, a restart after a frame this run did not compute); None
    for a frame that used its prior and for the first frame."""
    fallback = (record or {}).get("fallback")
    if not fallback or fallback == "first frame":
        return None
    tail = "" if "without" in fallback or "no prior" in fallback else "; ran without a prior"
    return f"stereojax predict: {name}: {fallback}{tail}"


def frame_mark(record: dict | None) -> str:
    """What a frame's prior did, in a few words (the video's label beside the frame's name):
    "prior" where it was used, "scene cut", "first frame", "restart" (the frame before was not
    computed in this run), "fallback: <why>" for the other fallbacks, "" without a record."""
    if not record:
        return ""
    if record.get("used_prior"):
        return "prior"
    fallback = record.get("fallback") or "no prior"
    if fallback.startswith("scene cut"):
        return "scene cut"
    if fallback == "first frame":
        return "first frame"
    if fallback == RESTART:
        return "restart"
    return "fallback: " + fallback.split(":")[0]


#: the label colours (RGB) of the video: the prior used, a scene cut, another fallback, neither
_MARK_COLOURS = {"prior": (80, 220, 80), "scene cut": (255, 80, 80), "fallback": (255, 170, 40)}


def _frame_record(folder: Path) -> dict | None:
    """A frame folder's sequence record (its ``timings.json``'s ``sequence``), None when unreadable."""
    try:
        rec = json.loads((folder / "timings.json").read_text()).get("sequence")
    except (OSError, ValueError, AttributeError):
        return None
    return rec if isinstance(rec, dict) else None


def _text(img: np.ndarray, text: str, x: int, y: int, scale: float, colour) -> None:
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, tuple(int(c) for c in colour),
                max(1, int(round(scale * 2))), cv2.LINE_AA)


def _strip_height(scale: float) -> int:
    return int(round(28 * scale)) + 6


def video_panel(name: str, left: np.ndarray, disp: np.ndarray, top: float, mark: str) -> np.ndarray:
    """One frame of the video, ``u8[H', W, 3]`` RGB: a header (the frame's name and ``mark``,
    :func:`frame_mark`, in green for "prior", red for "scene cut", orange for another fallback),
    the left image, the colour disparity (Turbo, 0 .. ``top`` px, black = no estimate) and a colour
    bar with its scale (0 and ``top`` px)."""
    left = to_u8(left)
    left = np.repeat(left[..., None], 3, -1) if left.ndim == 2 else left[..., :3]
    h, w = left.shape[:2]
    color = io.colorize_disparity(np.asarray(disp, np.float32), max(top, 1.0))
    if color.shape[:2] != (h, w):
        color = cv2.resize(color, (w, h), interpolation=cv2.INTER_NEAREST)
    scale = float(np.clip(w / 1600, 0.3, 0.8))
    sh = _strip_height(scale)
    head = np.zeros((sh, w, 3), np.uint8)
    baseline = sh - int(round(8 * scale)) - 2
    _text(head, name, 4, baseline, scale, (255, 255, 255))
    if mark:
        (tw, _), _ = cv2.getTextSize(name + "  ", cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, int(round(scale * 2))))
        colour = _MARK_COLOURS.get(mark.split(":")[0], (200, 200, 200))
        _text(head, mark, 4 + tw, baseline, scale, colour)
    # the colour bar: the middle half of the width (less where its labels need the room), labelled
    # 0 and the top of the scale
    bar = np.zeros((sh, w, 3), np.uint8)
    thick = max(1, int(round(scale * 2)))
    top_text = f"{max(top, 1.0):.0f} px"
    (zw, _), _ = cv2.getTextSize("0", cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    (tw, _), _ = cv2.getTextSize(top_text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    x0, x1 = max(w // 4, zw + 8), min(w - w // 4, w - tw - 8)
    if x1 - x0 < 8:                   # too narrow for the labels: the bar alone, over the whole width
        x0, x1 = 0, w
    ramp = np.linspace(0.0, max(top, 1.0), max(x1 - x0, 1), dtype=np.float32)[None, :]
    bar[2:sh - 2, x0:x1] = io.colorize_disparity(np.repeat(ramp, sh - 4, 0), max(top, 1.0))
    if x0 > 0:
        _text(bar, "0", x0 - zw - 4, baseline, scale, (255, 255, 255))
        _text(bar, top_text, x1 + 4, baseline, scale, (255, 255, 255))
    return np.concatenate([head, left, color.astype(np.uint8), bar], 0)


def predict_sequence(pairs, out: Path, resolve, opts: dict, fps: float = 10.0, overwrite: bool = False,
                     verify: bool = False, unmatched=None, announced=None, settings: PriorSettings | None = None):
    """The pairs, in their order, as one stream into ``out/<name>/`` (as a batch), with one line
    per fallback (:func:`event_line`), then the video; ``summary.json`` as a batch's with each
    frame's sequence record, the kept frames' included. Returns the summary."""
    if opts.get("disp_range") is not None:
        raise ConfigError("--sequence takes its limits from the previous frame; it runs without --disp-range")
    if not fps > 0:
        raise ConfigError(f"--fps must be positive, got {fps}")
    holder = SequenceHolder(pairs, settings)
    seq_opts = {**opts, "sequence": holder}

    def mapper(items):
        for pair in items:
            holder.current = pair[0]
            work = frame_work(pair, out, resolve, seq_opts)
            result = work[1]
            line = event_line(pair[0], result["timings"].get("sequence")) if result is not None else None
            if line:
                tqdm.write(line, file=sys.stderr)       # beside the batch's progress bar, not on it
            yield work

    with folder_lock(output_folder(out), "predict"):
        summary = predict_batch_locked(pairs, out, resolve, seq_opts, [current_device()], overwrite, verify, unmatched,
                                       announced, mapper=mapper, workers=1, where="a sequence: frames in order, "
                                       "each with the previous frame's disparity as its prior", keep_skipped=True)
    video = write_video(out, pairs, fps)
    if video is not None:
        print(f"stereojax predict: video -> {video}", file=sys.stderr)
    return summary


def write_video(out: Path, pairs, fps: float) -> Path | None:
    """``out/sequence.mp4`` (else an animated ``out/sequence.png``) of every computed frame
    (:func:`video_panel`: the frame's name and what its prior did, the left image, the colour
    disparity, a colour bar), one colour scale (the largest of the frames' 99.5th percentiles);
    and ``out/sequence.json``: the video's name, its colour scale and each frame's label. None
    when no frame is there."""
    frames = [(name, left) for name, left, _ in pairs if (out / name / "disparity.pfm").is_file()]
    if not frames:
        return None
    disps = [io.read_pfm(out / name / "disparity.pfm") for name, _ in frames]
    top = max(float(np.percentile(d[np.isfinite(d)], 99.5)) if np.isfinite(d).any() else 1.0 for d in disps)
    top = max(top, 1.0)
    marks = [frame_mark(_frame_record(out / name)) for name, _ in frames]
    panels = [video_panel(name, io.read_image(left_p), d, top, mark)
              for (name, left_p), d, mark in zip(frames, disps, marks)]
    h = max(p.shape[0] for p in panels)
    w = max(p.shape[1] for p in panels)
    panels = [np.pad(p, ((0, h - p.shape[0]), (0, w - p.shape[1]), (0, 0))) for p in panels]
    # written under a hidden name and renamed once complete: a killed run leaves no half video
    tmp = out / f".sequence.partial-{os.getpid()}.mp4"
    try:
        video = None
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
        if writer.isOpened():
            for p in panels:
                writer.write(cv2.cvtColor(p, cv2.COLOR_RGB2BGR))
            writer.release()
            if tmp.is_file() and tmp.stat().st_size > 0:
                os.replace(tmp, out / "sequence.mp4")
                video = out / "sequence.mp4"
        if video is None:
            from PIL import Image          # an animated PNG where OpenCV writes no MP4

            tmp = tmp.with_suffix(".png")
            images = [Image.fromarray(p) for p in panels]
            images[0].save(tmp, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
            os.replace(tmp, out / "sequence.png")
            video = out / "sequence.png"
    finally:
        for leftover in (tmp, tmp.with_suffix(".mp4")):
            leftover.unlink(missing_ok=True)
    io.write_json(out / "sequence.json", {
        "video": video.name, "fps": float(fps), "colormap": "turbo", "unit": "px", "min": 0.0, "max": round(top, 3),
        "no_estimate": [0, 0, 0],
        "layout": "per frame, top to bottom: its name and what its prior did; the left image; the colour disparity; "
                  "the colour bar from min to max (disparities above max have the top colour)",
        "marks": {"prior": "the previous frame's disparity narrowed this frame's search (green)",
                  "scene cut": "the left image changed too much: no prior (red)",
                  "first frame": "the stream starts here: no prior",
                  "restart": "the frame before was not computed in this run (resumed, missing): no prior",
                  "fallback: ...": "the prior was refused, and why (summary.json: per_frame[i].sequence.fallback) "
                                   "(orange)"},
        "frames": [{"frame": name, "mark": mark} for (name, _), mark in zip(frames, marks)]})
    return video
