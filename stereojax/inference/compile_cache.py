"""JAX's persistent compilation cache for stereojax, and the size buckets that let frames of
nearly equal size share one compiled program.

Compiling the learned chain for a KITTI frame takes seconds to tens of seconds; with the
cache, a second process (``stereojax predict`` run again, a batch job, a notebook restarted)
reads the compiled program from disk instead. The folder is, in this order:
``enable(path)``'s argument, the environment variable ``STEREOJAX_CACHE_DIR`` (``off``
disables the cache), else ``$XDG_CACHE_HOME/stereojax/jax`` (``~/.cache/stereojax/jax``).
Nothing is read at import time; the CLI calls :func:`enable` once per process, and so does
:class:`stereojax.inference.predictor.Predictor` (and :func:`stereojax.inference.predictor.disparity`) from Python.

Size buckets: :func:`bucket_shape` rounds a frame up to a multiple of
:data:`BUCKET_H` x :data:`BUCKET_W` pixels, so KITTI's 1242x375, 1241x376, 1238x374 and
1224x370 all run as 1248x384; the chain pads on the right and bottom and crops back exactly.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import jax

ENV_VAR = "STEREOJAX_CACHE_DIR"
#: rows and columns are padded up to multiples of these (see module docstring)
BUCKET_H = 16
BUCKET_W = 32

_enabled: dict = {}


def default_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "stereojax" / "jax"


def cache_dir(path=None) -> Path | None:
    """The cache folder that :func:`enable` would use, or None when disabled."""
    if path is not None:
        return Path(path)
    env = os.environ.get(ENV_VAR)
    if env is not None and env.strip() != "":
        if env.strip().lower() in ("off", "none", "0", "false"):
            return None
        return Path(env).expanduser()
    return default_dir()


def enable(path=None) -> Path | None:
    """Switch on JAX's persistent compilation cache in ``path`` (see module docstring);
    returns the folder, or None when disabled or the folder can be neither created nor read
    (then every process compiles again, which is slower but correct).

    A folder that can be read but not written (a cache shipped read-only in a cluster image) is
    read and never written, said once on stderr. A damaged entry (random bytes, or a write cut
    short by SIGKILL) is removed and written afresh once compiled (:class:`HealingCache`),
    instead of being read, warned about and compiled again by every later process."""


    folder = cache_dir(path)
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        if not folder.is_dir():
            return None
    if not os.access(folder, os.R_OK | os.X_OK):
        return None
    writable = _writable(folder)
    if _enabled.get("dir") != str(folder):
        _install(writable)
        jax.config.update("jax_compilation_cache_dir", str(folder))
        # cache every program of the chain, however quick to compile, and whatever its size
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        _enabled["dir"] = str(folder)
        if not writable:
            print(f"stereojax: the compile cache {folder} is read-only: reading it, writing nothing new",
                  file=sys.stderr)
    return folder


def ensure_enabled() -> Path | None:
    """:func:`enable` once per process, unless it was called already or the user set JAX's own
    ``jax_compilation_cache_dir`` (then theirs is kept); what Python entry points call, so that a
    script reuses compiled chains across runs as the CLI does (``STEREOJAX_CACHE_DIR=off``: no)."""

    if "tried" in _enabled:
        return Path(_enabled["dir"]) if "dir" in _enabled else None
    _enabled["tried"] = True
    if jax.config.jax_compilation_cache_dir:
        return None
    return enable()


def _writable(folder: Path) -> bool:
    """Whether a file can be created in ``folder`` (tried, not guessed from the permission bits:
    a read-only mount refuses even root)."""

    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".stereojax-probe-"):
            return True
    except OSError:
        return False


def _install(writable: bool) -> None:
    """Make JAX build its file cache as a :class:`HealingCache` (read-only when not ``writable``).
    JAX builds the cache once, on the first compile after the folder is set."""
    try:
        from jax._src import compilation_cache as cc
        from jax._src.lru_cache import LRUCache
    except ImportError:         # another JAX layout: its own cache, without healing
        return
    if not hasattr(cc, "get_file_cache"):
        return
    global HealingCache
    HealingCache = _healing_cache_class(LRUCache, cc)

    def get_file_cache(path):
        return HealingCache(path, max_size=-1, writable=writable), path

    cc.get_file_cache = get_file_cache
    if hasattr(cc, "reset_cache"):
        cc.reset_cache()


HealingCache = None


def _healing_cache_class(base, cc):
    """JAX's file cache with three changes: an entry that does not decompress is removed and
    reported as missing (so JAX compiles it and :meth:`put` writes it afresh); :meth:`put` writes
    to a temporary name and renames, so a killed write leaves no half entry, and it replaces an
    existing entry (JAX only writes after a miss or a failed read, so the old one was bad); and
    nothing is written when the folder is read-only."""

    class _HealingCache(base):
        def __init__(self, path, *, max_size: int, writable: bool = True):
            super().__init__(path, max_size=max_size)
            self.writable = writable

        def _entry(self, key: str) -> Path:
            return Path(self.path) / f"{key}-cache"

        def get(self, key: str):
            value = super().get(key)
            if value is None:
                return None
            try:
                cc.extract_executable_and_time(cc.decompress_executable(value))
            except Exception as exc:         # noqa: BLE001 -- any failure means the entry is unusable
                removed = ""
                if self.writable:
                    try:
                        self._entry(key).unlink()
                        removed = "removed; "
                    except OSError:
                        pass
                print(f"stereojax: a damaged compile-cache entry ({key[:40]}..., {type(exc).__name__}) was "
                      f"{removed}compiling it afresh", file=sys.stderr)
                return None
            return value

        def put(self, key: str, value: bytes) -> None:
            if not self.writable:
                return
            final = self._entry(key)
            tmp = final.with_name(f".{final.name}.tmp-{os.getpid()}")
            try:
                tmp.write_bytes(value)
                os.replace(tmp, final)
            except OSError:
                tmp.unlink(missing_ok=True)

    return _HealingCache


def bucket_shape(height: int, width: int, bucket_h: int = BUCKET_H, bucket_w: int = BUCKET_W) -> tuple[int, int]:
    """(H, W) rounded up to the size bucket: the shape the chain is compiled for."""
    return -(-height // bucket_h) * bucket_h, -(-width // bucket_w) * bucket_w
