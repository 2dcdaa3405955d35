"""The composed stereo chain: matching cost -> CBCA -> SGM -> CBCA -> WTA -> LR check and
filling -> sub-pixel -> median -> bilateral, as one jitted function.

``disparity(left, right, config)`` validates its inputs (numpy, at the boundary), converts
them to grey ``f32[H, W]`` and runs the jitted chain; ``stages(...)`` returns every
intermediate result for inspection.
"""

from __future__ import annotations

import functools
import numbers
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from stereojax import chain as chain_mod
from stereojax.config import StereoConfig, preset
from stereojax.data.images import as_grey, pair_float_scale
from stereojax.errors import ConfigError, StereoInputError, wxh
from stereojax.inference import tiling
from stereojax.inference.compile_cache import bucket_shape, ensure_enabled
from stereojax.inference.memory import check_memory
from stereojax.progress import Phases
from stereojax.volume import CostVolume


def min_image_size(config: StereoConfig) -> int:
    """Smallest height/width the chain accepts (the largest window it uses)."""
    c = config.cost
    windows = [2 * max(c.census_radius) + 1, 2 * c.sad_radius + 1, config.refine.median_size,
               2 * config.refine.bilateral_radius + 1, 2 * config.cbca.arm_length + 1]
    return max(windows)


def check_disp_range(disp_range, width: int | None = None) -> tuple[int, int] | None:
    """``(MIN, MAX)`` as ints (disparities MIN <= d < MAX), or None; a one-line
    :class:`StereoInputError` for anything else: not two integers, MIN >= MAX, or (given the
    image ``width``) a range at least as wide as the image."""
    if disp_range is None:
        return None

    try:
        lo, hi = disp_range
    except (TypeError, ValueError):
        raise StereoInputError(f"disp_range must be two integers (MIN, MAX), got {disp_range!r}") from None
    for v in (lo, hi):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise StereoInputError(f"disp_range must be two integers (MIN, MAX), got {disp_range!r}")
    lo, hi = int(lo), int(hi)
    if lo >= hi:
        raise StereoInputError(f"disp_range MIN must be below MAX (disparities MIN <= d < MAX), got {lo} {hi}")
    if width is not None and hi - lo >= width:
        raise StereoInputError(f"disp_range {lo}..{hi} spans {hi - lo} disparities, as many as the image is wide "
                               f"({width}); give a narrower range")
    return lo, hi


def check_pixel_range(pixel_range, shape: tuple[int, int], lo: int, hi: int) -> np.ndarray:
    """``i32[2, H, W]``: per-pixel limits (MIN, MAX maps, MIN <= d < MAX) checked and intersected
    with the range ``lo <= d < hi``; a one-line :class:`StereoInputError` for maps that are not
    two ``shape`` arrays of integers, or that leave a pixel no disparity."""
    try:
        mn, mx = pixel_range
        maps = np.stack([np.asarray(mn), np.asarray(mx)])
    except (TypeError, ValueError):
        raise StereoInputError("pixel_range must be two [H, W] maps (MIN, MAX) of the image's size "
                               f"{wxh(shape)}") from None
    if maps.shape != (2,) + tuple(shape):
        got = wxh(maps.shape[1:]) if maps.ndim == 3 else f"shape {maps.shape[1:]}"
        raise StereoInputError(f"pixel_range maps are {got}, the image is {wxh(shape)}")
    if maps.dtype.kind not in "iu":
        if maps.dtype.kind != "f" or not np.all(np.isfinite(maps)) or np.any(maps != np.round(maps)):
            raise StereoInputError("pixel_range maps must hold integers (disparities MIN <= d < MAX)")
    maps = np.clip(maps.astype(np.int64), lo, hi).astype(np.int32)
    empty = maps[0] >= maps[1]
    if empty.any():
        y, x = (int(v[0]) for v in np.nonzero(empty))
        raise StereoInputError(f"pixel_range leaves {int(empty.sum())} pixels no disparity (e.g. at row {y}, "
                               f"column {x}: MIN {int(np.asarray(mn)[y, x])}, MAX {int(np.asarray(mx)[y, x])}, "
                               f"within the range {lo}..{hi}); each needs MIN < MAX inside it")
    return maps


def shift_right_image(grey: np.ndarray, lo: int) -> np.ndarray:
    """The right image moved by ``lo`` columns, edges repeated: out[:, u] = grey[:, u - lo], so that
    disparity d of the original pair is disparity d - lo of (left, out)."""
    if lo == 0:
        return grey
    w = grey.shape[1]
    cols = np.clip(np.arange(w) - lo, 0, w - 1)
    return np.ascontiguousarray(grey[:, cols])


def _kind(arr: np.ndarray) -> str:
    return f"{'colour' if arr.ndim == 3 else 'grey'} {arr.dtype}"


def check_size(h: int, w: int, config: StereoConfig) -> None:
    """Refuse an ``h x w`` pair too small for ``config``'s windows or disparity range."""
    need = min_image_size(config)
    if h < need or w < need:
        raise StereoInputError(f"image is {w}x{h}, smaller than the {need}x{need} window the "
                               "configuration needs")
    if config.max_disp >= w:
        raise StereoInputError(f"max_disp must be smaller than the image width {w}, got {config.max_disp}")


def prepare_pair(left: Any, right: Any, config: StereoConfig, memory_limit_gb=None,
                 keep: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Check a pair against a config; return grey ``f32[H, W]`` left and right images.

    A colour image paired with a grey one (or 8-bit with 16-bit/float) is accepted: both are
    converted to grey 0..255, with an :class:`~stereojax.errors.InputWarning` saying so.
    Before returning, the chain's peak memory is estimated (:mod:`stereojax.inference.memory`) and a
    frame that would not fit in ``memory_limit_gb`` (default: ``STEREOJAX_MEMORY_LIMIT_GB``,
    else 70 % of the available memory) raises :class:`MemoryBudgetError`.
    """
    config.validate()
    la, ra = np.asarray(left), np.asarray(right)
    scale = pair_float_scale(la, ra)
    gl, gr = as_grey(la, "left", scale), as_grey(ra, "right", scale)
    if gl.shape != gr.shape:
        raise StereoInputError(f"left is {wxh(gl.shape)} but right is {wxh(gr.shape)}; a rectified pair has equal "
                               "sizes")
    if (la.ndim == 3) != (ra.ndim == 3) or la.dtype != ra.dtype:
        import warnings

        from stereojax.errors import InputWarning

        warnings.warn(f"left is {_kind(la)} but right is {_kind(ra)}; both converted to grey "
                      "0..255 before matching", InputWarning, stacklevel=3)
    h, w = gl.shape
    check_size(h, w, config)

    check_memory(h, w, config, memory_limit_gb, keep=keep)
    return gl, gr


def _chain(left: jax.Array, right: jax.Array, config: StereoConfig, variables=None, net=None,
           kept: dict | None = None, valid=None, limits=None) -> chain_mod.State:
    """Every stage of :data:`stereojax.chain.STAGES` in one program; ``kept``: see
    :func:`stereojax.chain.run`."""
    st = chain_mod.initial(left, right, valid, limits, variables, net)
    return chain_mod.run(chain_mod.STAGES, st, config, kept)


def chain_from_volume(vol, left: jax.Array, right: jax.Array, config: StereoConfig,
                      valid=None, right_offset=None, kept: dict | None = None) -> chain_mod.State:
    """Everything after the matching cost (:data:`stereojax.chain.BACK`) on the left-view
    volume: a :class:`~stereojax.volume.CostVolume`, or a full ``f32[H, W, D]`` array."""
    if not isinstance(vol, CostVolume):
        vol = CostVolume.full(vol, valid)
    st = chain_mod.State(left, right, vol.valid, vol=vol, offset=vol.offset if vol.banded else None,
                         right_offset=right_offset)
    return chain_mod.run(chain_mod.BACK, st, config, kept)


@functools.partial(jax.jit, static_argnames=("config", "net"))
def disparity_grey(left: jax.Array, right: jax.Array, config: StereoConfig, variables=None,
                   net=None) -> jax.Array:
    """Jitted chain on grey ``f32[H, W]`` images already checked by :func:`prepare_pair`.

    variables, net: the matching network's variables and (static) NetConfig when
    ``config.cost.method == "learned"``; None otherwise.
    """
    return _chain(left, right, config, variables, net).disparity


@functools.partial(jax.jit, static_argnames=("config", "net", "confidence"))
def disparity_padded(left: jax.Array, right: jax.Array, valid: jax.Array, config: StereoConfig,
                     variables=None, net=None, confidence: bool = False, limits=None) -> jax.Array:
    """:func:`disparity_grey` on a pair padded (right and bottom) to its size bucket.

    valid: ``i32[2]``, the real (rows, columns); it is an argument, not a static value, so every
    frame of one bucket runs the same compiled program. Crop the result to ``[:rows, :cols]``.
    confidence: also return the confidence map (:func:`stereojax.validation.confidence_measure.confidence`).
    limits: per-pixel disparity limits ``i32[2, H, W]`` (MIN <= d < MAX, chain disparities) or None.
    """
    return chain_mod.result(_chain(left, right, config, variables, net, valid=valid, limits=limits), confidence)


@functools.partial(jax.jit, static_argnames=("config", "net"))
def _volume_padded(left, right, valid, config: StereoConfig, variables=None, net=None):
    """(the left-view CostVolume, the right view's band offsets or None) of a padded pair: the
    chain's :data:`~stereojax.chain.FRONT`, cut where the chain cuts it
    (:func:`stereojax.chain.split`)."""
    if not chain_mod.two_programs(config, net):
        st = chain_mod.front(left, right, config, variables, net, valid)
    else:
        st = chain_mod.second_front(chain_mod.first_program(left, right, valid, config, variables, net),
                                    config, variables)
    return st.vol, st.right_offset


@functools.partial(jax.jit, static_argnames=("config", "confidence"))
def disparity_from_volume(vol, right_offset, left, right, config: StereoConfig, confidence: bool = False):
    """Everything after the matching cost (:func:`chain_from_volume`) on a padded pair's
    CostVolume; the disparity ``f32[H, W]`` of the bucket (crop it to ``vol.valid``), and its
    confidence when asked."""
    return chain_mod.result(chain_from_volume(vol, left, right, config, right_offset=right_offset), confidence)


@dataclass(frozen=True)
class Volume:
    """A pair's left-view matching cost, kept to run the rest of the chain on it many times
    (:meth:`Predictor.volume`): the :class:`~stereojax.volume.CostVolume` (its ``valid`` = the
    real (rows, columns)), the right view's band offsets (None: full range) and the grey images
    ``f32[Hb, Wb]``, padded to the size bucket."""

    cost: CostVolume
    right_offset: Any
    left: np.ndarray
    right: np.ndarray

    @property
    def valid(self):
        return np.asarray(self.cost.valid)


def pad_to(grey: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pad ``f32[H, W]`` on the right and bottom to ``shape`` by repeating the last column/row."""
    h, w = grey.shape
    return np.pad(grey, ((0, shape[0] - h), (0, shape[1] - w)), mode="edge")


class CompiledChain:
    """The chain's programs compiled once for a size bucket, a config, a network architecture
    and a device (ahead of time, so that compiling and running can be timed and reported apart).
    It holds no weights: the network's variables are an argument of every call, so one compiled
    chain serves every model of that architecture and can never run another model's weights.
    Call it with grey ``f32[H, W]`` images of any size in the bucket; it pads, runs and crops
    back exactly.
    """

    def __init__(self, shape: tuple[int, int], config: StereoConfig, net=None, variables=None, device=None,
                 confidence: bool = False, limited: bool = False):
        """variables: the variables (or arrays of their shapes) the chain will be called with.
        confidence: the chain returns (disparity, confidence). limited: every call gives
        per-pixel disparity limits (:meth:`Predictor.__call__`'s ``pixel_range``)."""
        self.shape, self.config, self.net, self.device = shape, config, net, device
        self.confidence, self.limited = confidence, limited
        sharding = None
        if device is not None:
            from jax.sharding import SingleDeviceSharding

            sharding = SingleDeviceSharding(device)
        var_spec = None if variables is None else jax.tree_util.tree_map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), variables)
        spec = jax.ShapeDtypeStruct(shape, jnp.float32, sharding=sharding)
        valid = jax.ShapeDtypeStruct((2,), jnp.int32, sharding=sharding)
        lim = jax.ShapeDtypeStruct((2,) + tuple(shape), jnp.int32, sharding=sharding) if limited else None
        self._two = chain_mod.two_programs(config, net)
        if self._two:          # the method's two programs, the second fed the first's outputs
            self._first = chain_mod.first_program.lower(spec, spec, valid, config, var_spec, net, lim).compile()
            carry = jax.eval_shape(lambda a, b, v, w, m: chain_mod.first_program(a, b, v, config, w, net, m),
                                   spec, spec, valid, var_spec, lim)
            if sharding is not None:
                carry = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding),
                                               carry)
            self._second = chain_mod.second_program.lower(carry, config, var_spec, confidence).compile()
        else:
            self._compiled = disparity_padded.lower(spec, spec, valid, config, var_spec, net, confidence,
                                                    lim).compile()

    def __call__(self, left: np.ndarray, right: np.ndarray, variables=None, limits=None) -> np.ndarray:
        """Disparity ``f32[H, W]`` of a grey pair in the bucket; variables: the network's, on
        this chain's device (:class:`Predictor` puts them there once); limits: ``i32[2, H, W]``
        per-pixel disparity limits (MIN <= d < MAX, chain disparities), given exactly when the
        chain was compiled ``limited``."""
        h, w = left.shape
        if h > self.shape[0] or w > self.shape[1]:
            raise ValueError(f"a {w}x{h} pair does not fit the {wxh(self.shape)} bucket")
        if (limits is not None) != self.limited:
            raise ValueError("per-pixel limits must be given exactly when the chain was compiled for them")
        lp, rp = pad_to(left, self.shape), pad_to(right, self.shape)
        lp, rp, valid = jax.device_put((lp, rp, np.array([h, w], np.int32)), self.device)
        lim = None
        if limits is not None:     # padding: the whole range
            lim = np.empty((2,) + tuple(self.shape), np.int32)
            lim[0], lim[1] = 0, self.config.max_disp
            lim[:, :h, :w] = limits
            lim = jax.device_put(lim, self.device)
        if self._two:
            out = self._second(self._first(lp, rp, valid, variables, lim), variables)
        else:
            out = self._compiled(lp, rp, valid, variables, lim)
        if self.confidence:
            return np.asarray(out[0])[:h, :w], np.asarray(out[1])[:h, :w]
        return np.asarray(out)[:h, :w]


#: the compiled chains of this process, keyed on what a program depends on (bucket, config,
#: architecture, device, the shapes of the variables), never on weights; the most recently used
#: few per device are kept (a batch of mixed sizes would otherwise hoard programs)
_COMPILED: dict = {}
_COMPILED_LOCK = threading.Lock()
_KEEP_PER_DEVICE = 4


def default_device(device=None):
    """``device``, or the default device when None."""
    if device is not None:
        return device
    d = jax.config.jax_default_device
    if isinstance(d, str):
        return jax.devices(d)[0]
    return d or jax.devices()[0]


def _variable_shapes(variables):
    if variables is None:
        return None
    leaves, tree = jax.tree_util.tree_flatten(variables)
    return tree, tuple((tuple(x.shape), str(x.dtype)) for x in leaves)


def compiled_chain(shape: tuple[int, int], config: StereoConfig, net=None, variables=None,
                   device=None, confidence: bool = False, limited: bool = False) -> tuple[CompiledChain, bool]:
    """(the :class:`CompiledChain` of a bucket shape, config, architecture and device, whether it
    was compiled now); ``variables`` give the shapes only. Safe to call from the worker threads
    of :func:`stereojax.devices.map_frames`. Most callers want :class:`Predictor`.

    ``device`` None means the default device, named: a program compiled for it is the one a
    batch compiles for its first device, so both find one persistent-cache entry."""
    device = default_device(device)
    key = (tuple(shape), config, net, device, _variable_shapes(variables), confidence, limited)
    with _COMPILED_LOCK:
        fresh = key not in _COMPILED
        if fresh:
            mine = [k for k in _COMPILED if k[3] == device]
            evict = mine[:max(0, len(mine) - _KEEP_PER_DEVICE + 1)]
            for old in evict:
                del _COMPILED[old]
            if evict:
                # JAX's own caches keep every executable alive, each with hundreds of memory maps
                # of its machine code (about 480 for a census chain on CPU); a long batch of many
                # sizes would reach the kernel's vm.max_map_count (65 530) and crash inside XLA.
                # The chains still kept are referenced here and stay compiled.
                jax.clear_caches()
            _COMPILED[key] = CompiledChain(tuple(shape), config, net, variables, device, confidence, limited)
        else:   # the most recently used last
            _COMPILED[key] = _COMPILED.pop(key)
        return _COMPILED[key], fresh


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
    here, and passed to every run.
    """

    def __init__(self, config: StereoConfig | None = None, model=None, device=None, memory_limit_gb=None,
                 confidence: bool = False, tile: str = "off", disp_range=None):
        self.disp_range = check_disp_range(disp_range)
        config = (config or preset("census")).validate()
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
        if variables is not None:
            variables = jax.device_put(variables, device)
        self.variables = variables

    def prepare(self, left, right) -> tuple[np.ndarray, np.ndarray]:
        """Grey ``f32[H, W]`` images of a pair, checked against this predictor's config (with a
        ``disp_range``, the right image moved by its MIN: :func:`shift_right_image`)."""
        if self.disp_range is not None and np.ndim(left) >= 2:
            check_disp_range(self.disp_range, np.shape(left)[1])
        gl, gr = prepare_pair(left, right, self.config, self.memory_limit_gb)
        if self.disp_range is None:
            return gl, gr
        return gl, shift_right_image(gr, self.disp_range[0])

    def _offset(self, out):
        """The chain's disparities moved back to the original pair's (``disp_range`` MIN added)."""
        if self.disp_range is None or self.disp_range[0] == 0:
            return out
        if self.confidence:
            return out[0] + np.float32(self.disp_range[0]), out[1]
        return out + np.float32(self.disp_range[0])

    def _key(self, height: int, width: int, limited: bool = False):

        return (bucket_shape(height, width), self.config, self.net, self.device, _variable_shapes(self.variables),
                self.confidence, bool(limited))

    def is_compiled(self, height: int, width: int, limited: bool = False) -> bool:
        """Whether the chain for a ``height x width`` pair is compiled in this process already."""
        return self._key(height, width, limited) in _COMPILED

    def compiled(self, height: int, width: int, limited: bool = False) -> tuple[CompiledChain, bool]:
        """(the compiled chain for a ``height x width`` pair, whether it was compiled now);
        ``limited``: the chain that takes per-pixel limits."""
        shape, config, net, device, _, confidence, limited = self._key(height, width, limited)
        return compiled_chain(shape, config, net, self.variables, device, confidence, limited)

    def limits(self, pixel_range, shape) -> np.ndarray | None:
        """``i32[2, H, W]`` per-pixel limits in the chain's disparities from ``pixel_range`` (two
        ``[H, W]`` maps MIN, MAX of the pair's disparities, MIN <= d < MAX; see :func:`check_pixel_range`),
        intersected with this predictor's range; None when ``pixel_range`` is None."""
        if pixel_range is None:
            return None
        lo = 0 if self.disp_range is None else self.disp_range[0]
        return check_pixel_range(pixel_range, tuple(shape[:2]), lo, lo + self.config.max_disp) - np.int32(lo)

    def run(self, gl: np.ndarray, gr: np.ndarray, limits=None) -> np.ndarray:
        """The chain on grey images already checked by :meth:`prepare`; ``limits`` from :meth:`limits`."""
        chain, _ = self.compiled(*gl.shape, limited=limits is not None)
        return self._offset(chain(gl, gr, self.variables, limits))

    def __call__(self, left, right, pixel_range=None) -> np.ndarray:
        """Dense sub-pixel disparity ``f32[H, W]`` (left view) of a rectified pair.

        pixel_range: None, or two ``[H, W]`` integer maps (MIN, MAX): pixel (y, x) takes a
        disparity MIN[y, x] <= d < MAX[y, x] (a prior from another sensor or an earlier frame),
        intersected with the predictor's range; banded chains move each band inside it."""
        limits = self.limits(pixel_range, np.shape(left))
        rows = self.strip_rows(left)
        if rows is not None:
            return self.in_strips(left, right, rows, limits=limits)
        return self.run(*self.prepare(left, right), limits)

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

    def _in_strips_shown(self, left, right, rows: int, n: int, phases, limits=None):
        """:meth:`in_strips` with a progress bar over the strips (the time left) unless ``phases``
        is quiet; (disparity, seconds)."""


        h, w = np.shape(left)[:2]
        t0 = time.perf_counter()
        if phases.quiet:
            return self.in_strips(left, right, rows, limits=limits), time.perf_counter() - t0
        print(f"stereojax: computing the disparity of {w}x{h} in {n} strips of {rows} rows (the whole frame would "
              "not fit the memory limit; --tile off refuses it)", flush=True)
        with tqdm(total=n, desc="strips", unit="strip", file=sys.stderr, dynamic_ncols=True) as bar:
            out = self.in_strips(left, right, rows, on_strip=lambda: bar.update(1), limits=limits)
        return out, time.perf_counter() - t0

    def volume(self, left, right) -> Volume:
        """The pair's matching cost with this predictor's cost settings, padded to its size
        bucket, for :meth:`from_volume` (e.g. to try many back-end settings on one volume)."""

        gl, gr = self.prepare(left, right)
        shape = bucket_shape(*gl.shape)
        lp, rp, valid = pad_to(gl, shape), pad_to(gr, shape), np.array(gl.shape, np.int32)
        cost, right_offset = _volume_padded(lp, rp, valid, self.config, self.variables, self.net)
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
        """(disparity, timings) of a pair, compilation timed apart: ``timings`` has ``seconds``
        (the run), ``compile_s`` (0 when this process had compiled the chain already), the
        ``bucket`` [H, W] and the ``device``. ``phases``: a :class:`stereojax.progress.Phases`
        that shows each step (default: silent). ``pixel_range``: as in :meth:`__call__`."""

        phases = phases or Phases(quiet=True)
        device = self.device
        limits = self.limits(pixel_range, np.shape(left))
        rows = self.strip_rows(left)
        if rows is not None:
            h, w = np.shape(left)[:2]
            n = len(tiling.strips(h, rows, tiling.SEAM_OVERLAP))
            out, secs = self._in_strips_shown(left, right, rows, n, phases, limits)
            shape = bucket_shape(rows, w)
            return out, {"seconds": secs, "compile_s": 0.0, "bucket": [int(shape[0]), int(shape[1])],
                         "device": str(device), "strips": n, "strip_rows": rows}
        gl, gr = self.prepare(left, right)
        shape = bucket_shape(*gl.shape)
        compile_s = 0.0
        limited = limits is not None
        if not self.is_compiled(*gl.shape, limited=limited):
            phases.start(f"compiling the {self.config.cost.method} chain for {shape[1]}x{shape[0]} "
                         f"(size bucket of {gl.shape[1]}x{gl.shape[0]}), {self.config.max_disp} disparities")
            self.compiled(*gl.shape, limited=limited)
            compile_s = phases.done()
        phases.start(f"computing the disparity of {gl.shape[1]}x{gl.shape[0]}")
        disp = self.run(gl, gr, limits)
        secs = phases.done()
        return disp, {"seconds": secs, "compile_s": compile_s, "bucket": [int(shape[0]), int(shape[1])],
                      "device": str(device)}

    def stages(self, left, right) -> dict[str, np.ndarray]:
        """Every intermediate result (see :func:`stages`)."""
        return stages(left, right, self.config, self.model, self.memory_limit_gb)


@functools.partial(jax.jit, static_argnames=("config", "net"))
def _stages_grey(left, right, config, variables=None, net=None):
    kept = {}
    _chain(left, right, config, variables, net, kept)
    return _as_arrays(kept)


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
    out = _stages_grey(jnp.asarray(gl), jnp.asarray(gr), config, variables, net)
    return {k: np.asarray(v) for k, v in out.items()}


def _as_arrays(out: dict) -> dict:
    """Volumes of the kept stages as full ``f32[H, W, D]`` arrays (entries outside a band: 1),
    and the bands' offsets as ``band_offset`` when banded."""
    res = {}
    for k, v in out.items():
        if isinstance(v, CostVolume):
            res[k] = v.to_full(1.0)
            if v.banded and k == "cost":
                res["band_offset"] = v.offset
        else:
            res[k] = v
    return res
