"""stereojax.inference.prepare: disparity ranges a user gives (``disp_range=(MIN, MAX)``, negative values
included) are checked in one line and shift the right image."""

from __future__ import annotations

import numpy as np
import pytest

import stereojax
from stereojax import StereoInputError
from stereojax.inference.prepare import check_disp_range, shift_right_image

from ..helpers import offset_pair as _pair


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
