"""``--disp-range auto``: the disparity range a pair spans, measured before the chain runs.

Two steps, both cheap (about 0.3 s on a KITTI pair, nearly all of it the feature matching):

1. **A window** from the feature matches of the rectification check
   (:func:`stereojax.data.rectification.check_rectified`): their 1st percentile less a quarter of
   their span, up to twice their 99th percentile (at least 48 px beyond it) or a third of the
   width, whichever is larger. Sparse features miss texture-poor near surfaces (KITTI's road in
   front of the car: on KITTI 2015 000001-000020 the matches' 99th percentile was 23-88 px
   against a ground-truth 99th percentile of 63-110 px), so the window is generous on purpose.
2. **A dense probe**: OpenCV's StereoSGBM on the pair at half size (a quarter from 1600 px wide)
   over that window, with its uniqueness and left-right checks, counting only pixels with some
   texture. The range is its 0.5th to 99.5th percentile, the near end widened by 10 % and
   PROBE_MARGIN_PX (small near objects are what a coarse probe misses), the far end by
   PROBE_FAR_MARGIN_PX only (the background is large and well seen, and every disparity searched
   below it is one more way to be wrong: census on Aloe lost 0.67 points > 3 px to a far end 12 px
   below the scene's, the first rule), its span rounded up to a multiple of 16 (sizes that share
   compiled chains).

The window alone was the old rule: it searched about twice what the scene needs, which costs
both time and accuracy (a wide range gives the coarse pass more ways to be wrong). The probe is
the fallback's replacement wherever it sees enough of the image; where it does not (a flat or
tiny image), the window is the range. The constants were chosen among four candidate settings
by ground-truth coverage alone (no error measured) on KITTI 2015, KITTI 2012 000000 and the
Middlebury scenes of ../shared/data, so the Middlebury scores of docs/results.md and
experiments/results/auto_range.md are not held out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from stereojax.data.images import to_u8
from stereojax.data.rectification import RectificationCheck

#: the window below the matches' 1st percentile: a quarter of their span, at least WINDOW_MARGIN_PX
WINDOW_MARGIN_SHARE = 0.25
WINDOW_MARGIN_PX = 16
#: the window above their 99th percentile: WINDOW_FACTOR times it, at least WINDOW_HEADROOM_PX beyond
WINDOW_FACTOR = 2.0
WINDOW_HEADROOM_PX = 48
#: ... and at least this share of the image width (a near object the features missed)
WINDOW_WIDTH_SHARE = 1 / 3

#: the probe's percentiles of its matched pixels, and how far beyond them the range reaches
PROBE_LOW_Q, PROBE_HIGH_Q = 0.5, 99.5
PROBE_WIDEN = 0.10
PROBE_MARGIN_PX = 8
PROBE_FAR_MARGIN_PX = 4
#: below this share of the probe's pixels matched, the probe is not trusted (the window is the range)
PROBE_MIN_SHARE = 0.2
#: images narrower than this are probed at full size; from PROBE_QUARTER_FROM_PX wide at a quarter
PROBE_HALF_FROM_PX = 128
PROBE_QUARTER_FROM_PX = 1600
ROUND_TO = 16


@dataclass(frozen=True)
class AutoRange:
    """What ``--disp-range auto`` found: ``lo <= d < hi``, and how."""

    lo: int
    hi: int
    #: "probe" (the dense probe's percentiles) or "window" (the feature window alone)
    source: str
    window: tuple[int, int]
    #: the probe's low and high percentile disparities (nan when it was not used), its share of
    #: matched pixels and its scale (2: half size)
    p_lo: float = float("nan")
    p_hi: float = float("nan")
    share: float = 0.0
    scale: int = 1

    @property
    def range(self) -> tuple[int, int]:
        return self.lo, self.hi

    def describe(self) -> str:
        if self.source == "probe":
            return (f"{self.lo} <= d < {self.hi} (a dense probe at 1/{self.scale} size over {self.window[0]}..."
                    f"{self.window[1]}: {PROBE_LOW_Q:g}-{PROBE_HIGH_Q:g} % of its {100 * self.share:.0f} % matched "
                    f"pixels between {self.p_lo:.1f} and {self.p_hi:.1f} px, widened)")
        return (f"{self.lo} <= d < {self.hi} (the feature matches' window; the dense probe matched only "
                f"{100 * self.share:.0f} % of the pixels)")


def feature_window(check: RectificationCheck | None, width: int) -> tuple[int, int]:
    """The window the probe searches (MIN <= d < MAX): from the feature matches (module
    docstring, step 1), or ``0 .. width / 3`` when there were too few of them to tell."""
    far = max(2, int(width * WINDOW_WIDTH_SHARE))
    if check is None or not (math.isfinite(check.disparity_p1) and math.isfinite(check.disparity_p99)):
        lo, hi = 0, far
    else:
        p1, p99 = check.disparity_p1, check.disparity_p99
        lo = math.floor(p1 - max(WINDOW_MARGIN_PX, WINDOW_MARGIN_SHARE * (p99 - p1)))
        hi = max(math.ceil(max(WINDOW_FACTOR * p99, p99 + WINDOW_HEADROOM_PX)) + 1, far)
        if p1 >= 0:      # a parallel rig: nothing lies behind infinity
            lo = max(lo, 0)
    return _clip(lo, hi, width)


def _clip(lo: int, hi: int, width: int) -> tuple[int, int]:
    return max(lo, -(width - 2)), max(min(hi, width - 1), max(lo, -(width - 2)) + 2)


def probe_scale(width: int) -> int:
    """1, 2 or 4: the factor the probe shrinks a pair of this width by."""
    return 1 if width < PROBE_HALF_FROM_PX else 2 if width < PROBE_QUARTER_FROM_PX else 4


def probe(left, right, window: tuple[int, int]) -> tuple[np.ndarray, float, int]:
    """OpenCV StereoSGBM on the pair shrunk by :func:`probe_scale`, over ``window``:
    (the matched pixels' disparities in full-size pixels, the share of pixels matched, the scale).
    Both images are left-padded so that the left border also gets matches."""
    l8, r8 = to_u8(left), to_u8(right)
    h, w = l8.shape[:2]
    s = probe_scale(w)
    if s > 1:
        size = (max(w // s, 1), max(h // s, 1))
        l8 = cv2.resize(l8, size, interpolation=cv2.INTER_AREA)
        r8 = cv2.resize(r8, size, interpolation=cv2.INTER_AREA)
    low = math.floor(window[0] / s)
    count = int(math.ceil((math.ceil(window[1] / s) - low) / 16) * 16)
    block = 5
    matcher = cv2.StereoSGBM_create(minDisparity=low, numDisparities=count, blockSize=block,
                                    P1=8 * block * block, P2=32 * block * block, disp12MaxDiff=1,
                                    uniquenessRatio=15, speckleWindowSize=50, speckleRange=1,
                                    mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    pad = count + max(low, 0)
    wide = [(0, 0), (pad, 0)]
    raw = matcher.compute(np.pad(l8, wide, mode="edge"), np.pad(r8, wide, mode="edge"))[:, pad:]
    matched = raw > (low - 1) * 16          # OpenCV marks a pixel without a match (low - 1) * 16
    grad = np.abs(cv2.Sobel(l8, cv2.CV_32F, 1, 0))
    matched &= cv2.boxFilter(grad, -1, (block, block)) > 0      # a flat patch matches anything
    return raw[matched].astype(np.float32) * (s / 16.0), float(matched.mean()), s


def auto_disp_range(left, right, check: RectificationCheck | None) -> AutoRange | None:
    """``--disp-range auto`` for a pair (module docstring), or None when neither the probe nor the
    features see enough of the pair to tell. The range lies within (-width + 1, width)."""
    width = np.shape(left)[1]
    window = feature_window(check, width)
    found, share, s = probe(left, right, window)
    if share < PROBE_MIN_SHARE or found.size < 2:
        if check is None or not math.isfinite(check.disparity_p99):
            return None
        return AutoRange(*window, "window", window, share=share, scale=s)
    p_lo, p_hi = (float(v) for v in np.percentile(found, [PROBE_LOW_Q, PROBE_HIGH_Q]))
    lo = math.floor(p_lo - PROBE_FAR_MARGIN_PX)
    hi = math.ceil(p_hi + PROBE_WIDEN * abs(p_hi) + PROBE_MARGIN_PX) + 1
    if p_hi >= window[1] - 2 * s:           # the probe saw the window's ceiling: keep the window's
        hi = window[1]
    if window[0] >= 0:                      # a parallel rig (the window says so)
        lo = max(lo, 0)
    hi = lo + ROUND_TO * math.ceil((hi - lo) / ROUND_TO)
    lo, hi = _clip(lo, hi, width)
    return AutoRange(lo, hi, "probe", window, p_lo, p_hi, share, s)
