"""``--disp-range auto`` (stereojax.data.disp_range): a dense probe inside the window the rectification
check's feature matches allow."""

from __future__ import annotations

import numpy as np

from stereojax.data import load_middlebury
from stereojax.data.disp_range import ROUND_TO, auto_disp_range, feature_window
from stereojax.data.rectification import check_rectified

from ..helpers import offset_pair as _pair


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
