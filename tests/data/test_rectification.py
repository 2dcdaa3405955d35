"""stereojax.data.rectification: the check never ends a run on a tiny or flat pair, passes a rectified pair,
catches one that is shifted, rotated or swapped, and takes negative disparities for what they are."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from stereojax.data import io
from stereojax.data.datasets import load_dataset
from stereojax.data.rectification import check_rectified

from ..helpers import shifted_pair
from ..robustness_helpers import _cli

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
MOTORCYCLE = DATA / "middlebury" / "Motorcycle_MiddEval3Q"
needs_data = pytest.mark.skipif(not MOTORCYCLE.is_dir(), reason=f"real data not found at {DATA}")
FAST = ["--max-disp", "16", "--method", "census"]


@pytest.mark.parametrize("shape", [(1, 150), (10, 10), (40, 150), (63, 300)])
def test_rectification_check_skips_tiny_images(shape):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, shape).astype(np.uint8)
    check = check_rectified(img, img)
    assert check.problem is None and "too small" in check.skipped


def test_rectification_check_skips_flat_images():
    flat = np.full((120, 200), 7, np.uint8)
    assert "flat" in check_rectified(flat, flat).skipped
    left, right = shifted_pair(4, h=120, w=200)
    assert check_rectified(left, right).skipped is None


def _real_pair():
    s = load_dataset(DATA, "kitti2015", ["000021"], gt="noc")[0][1]()
    return s.left, s.right


@needs_data
def test_rectified_pair_passes_and_shifted_rotated_swapped_are_caught():
    left, right = _real_pair()
    assert check_rectified(left, right).problem is None
    shifted = np.roll(right, 3, axis=0)
    assert "not look rectified" in check_rectified(left, shifted).problem
    h, w = right.shape[:2]
    rot = cv2.warpAffine(right, cv2.getRotationMatrix2D((w / 2, h / 2), 1.0, 1.0), (w, h),
                         borderMode=cv2.BORDER_REPLICATE)
    assert "not look rectified" in check_rectified(left, rot).problem
    assert "swapped" in check_rectified(right, left).problem


def _negative_pair(shift: int = 60):
    """KITTI 000021 cut so that its disparities fall by ``shift``: most of them become negative."""
    left, right = _real_pair()
    return left[:, shift:], right[:, :-shift]


@needs_data
def test_a_range_with_negative_disparities_is_not_taken_for_a_swapped_pair():
    left, right = _negative_pair()
    assert "swapped" in check_rectified(left, right).problem                   # a range from 0: swapped
    assert check_rectified(left, right, min_disp=-96).problem is None          # allowed by the range
    far = check_rectified(left, right, min_disp=-8).problem                    # the range allows too little
    assert "more than 8 px to the right" in far and "lower the range's minimum" in far


@pytest.mark.slow
@needs_data
def test_predict_warns_or_refuses_an_unrectified_pair(tmp_path, capsys):
    left, right = _real_pair()
    io.write_png(tmp_path / "l.png", left)
    io.write_png(tmp_path / "r.png", right)
    # swapped: a warning, the run goes on
    code, _, err = _cli(["predict", tmp_path / "r.png", tmp_path / "l.png", "--out", tmp_path / "w", *FAST,
                         "--max-disp", "64"], capsys)
    assert code == 0 and "warning: left and right look swapped" in err
    code, _, err = _cli(["predict", tmp_path / "r.png", tmp_path / "l.png", "--out", tmp_path / "e", *FAST,
                         "--max-disp", "64", "--check-rectified", "error"], capsys)
    assert code == 2 and "swapped" in err and not (tmp_path / "e" / "disparity.png").exists()
    # mostly negative disparities, and a range that allows them: no advice to swap
    left, right = _negative_pair()
    io.write_png(tmp_path / "nl.png", left)
    io.write_png(tmp_path / "nr.png", right)
    code, _, err = _cli(["predict", tmp_path / "nl.png", tmp_path / "nr.png", "--out", tmp_path / "n", *FAST,
                         "--disp-range", "-96", "32"], capsys)
    assert code == 0 and "swapped" not in err, err


def test_rectified_chessboard_views_pass_the_check(data_root):
    """A repeated pattern (the shared rig's chessboard) matches many places equally well: without
    the ratio test and the fine pyramid levels, 3 of its 13 pairs, rectified, were flagged."""
    import cv2

    from stereojax.data.stereo_rig import Rectifier, calibrate

    folder = data_root / "calibration" / "opencv_stereo_chessboard"
    rig, report = calibrate(str(folder / "left*.jpg"), str(folder / "right*.jpg"), (9, 6), 0.025)
    rect = Rectifier(rig)
    raw_flagged = rect_flagged = 0
    for a, b in report.used:
        gl, gr = cv2.imread(str(folder / a), 0), cv2.imread(str(folder / b), 0)
        raw_flagged += check_rectified(gl, gr).problem is not None
        rect_flagged += check_rectified(*rect.rectify(gl, gr)).problem is not None
    assert raw_flagged == 13
    assert rect_flagged <= 1
