"""The chain as compiled programs: jitted functions of a padded pair, one :class:`CompiledChain`
per size bucket, config, architecture and device, and the process's few kept chains.

:class:`stereojax.inference.predictor.Predictor` picks the program for a pair; nothing here
checks inputs (:mod:`stereojax.inference.prepare` does) or prints.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import SingleDeviceSharding

from stereojax import chain as chain_mod
from stereojax.config import StereoConfig
from stereojax.errors import wxh
from stereojax.volume import CostVolume


def _chain(left: jax.Array, right: jax.Array, config: StereoConfig, variables=None, net=None,
           kept: dict | None = None, valid=None, limits=None, bands=None) -> chain_mod.State:
    """Every stage of :data:`stereojax.chain.STAGES` in one program; ``kept``: see
    :func:`stereojax.chain.run`; ``bands``: see :func:`stereojax.chain.initial`."""
    st = chain_mod.initial(left, right, valid, limits, variables, net, bands)
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
                     variables=None, net=None, confidence: bool = False, limits=None, bands=None) -> jax.Array:
    """:func:`disparity_grey` on a pair padded (right and bottom) to its size bucket.

    valid: ``i32[2]``, the real (rows, columns); it is an argument, not a static value, so every
    frame of one bucket runs the same compiled program. Crop the result to ``[:rows, :cols]``.
    confidence: also return the confidence map (:func:`stereojax.validation.confidence_measure.confidence`).
    limits: per-pixel disparity limits ``i32[2, H, W]`` (MIN <= d < MAX, chain disparities) or None.
    bands: (left, right) band offsets ``i32[H, W]`` instead of the coarse pass's, or None.
    """
    return chain_mod.result(_chain(left, right, config, variables, net, valid=valid, limits=limits, bands=bands),
                            confidence)


@functools.partial(jax.jit, static_argnames=("config", "net"))
def volume_padded(left, right, valid, config: StereoConfig, variables=None, net=None):
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
                 confidence: bool = False, limited: bool = False, cascade=None, given_bands: bool = False):
        """variables: the variables (or arrays of their shapes) the chain will be called with.
        confidence: the chain returns (disparity, confidence). limited: every call gives
        per-pixel disparity limits (:meth:`Predictor.__call__`'s ``pixel_range``). cascade: a
        :class:`~stereojax.matching_cost.cascade.CascadeSpec` (the full network where the
        student, ``net``, is unsure); ``variables`` are then (the student's, the full network's).
        given_bands: every call gives the band offsets (a banded config; no coarse pass)."""
        self.shape, self.config, self.net, self.device = shape, config, net, device
        self.confidence, self.limited, self.cascade, self.given_bands = confidence, limited, cascade, given_bands
        sharding = None if device is None else SingleDeviceSharding(device)

        def on_device(tree):
            return jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), tree)

        var_spec = None if variables is None else on_device(variables)
        full_spec = None
        if cascade is not None:
            var_spec, full_spec = var_spec
        spec = jax.ShapeDtypeStruct(shape, jnp.float32, sharding=sharding)
        valid = jax.ShapeDtypeStruct((2,), jnp.int32, sharding=sharding)
        lim = jax.ShapeDtypeStruct((2,) + tuple(shape), jnp.int32, sharding=sharding) if limited else None
        offs = None
        if given_bands:
            offs = (jax.ShapeDtypeStruct(shape, jnp.int32, sharding=sharding),) * 2
        self._two = chain_mod.two_programs(config, net)
        if cascade is not None and not self._two:
            raise ValueError("the cascade needs a pruned learned student (cost.candidates > 0)")
        if self._two:          # the method's two programs, the second fed the first's outputs
            self._first = chain_mod.first_program.lower(spec, spec, valid, config, var_spec, net, lim,
                                                        offs).compile()
            carry = on_device(jax.eval_shape(
                lambda a, b, v, w, m, o: chain_mod.first_program(a, b, v, config, w, net, m, o),
                spec, spec, valid, var_spec, lim, offs))
            if cascade is None:
                self._second = chain_mod.second_program.lower(carry, config, var_spec, confidence).compile()
            else:              # the student up to its confidence, then the mixed volume's chain
                self._student = chain_mod.cascade_student.lower(carry, config, var_spec).compile()
                vol, conf = on_device(jax.eval_shape(lambda c, w: chain_mod.cascade_student(c, config, w),
                                                     carry, var_spec))
                self._second = chain_mod.cascade_second.lower(carry, vol, conf, config, cascade, full_spec,
                                                              confidence).compile()
        else:
            self._compiled = disparity_padded.lower(spec, spec, valid, config, var_spec, net, confidence,
                                                    lim, offs).compile()

    def __call__(self, left: np.ndarray, right: np.ndarray, variables=None, limits=None, bands=None) -> np.ndarray:
        """Disparity ``f32[H, W]`` of a grey pair in the bucket; variables: the network's, on
        this chain's device (:class:`Predictor` puts them there once); limits: ``i32[2, H, W]``
        per-pixel disparity limits (MIN <= d < MAX, chain disparities), given exactly when the
        chain was compiled ``limited``; bands: (left, right) band offsets ``i32[H, W]``, given
        exactly when it was compiled ``given_bands``."""
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
        if (bands is not None) != self.given_bands:
            raise ValueError("band offsets must be given exactly when the chain was compiled for them")
        offs = None
        if bands is not None:      # padding: the last real column's and row's bands
            offs = jax.device_put(tuple(pad_to(np.asarray(b, np.int32), self.shape) for b in bands), self.device)
        if self.cascade is not None:
            student, full = variables
            carry = self._first(lp, rp, valid, student, lim, offs)
            out = self._second(carry, *self._student(carry, student), full)
        elif self._two:
            out = self._second(self._first(lp, rp, valid, variables, lim, offs), variables)
        else:
            out = self._compiled(lp, rp, valid, variables, lim, offs)
        if self.confidence:
            return np.asarray(out[0])[:h, :w], np.asarray(out[1])[:h, :w]
        return np.asarray(out)[:h, :w]


#: the compiled chains of this process, keyed on what a program depends on (bucket, config,
#: architecture, device, the shapes of the variables), never on weights; the most recently used
#: few per device are kept (a batch of mixed sizes would otherwise hoard programs)
_COMPILED: dict = {}
_COMPILED_LOCK = threading.Lock()
_KEEP_PER_DEVICE = 4


def is_kept(key) -> bool:
    """Whether the chain of a :class:`~stereojax.inference.predictor.Predictor` key is compiled and kept."""
    return key in _COMPILED


def default_device(device=None):
    """``device``, or the default device when None."""
    if device is not None:
        return device
    d = jax.config.jax_default_device
    if isinstance(d, str):
        return jax.devices(d)[0]
    return d or jax.devices()[0]


def variable_shapes(variables):
    if variables is None:
        return None
    leaves, tree = jax.tree_util.tree_flatten(variables)
    return tree, tuple((tuple(x.shape), str(x.dtype)) for x in leaves)


def compiled_chain(shape: tuple[int, int], config: StereoConfig, net=None, variables=None,
                   device=None, confidence: bool = False, limited: bool = False,
                   cascade=None, given_bands: bool = False) -> tuple[CompiledChain, bool]:
    """(the :class:`CompiledChain` of a bucket shape, config, architecture and device, whether it
    was compiled now); ``variables`` give the shapes only; ``cascade``: see :class:`CompiledChain`. Safe to call from the worker threads
    of :func:`stereojax.devices.map_frames`. Most callers want :class:`Predictor`.

    ``device`` None means the default device, named: a program compiled for it is the one a
    batch compiles for its first device, so both find one persistent-cache entry."""
    device = default_device(device)
    key = (tuple(shape), config, net, device, variable_shapes(variables), confidence, limited, cascade, given_bands)
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
            _COMPILED[key] = CompiledChain(tuple(shape), config, net, variables, device, confidence, limited,
                                           cascade, given_bands)
        else:   # the most recently used last
            _COMPILED[key] = _COMPILED.pop(key)
        return _COMPILED[key], fresh


@functools.partial(jax.jit, static_argnames=("config", "net"))
def stages_grey(left, right, config, variables=None, net=None):
    kept = {}
    _chain(left, right, config, variables, net, kept)
    return as_arrays(kept)


def as_arrays(out: dict) -> dict:
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
