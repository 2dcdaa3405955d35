"""The native CPU kernels: the one place that loads and registers them, and says which ran.

The classical stages (SGM, CBCA, the census cost, the right view's WTA, the
filling after the left-right check, the learned head's top-K candidate ranking, WTA, the confidence, the median filter, the
learned head at its candidates) each have two kernels: the JAX kernel in the
step's module (the reference, and the path on every platform other than the CPU) and a C++17
kernel beside it (``semi_global.cc``, ``cross_based.cc``, ``census.cc``, ``right_view.cc``,
``filling.cc``, ``ranking.cc``, ``winner_takes_all.cc``, ``confidence_measure.cc``, ``median.cc``, ``head.cc``), compiled into one
shared library ``stereojax/_native*.so`` by ``pip install`` (setup.py) and called from inside the
jitted chain as an XLA FFI custom call on the CPU. Each step's module offers one function that
picks its kernel (:func:`select`): with native kernels chosen and loaded, it is
``jax.lax.platform_dependent(cpu=native, default=jax)``, so a GPU still runs the JAX kernel.

Which kernels run is the config's ``kernels`` setting (``StereoConfig.kernels``, ``--kernels``):

* ``"auto"`` (default): native where the library loaded, else the JAX kernels (:func:`status`
  says why; the CLI prints it as its first line);
* ``"native"``: the native kernels, an error if the library did not load;
* ``"xla"``: the JAX kernels everywhere.

``STEREOJAX_NATIVE=0`` in the environment skips loading the library (the ``auto`` setting then
runs the JAX kernels, and says so); the test suite fails on a CPU where the library did not
load unless ``STEREOJAX_NATIVE_SKIP=1`` says that the build was skipped on purpose.
``STEREOJAX_THREADS`` sets the native kernels' threads (default: the CPU count).
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path
from typing import NamedTuple

import jax

from stereojax.errors import ConfigError

#: the values of ``StereoConfig.kernels``
CHOICES = ("auto", "native", "xla")

#: FFI target name -> exported symbol of the library
TARGETS = {
    "stereojax_sgm": "StereojaxSgm",
    "stereojax_cbca": "StereojaxCbca",
    "stereojax_census": "StereojaxCensus",
    "stereojax_right_wta": "StereojaxRightWta",
    "stereojax_fill": "StereojaxFill",
    "stereojax_rank": "StereojaxRank",
    "stereojax_copy": "StereojaxCopy",
    "stereojax_wta": "StereojaxWta",
    "stereojax_confidence": "StereojaxConfidence",
    "stereojax_median": "StereojaxMedian",
    "stereojax_head": "StereojaxHead",
    "stereojax_head_band": "StereojaxHeadBand",
}


class Status(NamedTuple):
    """Whether the native kernels loaded: ``loaded``, the library's ``path`` (or None) and the
    ``reason`` they did not load (None when they did)."""

    loaded: bool
    path: str | None
    reason: str | None


_STATUS: Status | None = None


def _library_path() -> Path | None:
    here = Path(__file__).resolve().parent
    found = sorted(here.glob("_native*.so")) + sorted(here.glob("_native*.pyd"))
    return found[0] if found else None


def load() -> Status:
    """Load the library and register its FFI targets for the CPU (once per process)."""
    global _STATUS
    if _STATUS is not None:
        return _STATUS
    if os.environ.get("STEREOJAX_NATIVE", "1") == "0":
        _STATUS = Status(False, None, "STEREOJAX_NATIVE=0 in the environment")
        return _STATUS
    path = _library_path()
    if path is None:
        _STATUS = Status(False, None, "the extension stereojax/_native*.so is not built "
                                      "(pip install -e . or make install builds it; it needs a C++17 compiler)")
        return _STATUS
    try:
        lib = ctypes.CDLL(str(path))
        for target, symbol in TARGETS.items():
            jax.ffi.register_ffi_target(target, jax.ffi.pycapsule(getattr(lib, symbol)), platform="cpu")
    except (OSError, AttributeError, RuntimeError, ValueError) as exc:
        _STATUS = Status(False, str(path), f"{path.name} failed to load: {exc}")
        return _STATUS
    _keep_freed_memory()
    _STATUS = Status(True, str(path), None)
    return _STATUS


def _keep_freed_memory() -> None:
    """Let glibc serve the chain's large buffers from its heap and keep them when freed
    (``mallopt``: mmap threshold 1 GiB, no trimming below 2 GiB), so that a warm run reuses pages
    instead of faulting in fresh ones: measured on a KITTI band volume (89 MB), a native copy
    took 42-69 ms with fresh pages and 9-10 ms with kept ones (``stereojax bench``'s memory
    floor). ``STEREOJAX_MALLOC=0`` leaves the allocator as it is."""
    if os.environ.get("STEREOJAX_MALLOC", "1") == "0":
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 1 << 30)          # M_MMAP_THRESHOLD
        libc.mallopt(-1, (1 << 31) - 1)    # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass                               # not glibc: nothing to tune


def status() -> Status:
    return load()


def check_choice(kernels: str) -> None:
    if kernels not in CHOICES:
        raise ConfigError(f"kernels must be one of {CHOICES}, got {kernels!r}")


def native(kernels: str = "auto") -> bool:
    """Whether the chain of a config with this ``kernels`` setting runs the native kernels on the
    CPU; ``"native"`` without a loaded library is an error."""
    check_choice(kernels)
    if kernels == "xla":
        return False
    st = load()
    if kernels == "native" and not st.loaded:
        raise ConfigError(f"--kernels native: the native kernels did not load ({st.reason})")
    return st.loaded


def describe(kernels: str = "auto") -> str:
    """What runs, in words: the first printed line of the CLI and the ``kernels`` entry of
    ``timings.json`` / ``frame.json``."""
    if native(kernels):
        return "native C++ kernels on the CPU (XLA FFI), JAX kernels elsewhere"
    if kernels == "xla":
        return "JAX (XLA) kernels (--kernels xla)"
    return f"JAX (XLA) kernels: the native kernels did not load ({load().reason})"


def record(kernels: str = "auto") -> dict:
    """The entry ``timings.json`` and ``frame.json`` keep: which kernels ran, and why."""
    use = native(kernels)
    return {"kernels": "native" if use else "xla", "setting": kernels,
            "reason": None if use or kernels == "xla" else load().reason}


def select(kernels: str, native_fn, xla_fn, *args):
    """``native_fn(*args)`` on the CPU when this ``kernels`` setting runs the native kernels,
    ``xla_fn(*args)`` otherwise and on every other platform (the one switch of the chain)."""
    if not native(kernels):
        return xla_fn(*args)
    return jax.lax.platform_dependent(*args, cpu=native_fn, default=xla_fn)


def copy_native(vol):
    """A copy of ``f32[H, W, K]`` by the native library on all threads (``volume.cc``): the
    memory-traffic floor of a kernel that reads one volume and writes one (``stereojax bench``)."""
    import jax.numpy as jnp
    import numpy as np

    call = jax.ffi.ffi_call("stereojax_copy", jax.ShapeDtypeStruct(vol.shape, jnp.float32))
    return call(vol, threads=np.int32(threads()))


def threads() -> int:
    """The native kernels' threads (``STEREOJAX_THREADS``, default: the CPUs this process may use)."""
    env = os.environ.get("STEREOJAX_THREADS")
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)
