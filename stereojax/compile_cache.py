"""JAX's persistent compilation cache for stereojax, and the size buckets that let frames of
nearly equal size share one compiled program.

Compiling the learned chain for a KITTI frame takes seconds to tens of seconds; with the
cache, a second process (``stereojax predict`` run again, a batch job, a notebook restarted)
reads the compiled program from disk instead. The folder is, in this order:
``enable(path)``'s argument, the environment variable ``STEREOJAX_CACHE_DIR`` (``off``
disables the cache), else ``$XDG_CACHE_HOME/stereojax/jax`` (``~/.cache/stereojax/jax``).
Nothing is read at import time; the CLI calls :func:`enable` once per process, and Python
users call it themselves.

Size buckets: :func:`bucket_shape` rounds a frame up to a multiple of
:data:`BUCKET_H` x :data:`BUCKET_W` pixels, so KITTI's 1242x375, 1241x376, 1238x374 and
1224x370 all run as 1248x384; the chain pads on the right and bottom and crops back exactly.
"""

from __future__ import annotations

import os
from pathlib import Path

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
    returns the folder, or None when disabled or the folder cannot be created (then every
    process compiles again, which is slower but correct)."""
    import jax

    folder = cache_dir(path)
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(folder, os.W_OK | os.X_OK):
        return None
    if _enabled.get("dir") != str(folder):
        jax.config.update("jax_compilation_cache_dir", str(folder))
        # cache every program of the chain, however quick to compile, and whatever its size
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        _enabled["dir"] = str(folder)
    return folder


def real_pixels(shape, valid):
    """``bool[H, W]``: the real pixels (rows < valid[0], columns < valid[1]) of a pair padded to
    its bucket, ``valid`` a traced ``i32[2]``; None when ``valid`` is None (nothing padded)."""
    import jax.numpy as jnp

    if valid is None:
        return None
    h, w = shape
    return (jnp.arange(h)[:, None] < valid[0]) & (jnp.arange(w)[None, :] < valid[1])


def bucket_shape(height: int, width: int, bucket_h: int = BUCKET_H, bucket_w: int = BUCKET_W) -> tuple[int, int]:
    """(H, W) rounded up to the size bucket: the shape the chain is compiled for."""
    return -(-height // bucket_h) * bucket_h, -(-width // bucket_w) * bucket_w
