"""Disparity ranges a user gives: ``disp_range=(MIN, MAX)`` / ``--disp-range MIN MAX`` (negative
values included) and ``--disp-range auto`` (a dense probe inside the window the rectification check's feature
matches allow, :mod:`stereojax.data.disp_range`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import stereojax
from stereojax import StereoInputError
from stereojax.data import io, load_middlebury
from stereojax.data.disp_range import ROUND_TO, auto_disp_range, feature_window
from stereojax.data.rectification import check_rectified
from stereojax.inference.prepare import check_disp_range, shift_right_image

from .helpers import textured
from .robustness_helpers import _cli, _one_line


def _pair(d, h=48, w=96, seed=3):
    """left(x) == right(x - d) for any integer d (negative: the match lies to the right)."""
    big = textured(h, w + 2 * abs(d) + 2, seed)
    c = abs(d) + 1
    left = big[:, c: c + w]
    right = big[:, c + d: c + d + w]
    return left, right


def test_shift_right_image_moves_the_disparities():
    left, right = _pair(-5)
    moved = shift_right_image(right.astype(np.float32), -9)       # d - (-9) = 4
    np.testing.assert_array_equal(moved[:, :80], right[:, 9:89])


@pytest.mark.parametrize("d,rng", [(-6, (-16, 8)), (7, (4, 20)), (3, (0, 16))])
def test_a_given_range_finds_negative_and_offset_disparities(d, rng):
    left, right = _pair(d)
    cfg = stereojax.preset("census", 16)
    disp = stereojax.disparity(left, right, cfg, disp_range=rng)
    inner = disp[6:-6, 24:-24]
    assert np.median(inner) == pytest.approx(d, abs=0.25)
    assert (np.abs(inner - d) < 1).mean() > 0.9
    assert disp.min() >= rng[0] and disp.max() <= rng[1] - 1


@pytest.mark.parametrize("bad,msg", [((5, 5), "MIN must be below MAX"), ((9, 2), "MIN must be below MAX"),
                                     ((0.5, 8), "two integers"), ((1,), "two integers"),
                                     ((True, 8), "two integers"), ((-60, 60), "as many as the image is wide")])
def test_bad_ranges_are_refused_with_one_line(bad, msg):
    left, right = _pair(2)
    with pytest.raises(StereoInputError, match=msg) as exc:
        stereojax.disparity(left, right, stereojax.preset("census", 16), disp_range=bad)
    assert "\n" not in str(exc.value)


def test_check_disp_range_accepts_numpy_integers():
    assert check_disp_range((np.int64(-3), np.int32(9)), 100) == (-3, 9)


def _write(tmp_path, d):
    left, right = _pair(d, h=64, w=160, seed=5)
    io.write_png(tmp_path / "l.png", left)
    io.write_png(tmp_path / "r.png", right)
    return tmp_path / "l.png", tmp_path / "r.png"


def test_cli_range_and_its_errors(tmp_path, capsys):
    lp, rp = _write(tmp_path, -4)
    out = tmp_path / "out"
    code, stdout, err = _cli(["predict", lp, rp, "--out", out, "--method", "census", "--disp-range", "-12", "8",
                              "--check-rectified", "off"], capsys)
    assert code == 0, err
    assert "disparities -12 <= d < 8" in stdout
    disp = io.read_pfm(out / "disparity.pfm")
    assert np.median(disp[8:-8, 30:-30]) == pytest.approx(-4, abs=0.3)
    assert json.loads((out / "timings.json").read_text())["disp_range"] == [-12, 8]
    for bad in (["8", "8"], ["a", "9"], ["3"], ["-200", "200"]):
        out2 = tmp_path / ("bad" + "_".join(bad))
        code, _, err = _cli(["predict", lp, rp, "--out", out2, "--method", "census", "--disp-range", *bad], capsys)
        line = _one_line(err)
        assert code != 0 and line.startswith("stereojax predict: error:") and "disp" in line.lower()
        assert not out2.exists() or list(out2.iterdir()) == []


@pytest.mark.slow
def test_cli_auto_range_on_a_real_kitti_pair(data_root, tmp_path, capsys):
    """auto: the range comes from the dense probe, is printed, recorded in frame.json, and
    covers the ground truth of the frame."""
    from stereojax.data import load_kitti2015

    root = data_root / "kitti2015" / "training"
    lp, rp = root / "image_2" / "000005_10.png", root / "image_3" / "000005_10.png"
    pairs = tmp_path / "pairs.txt"
    pairs.write_text(f"{lp} {rp}\n")
    out = tmp_path / "out"
    code, _, err = _cli(["predict", "--pairs", pairs, "--out", out, "--method", "census",
                         "--disp-range", "auto"], capsys)
    assert code == 0, err
    record = json.loads(next(out.glob("*/frame.json")).read_text())
    lo, hi = record["disp_range_used"]
    assert record["disp_range"] == "auto"
    s = load_kitti2015(root, "000005")
    gt = s.gt[s.gt_valid]
    assert lo <= np.percentile(gt, 1) and np.percentile(gt, 99) < hi
    assert hi - lo < 228


# --- --disp-range auto: the dense probe over the feature window (stereojax.data.disp_range) ---

def test_auto_range_holds_a_known_disparity_and_little_more():
    """A textured pair at d = 20 px: the range holds 20 and spans one rounding step, not the window."""

    left, right = _pair(20, h=160, w=320, seed=5)
    check = check_rectified(left, right)
    found = auto_disp_range(left, right, check)
    assert found.source == "probe" and found.lo <= 20 < found.hi
    assert (found.lo, found.hi) == (16, 16 + ROUND_TO)         # 20 - 4 px .. 20 + 10 % + 8 px, rounded up
    window = feature_window(check, 320)
    assert window[1] - window[0] > 3 * (found.hi - found.lo)
    assert "dense probe" in found.describe() and f"{found.lo} <= d < {found.hi}" in found.describe()


def test_auto_range_reaches_below_zero_when_the_matches_do():

    left, right = _pair(-12, h=160, w=320, seed=6)
    found = auto_disp_range(left, right, check_rectified(left, right, min_disp=-40))
    assert found.lo <= -12 < found.hi and found.hi <= 16


def test_auto_range_of_a_flat_pair_is_none():

    flat = np.full((120, 200), 90, np.uint8)
    assert auto_disp_range(flat, flat, check_rectified(flat, flat)) is None


def test_auto_range_on_middlebury_covers_the_ground_truth_and_is_narrow(data_root):
    """Reindeer (issue 40: auto searched about twice what the scene spans): the range holds 99 % of
    the ground truth, and is at most the true span rounded up to 16 plus two rounding steps (the
    feature window alone was 26..197 for a scene of 33..100 px at its 1st..99th percentiles)."""

    s = load_middlebury(data_root / "middlebury" / "Reindeer_2006H")
    gt = s.gt[s.gt_valid]
    found = auto_disp_range(s.left, s.right, check_rectified(s.left, s.right))
    assert np.mean((gt >= found.lo) & (gt < found.hi)) >= 0.99
    p1, p99 = np.percentile(gt, [1, 99])
    assert found.hi - found.lo <= 16 * np.ceil((p99 - p1) / 16) + 32
