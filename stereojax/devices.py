"""Frames spread over the local devices (issue "scale out"): ``evaluate`` and batch ``predict``
run one frame per device at a time, each device with its own compiled chain.

A frame's disparity does not depend on which device computed it (the same program runs on
every device), so N devices give the numbers of one device, only sooner when the devices are
real (several GPUs). On the CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` makes N
host devices that share the same cores: that checks correctness, not speed.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import jax

from stereojax.errors import ConfigError

T = TypeVar("T")
R = TypeVar("R")


def count(devices: int | None, have: list) -> int:
    """The number of devices to use: ``devices`` checked against the ``have`` list (None: all)."""
    n = len(have) if devices is None else devices
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ConfigError(f"--devices must be a positive integer, got {devices!r}")
    if n > len(have):
        raise ConfigError(f"--devices {n} asks for more devices than the {len(have)} "
                          f"{jax.default_backend()} device(s) there are")
    return n


def local_devices(devices: int | None = None) -> list:
    """The first ``devices`` devices of this process (None: every local device)."""
    have = jax.local_devices()
    return have[:count(devices, have)]


_LOCAL = threading.local()


def current_device():
    """The device of the calling :func:`map_frames` worker, or None outside one (the default
    device)."""
    return getattr(_LOCAL, "device", None)


def map_frames(work: Callable[[T], R], items: Iterable[T], devices: list | None = None) -> Iterator[R]:
    """``work(item)`` for every item, in order, with one worker thread per device; inside
    ``work``, :func:`current_device` names the worker's device (pass it to
    :class:`stereojax.inference.predictor.Predictor`). With one device (or none given) the items run
    one after the other in the calling thread. At most one frame per device is in flight plus
    one waiting, so memory grows with the device count, not with the number of items.

    ``work`` should catch the errors that concern one item (a bad pair) and return them; an
    exception that escapes stops the map and is raised here.
    """
    devices = list(devices or [])
    if len(devices) <= 1:
        if devices:
            _LOCAL.device = devices[0]
        try:
            for item in items:
                yield work(item)
        finally:
            _LOCAL.device = None
        return
    free: queue.Queue = queue.Queue()
    for d in devices:
        free.put(d)

    def bind():
        _LOCAL.device = free.get()

    it = iter(items)
    with ThreadPoolExecutor(max_workers=len(devices), initializer=bind,
                            thread_name_prefix="stereojax-device") as pool:
        pending: list[Any] = []
        try:
            for item in it:
                pending.append(pool.submit(work, item))
                if len(pending) > len(devices):
                    yield pending.pop(0).result()
            while pending:
                yield pending.pop(0).result()
        finally:
            for f in pending:
                f.cancel()
