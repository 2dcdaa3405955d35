"""Streams (stereojax.inference.sequence): the prior's limits, the fallbacks (scene cut, wrong
prior, too little prior, size change) and ``predict --sequence``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import stereojax
from stereojax.data import io
from stereojax.inference.sequence import (PriorSettings, Sequence, image_ncc, pinned_share, prior_bands,
                                          prior_limits)
from tests.helpers import banded_census, run_cli, shifted_pair


def test_prior_limits_hold_the_confident_neighbourhood():
    disp = np.full((20, 30), 10.0, np.float32)
    disp[:, 15:] = 20.0
    conf = np.ones_like(disp)
    conf[:5] = 0.0                                    # rows 0-4 unsure
    conf[12:15, 20:25] = 0.0                           # an object unsure in the previous frame
    s = PriorSettings(radius=2, own_radius=1, margin=1, relative=0.0, min_confidence=0.5)
    mn, mx, has = prior_limits(disp, conf, 64, s)
    assert has[4:12].all() and not has[:4].any()     # row 4 has a confident pixel within 1 px
    assert has[12:15, 20].all() and not has[13, 22]   # inside the object: no prior, the whole range
    assert mn[13, 22] == 0 and mx[13, 22] == 64
    assert (mn[10, :13] == 9).all() and (mx[10, :13] == 12).all()     # 10 +- 1, MAX exclusive
    assert mn[10, 15] == 9 and mx[10, 15] == 22       # near the step: both sides' disparities
    assert (mn[:3] == 0).all() and (mx[:3] == 64).all()               # no prior: the whole range


def test_pinned_share_counts_pixels_on_a_limit_the_prior_set():
    mn = np.full((2, 4), 5, np.int32)
    mx = np.full((2, 4), 10, np.int32)
    has = np.ones((2, 4), bool)
    disp = np.array([[5.0, 7.0, 9.0, 8.0], [6.0, 6.0, 6.0, 6.0]], np.float32)
    assert pinned_share(disp, mn, mx, has, 64) == pytest.approx(2 / 8)
    mn[:] = 0                                          # the range's own end is no pin
    assert pinned_share(disp, mn, mx, has, 64) == pytest.approx(1 / 8)


def _frames(n=3, d=5, h=40, w=72):
    """A short "stream": one textured scene moving 1 px per frame (disparity ``d``)."""
    big_l, _ = shifted_pair(d, h=h, w=w + n + 2, seed=4)
    out = []
    for i in range(n):
        left = big_l[:, i:i + w]
        right = np.zeros_like(left)
        right[:, :w - d] = left[:, d:]
        right[:, w - d:] = left[:, -1:]
        out.append((left, right))
    return out


@pytest.fixture(scope="module")
def seq():
    return Sequence(banded_census(32, 16), settings=PriorSettings(band_width=8, min_share=0.3))


@pytest.mark.slow
@pytest.mark.parametrize("skip_coarse", [False, True])
def test_a_stream_uses_its_prior_and_agrees_with_per_frame(seq, skip_coarse):
    """With the coarse pass (the default) and with bands placed by the prior (the fast setting)."""
    if skip_coarse:
        seq = Sequence(banded_census(32, 16), settings=PriorSettings(band_width=8, min_share=0.3,
                                                                     skip_coarse_share=0.5))
    seq.reset()
    frames = _frames()
    first = seq.push(*frames[0])
    assert first.record["fallback"] == "first frame" and not first.record["used_prior"]
    for left, right in frames[1:]:
        f = seq.push(left, right)
        assert f.record["used_prior"], f.record
        assert f.record["coarse_pass"] is not skip_coarse
        assert f.record["prior_share"] > 0.5
        plain = stereojax.Predictor(banded_census(32, 16))(left, right)
        inner = (slice(4, -4), slice(12, -4))
        assert np.mean(np.abs(f.disparity - plain)[inner] > 3) < 0.01


def test_a_scene_cut_falls_back_to_the_whole_range(seq):
    seq.reset()
    seq.push(*_frames()[0])
    other = shifted_pair(9, h=40, w=72, seed=11)
    f = seq.push(*other)
    assert f.record["fallback"].startswith("scene cut") and not f.record["used_prior"]
    plain = stereojax.Predictor(banded_census(32, 16), confidence=True)(*other)
    np.testing.assert_allclose(f.disparity, plain[0])
    assert image_ncc(other[0], _frames()[0][0]) < 0.5


def test_a_wrong_prior_costs_time_not_accuracy(seq):
    """A prior from another scene, given for the same images (no scene cut to see), disagrees
    with the frame's quick probe; the frame runs without it."""
    left, right = shifted_pair(12, h=40, w=72, seed=3)
    wrong = (np.full(left.shape, 3.0, np.float32), np.ones(left.shape, np.float32))
    f = seq.predict(left, right, wrong, {})
    assert f.record["fallback"].startswith("prior disagrees with this frame"), f.record
    assert f.record["agreement"] < 0.5
    plain = stereojax.Predictor(banded_census(32, 16), confidence=True)(left, right)
    np.testing.assert_allclose(f.disparity, plain[0])


def test_too_little_prior_and_a_size_change_restart(seq):
    seq.reset()
    left, right = _frames()[0]
    f = seq.predict(left, right, (np.zeros(left.shape, np.float32), np.zeros(left.shape, np.float32)), {})
    assert f.record["fallback"].startswith("too little prior")
    seq.push(left, right)
    small = shifted_pair(5, h=32, w=64, seed=1)
    g = seq.push(*small)
    assert "size changed from 72x40 to 64x32" in g.record["fallback"]
    assert g.disparity.shape == (32, 64)


@pytest.mark.slow
def test_predict_sequence_writes_frames_records_and_a_video(tmp_path, capsys):
    frames = _frames(n=3)
    for i, (left, right) in enumerate(frames):
        io.write_png(tmp_path / "L" / f"f{i}.png", left)
        if i != 1:                                     # frame f1 has no right image
            io.write_png(tmp_path / "R" / f"f{i}.png", right)
    out = tmp_path / "out"
    code, stdout, stderr = run_cli(["predict", tmp_path / "L", tmp_path / "R", "--out", out, "--sequence",
                                    "--method", "census", "--max-disp", 32, "--check-rectified", "off"], capsys)
    assert code == 0, stderr
    assert "f1" in stderr                              # the missing right frame is reported
    summary = json.loads((out / "summary.json").read_text())
    recs = {r["frame"]: r["sequence"] for r in summary["per_frame"]}
    assert set(recs) == {"f0", "f2"}
    assert recs["f0"]["fallback"] == "first frame"
    assert "fallback" in recs["f2"] and "ncc" in recs["f2"]
    video = [p for p in (out / "sequence.mp4", out / "sequence.png") if p.is_file()]
    assert video and video[0].stat().st_size > 0
    assert not list(out.glob(".sequence.partial*"))
    timings = json.loads((out / "f2" / "timings.json").read_text())
    assert timings["sequence"] == recs["f2"]


def test_sequence_refuses_one_pair_and_a_disp_range(tmp_path, capsys):
    left, right = _frames(n=1)[0]
    io.write_png(tmp_path / "l.png", left)
    io.write_png(tmp_path / "r.png", right)
    code, _, stderr = run_cli(["predict", tmp_path / "l.png", tmp_path / "r.png", "--out", tmp_path / "o",
                               "--sequence", "--method", "census"], capsys)
    assert code != 0 and "several pairs" in stderr
    for i in range(2):
        io.write_png(tmp_path / "L" / f"f{i}.png", left)
        io.write_png(tmp_path / "R" / f"f{i}.png", right)
    code, _, stderr = run_cli(["predict", tmp_path / "L", tmp_path / "R", "--out", tmp_path / "o2", "--sequence",
                               "--method", "census", "--disp-range", "0", "32"], capsys)
    assert code != 0 and "--disp-range" in stderr


@pytest.mark.slow
def test_given_bands_equal_to_the_coarse_pass_change_nothing():
    """A chain given the coarse pass's own band offsets computes what it computes with the
    coarse pass (the bands are the only thing the coarse pass gives the chain)."""
    import jax.numpy as jnp

    from stereojax import chain
    from stereojax.inference.programs import CompiledChain

    cfg = banded_census(32, 16)
    left, right = (a.astype(np.float32) for a in shifted_pair(6, h=40, w=72, seed=5))
    off = chain.bands(jnp.asarray(left), jnp.asarray(right), cfg, jnp.array([40, 72]))
    plain = CompiledChain((40, 72), cfg)(left, right)
    given = CompiledChain((40, 72), cfg, given_bands=True)(left, right, bands=tuple(np.asarray(o) for o in off))
    np.testing.assert_allclose(given, plain)
    shifted = tuple(np.clip(np.asarray(o) + 8, 0, 16) for o in off)      # other bands: another answer
    assert np.abs(CompiledChain((40, 72), cfg, given_bands=True)(left, right, bands=shifted) - plain).max() > 1


def test_prior_bands_centre_on_the_limits_and_fill_unsure_pixels_from_their_row():
    mn = np.full((3, 10), 20, np.int32)
    mx = np.full((3, 10), 31, np.int32)
    has = np.ones((3, 10), bool)
    has[1, :4] = False
    mn[1, :4], mx[1, :4] = 0, 64
    mn[1, 4:], mx[1, 4:] = 40, 51
    has[2] = False
    left, right = prior_bands(mn, mx, has, 8, 64)
    assert (left[0] == 21).all()                     # centre 25, 8 wide
    assert (left[1] == 41).all()                     # row 1: its prior pixels' centre, unsure ones too
    assert (left[2] == np.median([25] * 10 + [45] * 6) - 4).all()      # a row without any: the median
    assert right.shape == left.shape and right.min() >= 0 and right.max() <= 56
