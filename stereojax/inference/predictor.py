"""The predictor: one call from an image pair to its disparity map.

:class:`Predictor` holds a chain configuration, a model and a device; calling it checks and
converts the pair (:mod:`stereojax.inference.prepare`), runs the chain compiled once per size
bucket (:mod:`stereojax.inference.programs`), tiles a frame too large for memory
(:mod:`stereojax.inference.tiling`) and crops back. ``disparity(left, right, config)`` and
``stages(...)`` are its one-call forms; what a run prints lives in
:mod:`stereojax.inference.reporting`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import chain as chain_mod, kernels as kernels_mod
from stereojax.config import StereoConfig, preset
from stereojax.errors import ConfigError
from stereojax.inference import reporting, tiling
from stereojax.inference.compile_cache import bucket_shape, ensure_enabled
from stereojax.matching_cost.cascade import Cascade  # noqa: F401  (re-exported as stereojax.Cascade)
from stereojax.inference.prepare import check_disp_range, check_pixel_range, prepare_pair, range_pair
from stereojax.inference.programs import (CompiledChain, Volume, compiled_chain, default_device, disparity_from_volume,
                                          disparity_grey, is_kept, pad_to, stages_grey, variable_shapes,
                                          volume_padded)


class Predictor:
    """The one inference path of stereojax: a chain configuration, a model (a
    :class:`~stereojax.matching_cost.learned.LearnedModel` when ``config.cost.method == "learned"``, else
    None) and a device (None: the default one). Calling it on a pair checks and converts the
    images (:func:`prepare_pair`, memory guard included), pads them to their size bucket, runs
    the chain compiled once per bucket (:func:`compiled_chain`) and crops back::

        predict = Predictor(config, model)
        disp = predict(left, right)               # f32[H, W]
        inter = predict.stages(left, right)       # every intermediate result
        disp, conf = Predictor(config, model, confidence=True)(left, right)

    ``tile="auto"``: a frame whose chain would not fit the memory limit is computed in
    horizontal bands and stitched (:mod:`stereojax.inference.tiling`) instead of refused.
    ``confidence=True``: every call returns (disparity, confidence), the confidence a per-pixel
    value in [0, 1] from the cost margin and the left-right agreement
    (:func:`stereojax.validation.confidence_measure.confidence`). The model's variables are put on the device once,
    here, and passed to every run. ``cascade``: a :class:`~stereojax.matching_cost.cascade.Cascade`,
    the full network's cost where this (student) model is least sure
    (:mod:`stereojax.matching_cost.cascade`). ``kernels``: "auto", "native" or "xla", the kernels of
    the classical stages (:mod:`stereojax.kernels`), replacing ``config.kernels``; None keeps the config's.
    ``rectifier``: a :class:`~stereojax.data.stereo_rig.Rectifier`; every pair given to
    ``__call__``, :meth:`timed`, :meth:`volume` and :meth:`stages` is then a raw pair of its rig,
    rectified first (the disparity is on the rectified grid; depth from ``rectifier.calibration``).
    """

    def __init__(self, config: StereoConfig | None = None, model=None, device=None, memory_limit_gb=None,
                 confidence: bool = False, tile: str = "off", disp_range=None, cascade: Cascade | None = None,
                 kernels: str | None = None, rectifier=None):
        self.rectifier = rectifier
        self.disp_range = check_disp_range(disp_range)
        config = (config or preset("census")).validate()
        if kernels is not None:
            config = dataclasses.replace(config, kernels=kernels).validate()
        kernels_mod.native(config.kernels)   # "native" without the library: ConfigError here, not at the first call
        if self.disp_range is not None:      # MIN <= d < MAX: the chain runs over MAX - MIN disparities
            config = config.with_max_disp(self.disp_range[1] - self.disp_range[0])
        self.config = config
        self.confidence = bool(confidence)
        if tile not in ("off", "auto"):
            raise ConfigError(f"tile must be 'auto' or 'off', got {tile!r}")
        self.tile = tile
        variables, self.net = chain_mod.model_args(self.config, model)
        ensure_enabled()          # the persistent compile cache, as the CLI has it
        device = default_device(device)
        self.model, self.device, self.memory_limit_gb = model, device, memory_limit_gb
        self.cascade = None
        if cascade is not None:
            cascade = cascade.check()
            if not chain_mod.two_programs(self.config, self.net):
                raise ConfigError("the cascade's student must be a learned model with a pruned head "
                                  "(cost.candidates > 0), e.g. kitti2015_compact")
            self.cascade = cascade.spec()
            variables = (variables, cascade.full.variables)
        if variables is not None:
            variables = jax.device_put(variables, device)
        self.variables = variables

    def prepare(self, left, right) -> tuple[np.ndarray, np.ndarray]:
        """Grey ``f32[H, W]`` images of a pair, checked against this predictor's config: the chain's
        input. With a ``disp_range`` of MIN > 0, the pair without the MIN left columns that no
        disparity of the range can match (:func:`~stereojax.inference.prepare.range_pair`; the
        images are ``W - MIN`` wide); MIN < 0: the right image moved by MIN."""
        if self.disp_range is not None and np.ndim(left) >= 2:
            check_disp_range(self.disp_range, np.shape(left)[1])
        gl, gr = prepare_pair(left, right, self.config, self.memory_limit_gb)
        if self.disp_range is None:
            return gl, gr
        return range_pair(gl, gr, self.disp_range[0], self.config)

    def _cut(self) -> int:
        """The left columns :meth:`prepare` leaves out (a ``disp_range`` MIN > 0), else 0."""
        return 0 if self.disp_range is None else max(self.disp_range[0], 0)

    def _offset(self, out):
        """The chain's disparities moved back to the original pair's (``disp_range`` MIN added);
        with MIN > 0, the MIN left columns the chain did not search put back: the disparity of
        the first searched column, confidence 0 (no disparity of the range has a match there)."""
        if self.disp_range is None or self.disp_range[0] == 0:
            return out
        lo, cut = np.float32(self.disp_range[0]), self._cut()

        def back(disp):
            disp = np.asarray(disp) + lo
            return np.concatenate([np.repeat(disp[:, :1], cut, axis=1), disp], axis=1) if cut else disp

        if self.confidence:
            conf = np.asarray(out[1])
            if cut:
                conf = np.concatenate([np.zeros((conf.shape[0], cut), conf.dtype), conf], axis=1)
            return back(out[0]), conf
        return back(out)

    def _key(self, height: int, width: int, limited: bool = False, given_bands: bool = False):

        return (bucket_shape(height, width), self.config, self.net, self.device, variable_shapes(self.variables),
                self.confidence, bool(limited), self.cascade, bool(given_bands))

    def is_compiled(self, height: int, width: int, limited: bool = False, given_bands: bool = False) -> bool:
        """Whether the chain for a ``height x width`` pair is compiled in this process already (the
        size of the chain's input, :meth:`prepare`'s, which a ``disp_range`` MIN > 0 narrows)."""
        return is_kept(self._key(height, width, limited, given_bands))

    def compiled(self, height: int, width: int, limited: bool = False,
                 given_bands: bool = False) -> tuple[CompiledChain, bool]:
        """(the compiled chain for a ``height x width`` pair, whether it was compiled now);
        ``limited``: the chain that takes per-pixel limits; ``given_bands``: the chain that takes
        its band offsets instead of running the coarse pass."""
        shape, config, net, device, _, confidence, limited, cascade, given = self._key(height, width, limited,
                                                                                    given_bands)
        return compiled_chain(shape, config, net, self.variables, device, confidence, limited, cascade, given)

    def limits(self, pixel_range, shape) -> np.ndarray | None:
        """``i32[2, H, W]`` per-pixel limits in the chain's disparities from ``pixel_range`` (two
        ``[H, W]`` maps MIN, MAX of the pair's disparities, MIN <= d < MAX; see :func:`check_pixel_range`),
        intersected with this predictor's range; None when ``pixel_range`` is None."""
        if pixel_range is None:
            return None
        lo = 0 if self.disp_range is None else self.disp_range[0]
        maps = check_pixel_range(pixel_range, tuple(shape[:2]), lo, lo + self.config.max_disp) - np.int32(lo)
        return np.ascontiguousarray(maps[:, :, self._cut():])     # the columns :meth:`prepare` keeps

    def run(self, gl: np.ndarray, gr: np.ndarray, limits=None, bands=None) -> np.ndarray:
        """The chain on grey images already checked by :meth:`prepare`; ``limits`` from :meth:`limits`."""
        chain, _ = self.compiled(*gl.shape, limited=limits is not None, given_bands=bands is not None)
        return self._offset(chain(gl, gr, self.variables, limits, bands))

    def __call__(self, left, right, pixel_range=None, bands=None) -> np.ndarray:
        """Dense sub-pixel disparity ``f32[H, W]`` (left view) of a rectified pair.

        pixel_range: None, or two ``[H, W]`` integer maps (MIN, MAX): pixel (y, x) takes a
        disparity MIN[y, x] <= d < MAX[y, x] (a prior from another sensor or an earlier frame),
        intersected with the predictor's range; banded chains move each band inside it.
        bands: (left, right) band offsets ``i32[H, W]`` of a banded config, in the chain's
        disparities (each pixel's band is offset .. offset + band.width - 1), used instead of the
        coarse pass (:class:`stereojax.inference.sequence.Sequence` gives them from its prior)."""
        left, right = self.rectified(left, right)
        limits = self.limits(pixel_range, np.shape(left))
        if bands is not None:
            if not self.config.banded:
                raise ConfigError("bands= needs a banded config (band.width > 0)")
            bl, br = (np.asarray(b, np.int32) for b in bands)
            cut = self._cut()        # the columns :meth:`prepare` keeps: left x >= MIN, right u < W - MIN
            if cut:
                bl, br = np.ascontiguousarray(bl[:, cut:]), np.ascontiguousarray(br[:, :br.shape[1] - cut])
            return self.run(*self.prepare(left, right), limits, (bl, br))
        rows = self.strip_rows(left)
        if rows is not None:
            return self.in_strips(left, right, rows, limits=limits)
        return self.run(*self.prepare(left, right), limits)

    def rectified(self, left, right):
        """The pair rectified by this predictor's ``rectifier`` (unchanged without one)."""
        return (left, right) if self.rectifier is None else self.rectifier.rectify(left, right)

    def strip_rows(self, left) -> int | None:
        """With ``tile="auto"``, the rows per strip when the whole frame would not fit the memory
        limit (:mod:`stereojax.inference.tiling`); None when it is computed whole."""

        shape = np.shape(left)
        if self.tile != "auto" or len(shape) < 2:     # a bad input is refused by prepare()
            return None
        h, w = shape[:2]
        if tiling.fits(h, w, self.config, self.memory_limit_gb):
            return None
        return tiling.strip_rows(h, w, self.config, self.memory_limit_gb)

    def in_strips(self, left, right, rows: int, overlap: int | None = None, on_strip=None, limits=None):
        """The pair in horizontal strips of ``rows`` rows, stitched (:func:`stereojax.inference.tiling.run_in_strips`);
        ``limits`` (from :meth:`limits`) cut into the same strips."""

        return tiling.run_in_strips(lambda a, b, m=None: self.run(*self.prepare(a, b), m), left, right, rows,
                                   tiling.SEAM_OVERLAP if overlap is None else overlap, on_strip, limits)

    def volume(self, left, right) -> Volume:
        """The pair's matching cost with this predictor's cost settings, padded to its size
        bucket, for :meth:`from_volume` (e.g. to try many back-end settings on one volume)."""

        if self.cascade is not None:
            raise ConfigError("volume() keeps one network's cost; a cascade mixes two (use its student's Predictor)")
        gl, gr = self.prepare(*self.rectified(left, right))
        shape = bucket_shape(*gl.shape)
        lp, rp, valid = pad_to(gl, shape), pad_to(gr, shape), np.array(gl.shape, np.int32)
        cost, right_offset = volume_padded(lp, rp, valid, self.config, self.variables, self.net)
        return Volume(jax.device_get(cost), jax.device_get(right_offset), lp, rp)

    def from_volume(self, volume: Volume) -> np.ndarray:
        """The disparity ``f32[H, W]`` of a pair from its :meth:`volume`, with this predictor's
        aggregation, SGM and refinement settings (the cost settings are the volume's). Each new
        setting compiles a program; ``disparity_from_volume.clear_cache()`` frees them."""
        if volume.cost.banded != self.config.banded:
            raise ConfigError("the volume's bands and this predictor's band.width differ (banded "
                              f"{volume.cost.banded} vs {self.config.banded}); make the volume with "
                              "the same band settings")
        out = disparity_from_volume(volume.cost, volume.right_offset, volume.left, volume.right, self.config,
                                    self.confidence)
        h, w = volume.valid
        if self.confidence:
            return self._offset((np.asarray(out[0])[:h, :w], np.asarray(out[1])[:h, :w]))
        return self._offset(np.asarray(out)[:h, :w])

    def timed(self, left, right, phases=None, pixel_range=None) -> tuple[np.ndarray, dict]:
        """(disparity, timings) of a pair, compilation timed apart
        (:func:`stereojax.inference.reporting.timed`)."""
        return reporting.timed(self, *self.rectified(left, right), phases, pixel_range)

    def stages(self, left, right) -> dict[str, np.ndarray]:
        """Every intermediate result (see :func:`stages`)."""
        return stages(*self.rectified(left, right), self.config, self.model, self.memory_limit_gb)


def disparity(left: Any, right: Any, config: StereoConfig | None = None, params=None,
              memory_limit_gb=None, bucket: bool = True, confidence: bool = False,
              disp_range=None, pixel_range=None) -> np.ndarray:
    """Dense sub-pixel disparity ``f32[H, W]`` (left view) of a rectified pair.

    left, right: ``[H, W]`` or ``[H, W, 3]`` arrays (uint8, uint16 or float). config: a
    :class:`StereoConfig` (default: census preset, 228 disparities). params: a
    :class:`~stereojax.matching_cost.learned.LearnedModel` when ``config.cost.method == "learned"``.
    memory_limit_gb: refuse frames whose estimated peak memory exceeds this many GiB
    (default: ``STEREOJAX_MEMORY_LIMIT_GB``, else 70 % of the available memory; see
    :mod:`stereojax.inference.memory`). bucket: pad the pair to its size bucket
    (:func:`stereojax.inference.compile_cache.bucket_shape`) so that nearby sizes share one compiled
    program, and crop back (the result equals the unpadded one away from the padding); False
    compiles for the exact size. confidence: return (disparity, confidence ``f32[H, W]`` in
    [0, 1]), see :class:`Predictor`. disp_range: ``(MIN, MAX)``, the disparities MIN <= d < MAX
    to search instead of ``0 .. config.max_disp - 1`` (MIN may be negative: converging
    cameras, Middlebury's offsets). pixel_range: two ``[H, W]`` integer maps (MIN, MAX), each
    pixel's own limits MIN <= d < MAX, intersected with the range (:meth:`Predictor.__call__`).
    Raises :class:`StereoInputError` / :class:`ConfigError` on bad input and
    :class:`MemoryBudgetError` before allocating a chain that would not fit.
    """
    config = config or preset("census")
    if bucket or confidence or disp_range is not None or pixel_range is not None:
        return Predictor(config, params, memory_limit_gb=memory_limit_gb, confidence=confidence,
                         disp_range=disp_range)(left, right, pixel_range=pixel_range)
    variables, net = chain_mod.model_args(config, params)
    gl, gr = prepare_pair(left, right, config, memory_limit_gb)
    ensure_enabled()
    return np.asarray(disparity_grey(jnp.asarray(gl), jnp.asarray(gr), config, variables, net))


def stages(left: Any, right: Any, config: StereoConfig | None = None, params=None,
           memory_limit_gb=None) -> dict[str, np.ndarray]:
    """Every intermediate result of :func:`disparity` as numpy arrays.

    Keys: cost, cost_cbca, cost_sgm, cost_final (``f32[H, W, D]``; banded chains: entries
    outside a pixel's band are 1, and ``band_offset`` holds the bands), disp_wta, disp_right,
    labels (0 correct, 1 mismatch, 2 occlusion), disp_filled, disp_subpixel, disp_median,
    confidence, disparity. memory_limit_gb: as in :func:`disparity` (the estimate counts the kept volumes).
    """
    config = config or preset("census")
    variables, net = chain_mod.model_args(config, params)
    gl, gr = prepare_pair(left, right, config, memory_limit_gb, keep=True)
    out = stages_grey(jnp.asarray(gl), jnp.asarray(gr), config, variables, net)
    return {k: np.asarray(v) for k, v in out.items()}
