"""stereojax.metrics: KITTI background interpolation and error metrics, on hand-computed cases."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stereojax import metrics
from stereojax.errors import StereoInputError

N = np.nan


def test_interpolate_background_row_by_hand():
    disp = np.array([[N, 5, N, N, 2, N, N]], np.float32)
    valid = ~np.isnan(disp)
    # left end copies 5; the gap between 5 and 2 takes the smaller (background) 2; right end copies 2
    np.testing.assert_array_equal(metrics.interpolate_background(disp, valid), [[5, 5, 2, 2, 2, 2, 2]])
    disp = np.array([[3, 99, 7, 99, 99, 1, 99]], np.float32)  # values under the invalid mask are ignored
    valid = np.array([[1, 0, 1, 0, 0, 1, 0]], bool)
    np.testing.assert_array_equal(metrics.interpolate_background(disp, valid), [[3, 3, 7, 1, 1, 1, 1]])


def test_interpolate_background_empty_rows():
    disp = np.array([[N, N, N],
                     [4, N, 8],
                     [N, N, N],
                     [6, 1, N],
                     [N, N, N]], np.float32)
    out = metrics.interpolate_background(disp, ~np.isnan(disp))
    np.testing.assert_array_equal(out, [[4, 4, 8],   # top: copy of the first filled row
                                        [4, 4, 8],
                                        [4, 1, 1],   # between filled rows: smaller of above and below
                                        [6, 1, 1],
                                        [6, 1, 1]])  # bottom: copy of the last filled row
    assert out.dtype == np.float32


def test_interpolate_background_all_or_nothing():
    d = np.arange(6, dtype=np.float32).reshape(2, 3)
    np.testing.assert_array_equal(metrics.interpolate_background(d, np.ones((2, 3), bool)), d)
    np.testing.assert_array_equal(metrics.interpolate_background(d, np.zeros((2, 3), bool)), 0)
    with pytest.raises(StereoInputError, match="same shape"):
        metrics.interpolate_background(d, np.ones((3, 2), bool))


def _devkit_row(values, valid):
    """Literal transcription of the devkit's per-row loop (interpolateBackground)."""
    d, w = list(values), len(values)
    count = 0
    for u in range(w):
        if valid[u]:
            if count >= 1:
                u1, u2 = u - count, u - 1
                if u1 > 0 and u2 < w - 1:
                    for k in range(u1, u2 + 1):
                        d[k] = min(values[u1 - 1], values[u2 + 1])
            count = 0
        else:
            count += 1
    idx = [u for u in range(w) if valid[u]]
    for k in range(0, idx[0]):
        d[k] = values[idx[0]]
    for k in range(idx[-1] + 1, w):
        d[k] = values[idx[-1]]
    return d


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.integers(0, 50)), min_size=1, max_size=12))
def test_interpolate_background_matches_devkit_loop(cells):
    valid = np.array([c[0] for c in cells])
    if not valid.any():
        valid[0] = True
    values = np.array([c[1] for c in cells], np.float32)
    got = metrics.interpolate_background(values[None], valid[None])[0]
    np.testing.assert_array_equal(got, _devkit_row(values.tolist(), valid.tolist()))


GT = np.array([[10, 20, 100],
               [50, 0, 4]], np.float32)


GT_VALID = np.array([[1, 1, 1],
                     [1, 0, 1]], bool)


DISP = np.array([[10.5, 23, 104],
                 [60, 7, 2]], np.float32)


def test_evaluate_dense_by_hand():
    # errors on the 5 GT pixels: 0.5, 3, 4, 10, 2
    m = metrics.evaluate(DISP, GT, GT_VALID)
    assert m["n_gt"] == 5
    assert m["bad2"] == pytest.approx(60)  # 3, 4, 10 (2 is not > 2)
    assert m["bad3"] == pytest.approx(40)
    assert m["bad4"] == pytest.approx(20)
    assert m["bad5"] == pytest.approx(20)
    assert m["d1"] == pytest.approx(20)    # 4 px on 100 is < 5 %; 10 px on 50 is an outlier
    assert m["epe"] == pytest.approx(19.5 / 5)
    assert m["density"] == pytest.approx(100)


def test_evaluate_sparse_fill_error_by_hand():
    disp = DISP.copy()
    disp[1, 2] = np.nan  # no estimate
    est = np.ones((2, 3), bool)
    est[0, 1] = False  # no estimate either
    m = metrics.evaluate(disp, GT, GT_VALID, est_valid=est, fill="error")
    # errors: 0.5, missing, 4, 10, missing
    assert (m["bad2"], m["bad3"], m["bad4"], m["bad5"]) == pytest.approx((80, 80, 60, 60))
    assert m["d1"] == pytest.approx(60)
    assert m["epe"] == pytest.approx((0.5 + 4 + 10) / 3)  # over estimated GT pixels only
    assert m["density"] == pytest.approx(100 * 4 / 6)


def test_evaluate_sparse_fill_interpolate_by_hand():
    disp = DISP.copy()
    disp[1, 2] = -1  # negative = no estimate, as in the devkit
    est = np.ones((2, 3), bool)
    est[0, 1] = False
    m = metrics.evaluate(disp, GT, GT_VALID, est_valid=est)
    # (0,1) <- min(10.5, 104) = 10.5: error 9.5; (1,2) <- 7 (row end): error 3
    # errors: 0.5, 9.5, 4, 10, 3
    assert (m["bad2"], m["bad3"], m["bad4"], m["bad5"]) == pytest.approx((80, 60, 40, 40))
    assert m["d1"] == pytest.approx(40)
    assert m["epe"] == pytest.approx(27 / 5)
    assert m["density"] == pytest.approx(100 * 4 / 6)


def test_evaluate_custom_thresholds_and_default_gt_valid():
    m = metrics.evaluate(DISP, GT, None, thresholds=(0.5, 1))
    assert set(m) == {"bad0.5", "bad1", "d1", "epe", "density", "n_gt"}
    assert m["n_gt"] == 5 and m["bad0.5"] == pytest.approx(80)


def test_evaluate_errors():
    with pytest.raises(StereoInputError, match="no ground-truth pixels"):
        metrics.evaluate(DISP, GT, np.zeros((2, 3), bool))
    with pytest.raises(StereoInputError, match="ground truth is 2x3"):
        metrics.evaluate(DISP, GT.T, GT_VALID)
    with pytest.raises(StereoInputError, match="fill must be"):
        metrics.evaluate(DISP, GT, GT_VALID, fill="zero")
    with pytest.raises(StereoInputError, match="est_valid"):
        metrics.evaluate(DISP, GT, GT_VALID, est_valid=np.ones((3, 3), bool))


def test_evaluate_no_estimate_at_all():
    nothing = np.full((2, 3), np.nan, np.float32)
    m = metrics.evaluate(nothing, GT, GT_VALID, fill="error")
    assert m["bad3"] == 100 and math.isnan(m["epe"]) and m["density"] == 0
    m = metrics.evaluate(nothing, GT, GT_VALID)  # filled with 0: error = gt
    assert m["epe"] == pytest.approx((10 + 20 + 100 + 50 + 4) / 5)


def test_mean_metrics_is_a_plain_mean_over_frames():
    rows = [{"bad3": 10.0, "epe": 1.0, "n_gt": 100, "frame": "a"},
            {"bad3": 30.0, "epe": float("nan"), "n_gt": 900, "frame": "b"}]
    m = metrics.mean_metrics(rows)
    assert m["bad3"] == pytest.approx(20)  # not the pixel-weighted 28
    assert m["epe"] == pytest.approx(1.0)  # NaN ignored
    assert m["n_gt"] == 1000 and m["n_frames"] == 2 and "frame" not in m
    with pytest.raises(StereoInputError, match="at least one frame"):
        metrics.mean_metrics([])


def test_metrics_count_a_zero_estimate_as_missing():
    from stereojax.metrics import evaluate

    gt = np.full((20, 40), 10.0, np.float32)
    disp = gt.copy()
    disp[:, :10] = 0.0                                               # 0 = "no value", as in KITTI PNGs
    with_zero = evaluate(disp, gt, None, fill="error")
    assert with_zero["density"] == pytest.approx(75.0) and with_zero["bad3"] == pytest.approx(25.0)
    disp[:, :10] = np.inf
    assert evaluate(disp, gt, None, fill="error") == with_zero
    assert evaluate(np.where(np.isinf(disp), 0, disp), gt, None)["density"] == pytest.approx(75.0)
