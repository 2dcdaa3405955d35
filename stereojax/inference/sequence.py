"""Streams from a moving camera: each frame's disparity narrows the next one's search.

:class:`Sequence` takes one rectified pair at a time. The first frame (and any frame after a
fallback) runs the ordinary chain. Every later frame takes per-pixel limits ``MIN <= d < MAX``
(the chain's ``pixel_range``) from the previous frame:

* a pixel has a *prior* where it was confident in the previous frame (confidence >=
  ``min_confidence``) within ``own_radius`` of it; its limits are the min .. max of the confident
  disparities within ``radius``, widened by ``relative`` of the disparity and by ``margin``
  pixels (objects come closer, and pixels move across the image between frames: the window
  covers that motion). An object unsure in the previous frame thus keeps the whole range, not
  the limits of the confident background around it;
* a pixel without a prior keeps the whole range (its band comes from the coarse pass);
* the chain then runs with a narrower band (``band_width`` instead of the config's 48), which
  is where the time goes: every band kernel costs in proportion to it;
* where at least ``skip_coarse_share`` of the pixels have a prior, the bands come from the prior
  too (each band centred on its pixel's limits; a pixel without a prior takes the nearest prior
  pixel's of its row; the right view's from the left centre at its match) and the coarse pass
  does not run.

Fallbacks, each recorded in the frame's record:

* **scene cut**: the left image's normalised cross-correlation with the previous left image, at
  1/8 scale, below ``cut_ncc`` -> the whole frame runs without a prior;
* **too little prior**: fewer than ``min_share`` of the pixels have one -> the same;
* **prior disagrees with the frame**: a quick probe of the new pair (OpenCV's StereoSGBM at half
  size, about 0.05 s on a KITTI frame) falls inside the limits (2 px of slack) at fewer than
  ``min_agree`` of the prior pixels it matches -> the same, before the chain runs;
* **prior disagrees**: after the run, more than ``max_pinned`` of the prior pixels sit on a limit
  (within 0.5 px of MIN or MAX - 1, away from the range's own ends): the limits cut the true
  disparity off -> the frame is run again without a prior (a wrong prior costs time, not accuracy);
* **size change**: a frame of another size restarts the sequence at that frame.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereojax.data.images import to_u8
from stereojax.inference.predictor import Predictor


@dataclass(frozen=True)
class PriorSettings:
    """How a frame's disparity becomes the next frame's limits (module docstring)."""

    min_confidence: float = 0.5
    own_radius: int = 2
    radius: int = 16
    margin: int = 3
    relative: float = 0.25
    min_share: float = 0.6
    cut_ncc: float = 0.5
    #: the two checks of a wrong prior, chosen on KITTI 2015 training frames 000001-000015 (own prior
    #: moved 3 px: agreement >= 0.989, pinned <= 0.021; another frame's: agreement 0.66-0.99)
    max_pinned: float = 0.025
    min_agree: float = 0.97
    #: the band and the coarse pass: by default the config's band (48) and the coarse pass always, which
    #: leaves the result as good as without a prior; band_width=32, skip_coarse_share=0.8 takes about
    #: 0.9x the time but lost up to 0.26 points > 3 px on validation (experiments/results/sequence.md)
    band_width: int = 48
    skip_coarse_share: float = 1.01


def prior_limits(disp: np.ndarray, conf: np.ndarray, max_disp: int, s: PriorSettings):
    """(MIN, MAX) ``i32[H, W]`` limits for the next frame from a disparity and its confidence, and
    ``bool[H, W]`` where a prior exists (elsewhere the limits are the whole range 0 .. max_disp)."""
    sure = (conf >= s.min_confidence) & np.isfinite(disp) & (disp > 0)
    k = np.ones((2 * s.radius + 1, 2 * s.radius + 1), np.uint8)
    lo = cv2.erode(np.where(sure, disp, np.float32(1e9)).astype(np.float32), k)
    hi = cv2.dilate(np.where(sure, disp, np.float32(-1e9)).astype(np.float32), k)
    near = np.ones((2 * s.own_radius + 1, 2 * s.own_radius + 1), np.uint8)
    has = (hi >= lo) & (cv2.dilate(sure.astype(np.uint8), near) > 0)
    mn = np.floor(lo * (1 - s.relative)) - s.margin
    mx = np.ceil(hi * (1 + s.relative)) + s.margin + 1
    mn = np.where(has, np.clip(mn, 0, max_disp - 1), 0).astype(np.int32)
    mx = np.where(has, np.clip(mx, mn + 1, max_disp), max_disp).astype(np.int32)
    return mn, mx, has


def probe_map(left, right, max_disp: int) -> tuple[np.ndarray, np.ndarray]:
    """A quick disparity of a pair: OpenCV StereoSGBM at half size over 0 .. max_disp, left-padded
    (``f32[H, W]`` in full-size pixels, and ``bool[H, W]`` where it matched), brought back to
    full size (nearest)."""
    l8, r8 = to_u8(left), to_u8(right)
    if l8.ndim == 3:
        l8, r8 = cv2.cvtColor(l8, cv2.COLOR_RGB2GRAY), cv2.cvtColor(r8, cv2.COLOR_RGB2GRAY)
    h, w = l8.shape
    size = (max(w // 2, 1), max(h // 2, 1))
    l8 = cv2.resize(l8, size, interpolation=cv2.INTER_AREA)
    r8 = cv2.resize(r8, size, interpolation=cv2.INTER_AREA)
    count = int(np.ceil(max(max_disp // 2, 1) / 16) * 16)
    block = 5
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=count, blockSize=block, P1=8 * block * block,
                                    P2=32 * block * block, disp12MaxDiff=1, uniquenessRatio=15,
                                    speckleWindowSize=50, speckleRange=1, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    wide = [(0, 0), (count, 0)]
    raw = matcher.compute(np.pad(l8, wide, mode="edge"), np.pad(r8, wide, mode="edge"))[:, count:]
    disp = cv2.resize(raw.astype(np.float32) * (2 / 16.0), (w, h), interpolation=cv2.INTER_NEAREST)
    ok = cv2.resize((raw >= 0).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    return disp, ok


def agreement(probe: np.ndarray, probe_ok: np.ndarray, mn, mx, has, slack: float = 2.0) -> float:
    """The share of the prior pixels the probe matched whose probe disparity lies within their
    limits (``slack`` px either side); 1 when it matched none of them."""
    seen = has & probe_ok
    if not seen.any():
        return 1.0
    inside = (probe >= mn - slack) & (probe <= mx - 1 + slack)
    return float((inside & seen).sum() / seen.sum())


def prior_bands(mn, mx, has, k: int, max_disp: int) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) band offsets ``i32[H, W]`` of width ``k`` from a prior's limits: each band
    centred on its pixel's limits; a pixel without a prior takes the nearest prior pixel's centre
    in its row (the frame's median centre where a row has none); a right pixel x' the left
    centre at its match x' + c, with c the left centre at x'."""
    h, w = mn.shape
    centre = ((mn + mx) // 2).astype(np.int64)
    if not has.all():
        cols = np.arange(w)
        fill = int(np.median(centre[has])) if has.any() else max_disp // 2
        for y in np.nonzero(~has.all(axis=1))[0]:
            idx = np.nonzero(has[y])[0]
            if idx.size == 0:
                centre[y] = fill
                continue
            nearest = idx[np.clip(np.searchsorted(idx, cols), 0, idx.size - 1)]
            before = idx[np.clip(np.searchsorted(idx, cols) - 1, 0, idx.size - 1)]
            pick = np.where(np.abs(before - cols) < np.abs(nearest - cols), before, nearest)
            centre[y] = np.where(has[y], centre[y], centre[y, pick])
    left = np.clip(centre - k // 2, 0, max_disp - k)
    match = np.clip(np.arange(w)[None, :] + centre, 0, w - 1)
    right = np.clip(np.take_along_axis(centre, match, axis=1) - k // 2, 0, max_disp - k)
    return left.astype(np.int32), right.astype(np.int32)


def image_ncc(a: np.ndarray, b: np.ndarray, scale: int = 8) -> float:
    """Normalised cross-correlation of two images (grey or colour) at 1/``scale`` size."""
    def small(x):
        x = np.asarray(x, np.float32)
        if x.ndim == 3:
            x = x.mean(-1)
        x = cv2.resize(x, (max(1, x.shape[1] // scale), max(1, x.shape[0] // scale)), interpolation=cv2.INTER_AREA)
        return (x - x.mean()) / (x.std() + 1e-6)
    return float((small(a) * small(b)).mean())


def pinned_share(disp: np.ndarray, mn: np.ndarray, mx: np.ndarray, has: np.ndarray, max_disp: int) -> float:
    """The share of prior pixels whose disparity sits on a limit that the prior set (within 0.5
    px of MIN or of MAX - 1, where that limit is not the range's own end)."""
    if not has.any():
        return 0.0
    at_lo = (np.abs(disp - mn) <= 0.5) & (mn > 0)
    at_hi = (np.abs(disp - (mx - 1)) <= 0.5) & (mx < max_disp)
    return float(((at_lo | at_hi) & has).sum() / has.sum())


@dataclass
class Frame:
    """One frame of a :class:`Sequence`: its disparity and confidence ``f32[H, W]`` and its
    record (what the prior did, the fallback and why, the seconds)."""

    disparity: np.ndarray
    confidence: np.ndarray
    record: dict = field(default_factory=dict)


class Sequence:
    """Disparity of a stream of rectified pairs, one :meth:`push` per frame (module docstring)::

        seq = Sequence(config, model)
        for left, right in frames:
            f = seq.push(left, right)      # f.disparity, f.confidence, f.record

    ``config``/``model``: the chain, as for :class:`Predictor` (``device``, ``cascade`` too).
    ``settings``: :class:`PriorSettings`. ``rectifier``: a
    :class:`~stereojax.data.stereo_rig.Rectifier`: the frames are raw pairs of its rig, rectified first.
    """

    def __init__(self, config, model=None, settings: PriorSettings | None = None, device=None, cascade=None,
                 rectifier=None):
        self.rectifier = rectifier
        self.settings = settings or PriorSettings()
        self.full = Predictor(config, model, device, confidence=True, cascade=cascade)
        narrow = self.full.config
        if narrow.banded and self.settings.band_width < narrow.band.width:
            narrow = dataclasses.replace(narrow, band=dataclasses.replace(narrow.band, width=self.settings.band_width))
        self.tight = Predictor(narrow.validate(), model, device, confidence=True, cascade=cascade)
        self.max_disp = self.full.config.max_disp
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame: the next one runs without a prior."""
        self._prev = None
        self.index = 0

    def compile(self, height: int, width: int) -> float:
        """Compile the chains this sequence can run for this size (without limits, with limits,
        and with bands from the prior where the settings allow it); the seconds it took (0 when
        they were compiled already)."""
        t0 = time.perf_counter()
        if not self.full.is_compiled(height, width):
            self.full.compiled(height, width)
        prior_bands_possible = self.tight.config.banded and self.settings.skip_coarse_share <= 1.0
        for given in (False, True) if prior_bands_possible else (False,):
            if not self.tight.is_compiled(height, width, limited=True, given_bands=given):
                self.tight.compiled(height, width, limited=True, given_bands=given)
        return time.perf_counter() - t0

    def push(self, left, right) -> Frame:
        """The next frame's disparity, with the previous frame's as its prior where that holds."""
        t0 = time.perf_counter()
        if self.rectifier is not None:
            left, right = self.rectifier.rectify(left, right)
        shape = tuple(np.shape(left)[:2])
        record = {"frame": self.index}
        prior = None
        if self._prev is not None:
            prev_left, prev_disp, prev_conf = self._prev
            if prev_disp.shape != shape:
                record["fallback"] = (f"size changed from {prev_disp.shape[1]}x{prev_disp.shape[0]} to "
                                      f"{shape[1]}x{shape[0]}: the sequence restarts here")
            else:
                ncc = image_ncc(prev_left, left)
                record["ncc"] = round(ncc, 4)
                if ncc < self.settings.cut_ncc:
                    record["fallback"] = (f"scene cut: the left image correlates {ncc:.2f} with the previous one "
                                          f"(< {self.settings.cut_ncc})")
                else:
                    prior = (prev_disp, prev_conf)
        frame = self.predict(left, right, prior, record)
        self._prev = (np.asarray(left), frame.disparity, frame.confidence)
        self.index += 1
        frame.record["seconds"] = time.perf_counter() - t0
        return frame

    def predict(self, left, right, prior=None, record: dict | None = None) -> Frame:
        """One frame, with ``prior`` = (disparity, confidence) of another frame of this size as its
        prior (None: the ordinary chain); the checks of :meth:`push` after the run included."""
        record = {} if record is None else record
        s = self.settings
        if prior is None:
            record.setdefault("fallback", "first frame" if "frame" in record and record["frame"] == 0 else
                              record.get("fallback", "no prior"))
            return self._plain(left, right, record)
        mn, mx, has = prior_limits(np.asarray(prior[0], np.float32), np.asarray(prior[1], np.float32),
                                   self.max_disp, s)
        share = float(has.mean())
        record.update(prior_share=round(share, 4),
                      mean_limit_width=round(float((mx - mn)[has].mean()) if has.any() else 0.0, 2))
        if share < s.min_share:
            record["fallback"] = f"too little prior: {100 * share:.1f} % of the pixels (< {100 * s.min_share:g} %)"
            return self._plain(left, right, record)
        agree = agreement(*probe_map(left, right, self.max_disp), mn, mx, has)
        record["agreement"] = round(agree, 4)
        if agree < s.min_agree:
            record["fallback"] = (f"prior disagrees with this frame: a quick probe falls inside the limits at "
                                  f"{100 * agree:.1f} % of the prior pixels (< {100 * s.min_agree:g} %)")
            return self._plain(left, right, record)
        bands = None
        if self.tight.config.banded and share >= s.skip_coarse_share:
            bands = prior_bands(mn, mx, has, self.tight.config.band.width, self.max_disp)
        record["coarse_pass"] = bands is None
        disp, conf = self.tight(left, right, pixel_range=(mn, mx), bands=bands)
        pinned = pinned_share(disp, mn, mx, has, self.max_disp)
        record["pinned_share"] = round(pinned, 4)
        if pinned > s.max_pinned:
            record["fallback"] = (f"prior disagrees: {100 * pinned:.1f} % of the prior pixels sit on a limit "
                                  f"(> {100 * s.max_pinned:g} %); run again without it")
            return self._plain(left, right, record)
        record.update(used_prior=True, fallback=None)
        return Frame(disp, conf, record)

    def _plain(self, left, right, record) -> Frame:
        disp, conf = self.full(left, right)
        record["used_prior"] = False
        return Frame(disp, conf, record)
