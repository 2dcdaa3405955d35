"""A check, before matching, that a pair is rectified and in the right order.

Sparse ORB features are matched between the two images (Hamming distance, mutual best
matches) and filtered with RANSAC on the fundamental matrix. In a rectified pair a point and
its match lie on the same row, and the match in the right image lies at the same column or to
the left (x_right = x_left - d, d >= 0). The check reports the vertical offset of the matches
(median and the 90th percentile of its absolute value) and the share of matches that lie to
the right, which, when most do, means left and right are swapped. When the disparity range
allows negative disparities (``min_disp < 0``), a match that far to the right is expected: only
matches to the right of what the range allows count then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: a rectified pair: the matches' rows differ by at most this (median), and 90 % of them by at
#: most MAX_ROW_SPREAD_PX (ORB's keypoints are not sub-pixel exact: on the 60 rectified KITTI
#: unlabeled pairs of the shared data the 90th percentile reaches 0.83 px, none is flagged)
MAX_ROW_OFFSET_PX = 1.0
MAX_ROW_SPREAD_PX = 1.5
#: more than this share of the matches further right than the range allows (x_right > x_left + 0.5
#: when the lowest disparity is 0) means swapped
SWAPPED_SHARE = 0.5
MIN_MATCHES = 20
#: Lowe's ratio test of the matches (see _distinct_matches)
RATIO = 0.8
#: ORB pyramid levels (scale 1.2 each) whose keypoints measure the rows, when enough matches have them
FINE_OCTAVE = 1
#: ORB needs its 31-pixel patch plus a border inside the image: smaller images are not checked
MIN_SIDE_PX = 64


@dataclass(frozen=True)
class RectificationCheck:
    """What :func:`check_rectified` found. ``problem`` is None when the pair looks rectified (or
    when there were too few matches to tell), else one line with the measurement and what to do."""

    matches: int
    row_offset_median: float
    row_offset_p90: float
    share_right: float
    problem: str | None
    #: 1st and 99th percentiles of the matches' disparities x_left - x_right (nan: too few matches)
    disparity_p1: float = float("nan")
    disparity_p99: float = float("nan")
    #: why the check could not run (an image too small or too flat for feature matching), else None
    skipped: str | None = None


def _grey8(img) -> np.ndarray:

    a = np.asarray(img)
    if a.ndim == 3:
        a = cv2.cvtColor(a[..., :3].astype(np.float32), cv2.COLOR_RGB2GRAY)
    if a.dtype != np.uint8:
        a = np.clip(a.astype(np.float32) * (255.0 / max(float(a.max()), 1.0)), 0, 255)
    return a.astype(np.uint8)


def check_rectified(left, right, features: int = 3000, min_disp: int = 0) -> RectificationCheck:
    """Check a pair (any image arrays ``[H, W]`` or ``[H, W, 3]``) with ORB matches and RANSAC;
    well under a second on a KITTI-sized pair. An image too small or too flat for feature
    matching is not checked (``skipped`` says why); the check never raises on an image.
    ``min_disp``: the lowest disparity the run allows (``--disp-range MIN MAX``); below 0, matches
    down to that disparity are not taken for a swapped pair."""

    gl, gr = _grey8(left), _grey8(right)
    small = min(*gl.shape[:2], *gr.shape[:2])
    if small < MIN_SIDE_PX:
        return _skipped(f"the images are too small for feature matching ({gl.shape[1]}x{gl.shape[0]}, "
                        f"under {MIN_SIDE_PX} px on a side)")
    if int(gl.max()) == int(gl.min()) or int(gr.max()) == int(gr.min()):
        return _skipped("an image is flat (one grey level): no features to match")
    try:
        return _check(gl, gr, features, min(int(min_disp), 0))
    except cv2.error as exc:       # the check must never end a run
        first = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        return _skipped(f"OpenCV could not match features ({first.strip()})")


def _skipped(why: str) -> RectificationCheck:
    nan = float("nan")
    return RectificationCheck(0, nan, nan, nan, None, skipped=f"rectification check skipped: {why}")


def _distinct_matches(dl, dr) -> list:
    """Mutual best matches that also pass the ratio test (best < RATIO x second best): a repeated
    pattern (a chessboard, a fence) matches many places equally well and would be kept by the
    mutual check alone (on the shared chessboard rig, rectified, that flagged 3 of 13 pairs)."""
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    back = {m[0].queryIdx: m[0].trainIdx for m in bf.knnMatch(dr, dl, k=1) if m}
    return [m[0] for m in bf.knnMatch(dl, dr, k=2)
            if len(m) == 2 and m[0].distance < RATIO * m[1].distance and back.get(m[0].trainIdx) == m[0].queryIdx]


def _check(gl, gr, features: int, lowest: int) -> RectificationCheck:

    orb = cv2.ORB_create(nfeatures=features)

    def describe(img):
        # ORB can return far more than nfeatures points on regular patterns (ties): keep the best
        kps = sorted(orb.detect(img, None), key=lambda k: -k.response)[:features]
        return orb.compute(img, kps)
    kl, dl = describe(gl)
    kr, dr = describe(gr)
    if dl is None or dr is None or len(kl) < MIN_MATCHES or len(kr) < MIN_MATCHES:
        return RectificationCheck(0, float("nan"), float("nan"), float("nan"), None)
    pairs = _distinct_matches(dl, dr)
    if len(pairs) < MIN_MATCHES:
        return RectificationCheck(len(pairs), float("nan"), float("nan"), float("nan"), None)
    # rows are measured where both keypoints come from the finest pyramid levels: a keypoint of
    # level k is placed to about 1.2^k px, so coarse levels alone spread a rectified pair's rows
    # by 2-3 px (the chessboard rig of the shared data, rectified: 90th percentile 2.2 px -> 0.9)
    fine = [m for m in pairs if kl[m.queryIdx].octave <= FINE_OCTAVE and kr[m.trainIdx].octave <= FINE_OCTAVE]
    if len(fine) >= MIN_MATCHES:
        pairs = fine
    pl = np.float32([kl[m.queryIdx].pt for m in pairs])
    pr = np.float32([kr[m.trainIdx].pt for m in pairs])
    _, inliers = cv2.findFundamentalMat(pl, pr, cv2.FM_RANSAC, 1.0, 0.999)
    if inliers is not None and inliers.sum() >= MIN_MATCHES:
        keep = inliers.ravel().astype(bool)
        pl, pr = pl[keep], pr[keep]
    dy = pr[:, 1] - pl[:, 1]
    dx = pr[:, 0] - pl[:, 0]
    median, p90 = float(np.median(dy)), float(np.percentile(np.abs(dy), 90))
    share_right = float(np.mean(dx > 0.5 - lowest))        # disparity x_left - x_right below the range
    d1, d99 = (float(v) for v in np.percentile(-dx, [1, 99]))
    problem = None
    if share_right > SWAPPED_SHARE:
        where = "to the right" if lowest == 0 else f"more than {-lowest} px to the right (below the range's {lowest})"
        problem = (f"left and right look swapped: {100 * share_right:.0f} % of {len(dx)} feature matches lie {where} "
                   "in the right image (a rectified left view sees them further right); swap the two inputs"
                   + ("" if lowest == 0 else f", or lower the range's minimum to about {math.floor(d1)}"))
    elif abs(median) > MAX_ROW_OFFSET_PX or p90 > MAX_ROW_SPREAD_PX:
        problem = (f"the pair does not look rectified: matched features lie up to {p90:.1f} px apart vertically "
                   f"(90th percentile of {len(dy)} matches; median {median:+.1f} px); rectify it first, e.g. with "
                   "OpenCV's stereoRectify and remap")
    return RectificationCheck(len(dy), median, p90, share_right, problem, d1, d99)

