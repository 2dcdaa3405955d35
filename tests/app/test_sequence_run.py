"""``predict --sequence`` as a user sees it (issue 55, "Streams"): one console line per fallback
and scene cut, a video that names each frame, shows its colour scale and marks what the prior
did, and a ``summary.json`` that lists every frame across resumes."""

from __future__ import annotations

import json
from contextlib import redirect_stderr, redirect_stdout
from io import StringIO
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereojax.data import io
from tests.helpers import shifted_pair


def _stream(root, n_moving=2, h=40, w=72, d=5):
    """``root/L``, ``root/R``: ``n_moving`` frames of one textured scene moving 1 px per frame
    (f0, f1, ...), then a frame of another scene (a scene cut)."""
    big, _ = shifted_pair(d, h=h, w=w + n_moving + 2, seed=4)
    frames = []
    for i in range(n_moving):
        left = big[:, i:i + w]
        right = np.concatenate([left[:, d:], np.repeat(left[:, -1:], d, 1)], 1)
        frames.append((left, right))
    frames.append(shifted_pair(9, h=h, w=w, seed=11))
    for i, (left, right) in enumerate(frames):
        io.write_png(root / "L" / f"f{i}.png", left)
        io.write_png(root / "R" / f"f{i}.png", right)
    return root / "L", root / "R", [f"f{i}" for i in range(len(frames))]


def _lines(stderr: str) -> list[str]:
    """stderr's lines as a terminal would end up showing them (a progress bar redraws after a \\r)."""
    return [seg.split("\r")[-1] for seg in stderr.split("\n")]


def _cli(argv) -> tuple[int, str]:
    """``stereojax`` in-process: (exit code, stderr)."""
    from stereojax.app.cli import main

    err = StringIO()
    with redirect_stderr(err), redirect_stdout(StringIO()):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code
    return code, err.getvalue()


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """A three-frame stream (f2 a scene cut) run, then run again: every frame kept. (out, names, the
    first run's stderr and summary, the second's)."""
    root = tmp_path_factory.mktemp("stream")
    lp, rp, names = _stream(root)
    out = root / "out"
    argv = ["predict", lp, rp, "--out", out, "--sequence", "--method", "census", "--max-disp", 32,
            "--check-rectified", "off"]
    code, first_err = _cli(argv)
    assert code == 0, first_err
    first = json.loads((out / "summary.json").read_text())
    code, again_err = _cli(argv)
    assert code == 0, again_err
    again = json.loads((out / "summary.json").read_text())
    return out, names, first_err, first, again_err, again


@pytest.mark.slow
def test_each_fallback_and_scene_cut_gets_one_console_line(resumed):
    _, names, stderr, first, again_err, _ = resumed
    recs = {r["frame"]: r["sequence"] for r in first["per_frame"]}
    assert list(recs) == names
    assert recs["f2"]["fallback"].startswith("scene cut"), recs["f2"]
    lines = _lines(stderr)
    for name, rec in recs.items():           # one line per fallback, on its own line; none for the first frame
        fallback = rec.get("fallback")
        mine = [ln for ln in lines if f": {name}: " in ln and "method:" not in ln]
        if fallback and fallback != "first frame":
            assert len(mine) == 1 and mine[0].startswith(f"stereojax predict: {name}: {fallback}"), (name, lines)
        else:
            assert mine == [], (name, lines)
    assert sum("scene cut" in ln for ln in lines) == 1
    assert not any("scene cut" in ln for ln in _lines(again_err))      # nothing computed: no event to print


@pytest.mark.slow
def test_summary_lists_every_frame_after_a_resume_that_keeps_them_all(resumed):
    _, names, _, first, _, again = resumed
    assert again["computed"] == 0 and again["skipped"] == 3
    assert [r["frame"] for r in again["per_frame"]] == names
    assert all(r["kept"] for r in again["per_frame"])
    assert ({r["frame"]: r["sequence"] for r in again["per_frame"]}
            == {r["frame"]: r["sequence"] for r in first["per_frame"]})
    assert all(r["width"] == 72 and r["height"] == 40 and r["seconds"] > 0 for r in again["per_frame"])


@pytest.mark.slow
def test_the_streams_video_legend_marks_the_first_frame_and_the_cut(resumed):
    out, names, _, first, _, _ = resumed
    legend = json.loads((out / "sequence.json").read_text())
    assert [f["frame"] for f in legend["frames"]] == names
    marks = [f["mark"] for f in legend["frames"]]
    assert marks[0] == "first frame" and marks[2] == "scene cut"
    used = first["per_frame"][1]["sequence"]["used_prior"]
    assert marks[1] == "prior" if used else marks[1].startswith("fallback: ")


def test_usage_states_the_stream_thresholds_the_code_uses():
    """docs/usage.md's paragraph on streams gives PriorSettings' numbers (it said 85 % for the wrong-prior
    probe while the code refuses a prior below 97 %)."""
    from stereojax.inference.sequence import PriorSettings

    text = (Path(__file__).resolve().parents[2] / "docs" / "usage.md").read_text()
    para = text[text.index("**Streams**"):]
    para = para[:para.index("\n\n")]
    s = PriorSettings()
    for number in (f"{100 * s.min_agree:g} %", f"{100 * s.max_pinned:g} %", f"{100 * s.min_share:g} %",
                   f"below {s.cut_ncc:g}", f"{s.band_width}-wide"):
        assert number in para, number
    assert "85 %" not in para


def _read_video(path):
    """The frames of sequence.mp4 (or the animated sequence.png), RGB."""
    if path.suffix == ".mp4":
        cap = cv2.VideoCapture(str(path))
        frames = []
        while True:
            ok, f = cap.read()
            if not ok:
                break
            frames.append(cv2.cvtColor(f, cv2.COLOR_BGR2RGB))
        return frames
    from PIL import Image, ImageSequence

    return [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(Image.open(path))]


def test_the_video_names_each_frame_shows_its_scale_and_marks_the_prior(tmp_path):
    """write_video on three finished frame folders (no chain runs): a header with the frame's name
    and what its prior did, the left image, the colour disparity, and a colour bar from 0 to the
    scale's top; sequence.json says the same in words."""
    from stereojax.app.sequence_run import write_video

    h, w = 48, 160
    out = tmp_path / "out"
    records = [{"frame": 0, "fallback": "first frame", "used_prior": False},
               {"frame": 1, "fallback": None, "used_prior": True, "prior_share": 0.9},
               {"frame": 2, "fallback": "scene cut: the left image correlates 0.10 with the previous one (< 0.5)",
                "used_prior": False}]
    pairs = []
    for i, rec in enumerate(records):
        name = f"frame{i:02d}"
        left = np.full((h, w), 60 + 40 * i, np.uint8)
        io.write_png(tmp_path / "L" / f"{name}.png", left)
        (out / name).mkdir(parents=True)
        io.write_pfm(out / name / "disparity.pfm", np.tile(np.linspace(0, 40, w, dtype=np.float32), (h, 1)))
        io.write_json(out / name / "timings.json", {"seconds": 1.0, "sequence": rec})
        pairs.append((name, tmp_path / "L" / f"{name}.png", tmp_path / "R" / f"{name}.png"))
    video = write_video(out, pairs, 5.0)
    assert video is not None and video.is_file()

    legend = json.loads((out / "sequence.json").read_text())
    assert legend["video"] == video.name and legend["colormap"] == "turbo" and legend["unit"] == "px"
    assert legend["min"] == 0 and legend["max"] == pytest.approx(40, abs=0.3)
    assert [(f["frame"], f["mark"]) for f in legend["frames"]] == [
        ("frame00", "first frame"), ("frame01", "prior"), ("frame02", "scene cut")]

    frames = _read_video(video)
    assert len(frames) == 3
    tall, wide = frames[0].shape[:2]
    assert wide == w and tall > 2 * h + 20             # a header and a colour bar beside the two pictures
    strip = (tall - 2 * h) // 2
    heads = [f[:strip].astype(int) for f in frames]
    assert all(hd.max() > 150 for hd in heads)         # text on the black header
    assert np.abs(heads[0] - heads[1]).mean() > 1 and np.abs(heads[1] - heads[2]).mean() > 1   # names, marks
    bar = frames[0][-strip:].astype(int)
    row = bar[strip // 2]
    lo, hi = row[w // 4 + 3], row[w - w // 4 - 4]      # the bar's two ends: turbo's blue, then its red
    assert lo[2] > lo[0] + 20 and hi[0] > hi[2] + 40, (lo, hi)
    # the left image sits under the header, the colour disparity under it
    np.testing.assert_allclose(frames[1][strip + h // 2, w // 2], [100, 100, 100], atol=12)
