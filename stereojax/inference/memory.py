"""Memory guard: refuse a frame whose cost volumes would not fit, before building them.

The chain holds a few ``f32[H, W, D]`` volumes at once (cost, aggregated cost, the SGM
accumulator, XLA temporaries). Its peak is estimated as

    peak ≈ volumes × (H · W · D · 4 bytes) + fixed overhead (compilation, buffers)

with ``volumes`` calibrated by measuring the peak resident set size of a fresh process
(minus its size before the call) on a KITTI frame, 375×1242 with 228 disparities
(0.396 GiB per volume), with jax 0.10.2 on the CPU:

=======================================  ===========  ==============
chain                                    measured     volumes + 0.4 GiB
=======================================  ===========  ==============
census, ``disparity()``                  2.20 GiB     4.6
SAD, ``disparity()``                     2.44 GiB     5.2
census, ``stages()`` (keeps 4 volumes)   3.45 GiB     7.7
census, ``right_from_left=False``        4.07 GiB     9.3
=======================================  ===========  ==============

The factors below round these up (5.5 / +2.5 / +4 volumes, 0.5 GiB overhead), so the
estimate of the census chain on a KITTI frame is 2.7 GiB, as the README's ``make bench``
peak (2.74 GiB including the interpreter).

A banded chain (``band.width`` K > 0, :mod:`stereojax.matching_cost.coarse`) counts ``H · W · K`` instead
of ``H · W · D``, plus the coarse pass's ``(H/s) · (W/s) · (D/s)`` volumes. Measured against
it (2026-12-01, census, 48-wide bands, ``VOLUMES_BANDED``): the 6 MP pair (2982x2012, 282
disparities) peaks at 11.5 GiB (estimate 11.8 GiB); a KITTI frame at 1.68 GiB, of which about
0.6 GiB is compiling (estimate 1.3 GiB; 1.17 GiB measured with the chain from the cache).

The limit is, in this order: the ``limit_gb`` argument, the environment variable
``STEREOJAX_MEMORY_LIMIT_GB`` (GiB; ``off`` disables the guard), else
:data:`DEFAULT_SHARE` of the memory available now (``MemAvailable`` of ``/proc/meminfo``,
capped by a cgroup limit, else ``os.sysconf``). Everything is read at call time.
"""

from __future__ import annotations

import math
import os
import resource
from pathlib import Path

from stereojax.errors import ConfigError, MemoryBudgetError

GIB = 2 ** 30
#: f32[H, W, D] volumes alive at the peak of ``disparity()`` (census or SAD, learned alike).
VOLUMES = 5.5
#: extra volumes when ``stages()`` keeps every intermediate volume.
VOLUMES_STAGES = 2.5
#: extra volumes when the right view is aggregated on its own (``right_from_left=False``).
VOLUMES_RIGHT_CHAIN = 4.0
#: extra volumes of the learned chain (tower features, ranked candidates, the head's buffers):
#: measured 3.15 GiB peak RSS for ``preset("learned")`` on the KITTI frame (2.68 GiB estimated
#: without them, 3.08 GiB with them).
VOLUMES_LEARNED = 1.0
#: fixed overhead (compilation, images, small maps), bytes.
OVERHEAD = int(0.5 * GIB)
#: share of the available memory the chain may use when no limit is given.
DEFAULT_SHARE = 0.70
ENV_VAR = "STEREOJAX_MEMORY_LIMIT_GB"


def volumes(config, keep: bool = False) -> float:
    """Number of ``f32[H, W, D]`` volumes the chain of ``config`` holds at its peak."""
    n = VOLUMES
    if keep:
        n += VOLUMES_STAGES
    if config.refine.lr_check and not config.refine.right_from_left:
        n += VOLUMES_RIGHT_CHAIN
    if config.cost.method == "learned":
        n += VOLUMES_LEARNED
    return n


#: full ``f32[H, W, D]`` volumes a banded chain still builds: ``stages()`` returns its four
#: volumes at full size (for inspection); SAD is computed over the full range, then cut to bands.
FULL_VOLUMES_BANDED_STAGES = 4.0
#: f32[H, W, K] volumes alive at the peak of a banded chain (its SGM keeps one accumulator per
#: direction of travel): calibrated so that the estimate covers the measured peaks below
VOLUMES_BANDED = 6.5
FULL_VOLUMES_BANDED_SAD = 2.0


def chain_peak_bytes(height: int, width: int, config, keep: bool = False) -> int:
    """Estimated peak memory (bytes) of the chain on an ``height × width`` frame: its volumes
    count ``H · W · K`` (K the band width; D for the full-range chain), plus the coarse pass's
    ``(H / s) · (W / s) · (D / s)`` volumes of a banded chain."""
    if not config.banded:
        return int(volumes(config, keep) * height * width * config.max_disp * 4) + OVERHEAD
    k, s = config.band.width, config.band.scale
    band = (volumes(config, False) - VOLUMES + VOLUMES_BANDED) * height * width * k * 4
    coarse = VOLUMES * -(-height // s) * -(-width // s) * -(-config.max_disp // s) * 4
    full = (FULL_VOLUMES_BANDED_STAGES if keep else 0.0) + \
        (FULL_VOLUMES_BANDED_SAD if config.cost.method == "sad" else 0.0)
    return int(band + coarse + full * height * width * config.max_disp * 4) + OVERHEAD


def _proc_bytes(path: str, key: str) -> int | None:
    """The ``key:`` line of a /proc status file (``NNN kB``) in bytes, None if unreadable."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _meminfo_available() -> int | None:
    return _proc_bytes("/proc/meminfo", "MemAvailable")


def _cgroup_available() -> int | None:
    """Room left under a cgroup v2 memory limit (containers), or None without a limit."""
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
        return max(int(limit) - used, 0)
    except (OSError, ValueError):
        return None


def _sysconf_available() -> int | None:
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def current_rss_bytes() -> int:
    """Resident set size of this process now (0 where /proc is not available)."""
    try:
        return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def peak_rss_bytes() -> int:
    """This process's peak resident set size: VmHWM of /proc/self/status (the high-water mark of
    this program's own memory; ``ru_maxrss`` of a child would also count what its parent held
    when it forked), else ``ru_maxrss``."""
    hwm = _proc_bytes("/proc/self/status", "VmHWM")
    if hwm is not None:
        return hwm

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def available_bytes() -> int | None:
    """Memory available to this process now (bytes), or None when it cannot be read."""
    found = [b for b in (_meminfo_available(), _cgroup_available()) if b is not None]
    if not found:
        b = _sysconf_available()
        found = [b] if b is not None else []
    return min(found) if found else None


def _parse_limit(value, source: str) -> float:
    """A limit in GiB from an argument or the environment; inf means no limit."""
    if isinstance(value, str):
        text = value.strip().lower()
        if text in ("off", "none", "inf", "unlimited"):
            return math.inf
        try:
            value = float(text)
        except ValueError:
            raise ConfigError(f"{source} must be a positive number of GiB or 'off', got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value) or value <= 0:
        raise ConfigError(f"{source} must be a positive number of GiB or 'off', got {value!r}")
    return float(value)


def memory_limit(limit_gb=None) -> tuple[float, str]:
    """(limit in bytes, where it comes from); the limit is ``inf`` when the guard is off or
    the available memory cannot be read."""
    if limit_gb is not None:
        gib = _parse_limit(limit_gb, "memory_limit_gb")
        return gib * GIB, f"memory_limit_gb={limit_gb}"
    env = os.environ.get(ENV_VAR)
    if env not in (None, ""):
        gib = _parse_limit(env, ENV_VAR)
        return gib * GIB, f"{ENV_VAR}={env}"
    avail = available_bytes()
    if avail is None:
        return math.inf, "available memory unknown"
    return DEFAULT_SHARE * avail, f"{DEFAULT_SHARE:.0%} of the {avail / GIB:.1f} GiB available"


def check_memory(height: int, width: int, config, limit_gb=None, keep: bool = False) -> int:
    """Raise :class:`MemoryBudgetError` when the chain's estimated peak exceeds the limit;
    return the estimate (bytes) otherwise."""
    need = chain_peak_bytes(height, width, config, keep)
    limit, source = memory_limit(limit_gb)
    if need <= limit:
        return need
    per_disp = volumes(config, keep) * height * width * 4
    if config.banded:
        raise MemoryBudgetError(
            f"a {width}x{height} frame with {config.max_disp} disparities in bands of {config.band.width} "
            f"needs about {need / GIB:.1f} GiB, more than the limit of {limit / GIB:.1f} GiB ({source}); "
            f"use narrower bands (band.width), downscale the pair, or set {ENV_VAR} to raise the limit")
    fit_disp = int((limit - OVERHEAD) // per_disp) if limit > OVERHEAD else 0
    # downscale factor s (both axes) so that the volumes fit with D / s disparities
    scale = 2
    while scale < 64 and (volumes(config, keep) * -(-height // scale) * -(-width // scale)
                          * -(-config.max_disp // scale) * 4 + OVERHEAD) > limit:
        scale *= 2
    what = "stages()" if keep else f"{config.cost.method} chain"
    hint = (f"use a smaller maximum disparity (--max-disp / max_disp; at most {fit_disp} fits)" if fit_disp >= 1
            else "no disparity range fits at this size")
    raise MemoryBudgetError(
        f"a {width}x{height} frame with {config.max_disp} disparities needs about "
        f"{need / GIB:.1f} GiB for the {what} ({volumes(config, keep):g} f32[H, W, D] volumes of "
        f"{height * width * config.max_disp * 4 / GIB:.2f} GiB), more than the limit of "
        f"{limit / GIB:.1f} GiB ({source}); {hint}, or downscale the pair by {scale} "
        f"(and the disparities with it), or set {ENV_VAR} to raise the limit")

