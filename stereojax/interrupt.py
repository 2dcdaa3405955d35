"""Stopping a long command cleanly: SIGINT (Ctrl-C) and SIGTERM (a scheduler, ``kill``) raise
:class:`Interrupted` in the main thread, so that a batch can write what it has done and exit with
the conventional code (128 + the signal number: 130, 143)."""

from __future__ import annotations

import contextlib
import signal
import threading


class Interrupted(Exception):
    """A long command was asked to stop by a signal. ``exit_code``: 128 + the signal number."""

    def __init__(self, signum: int):
        self.signum = signum
        self.signal_name = signal.Signals(signum).name
        self.exit_code = 128 + signum
        self.summary: dict | None = None
        super().__init__(f"interrupted by {self.signal_name}")


@contextlib.contextmanager
def stop_on_signals(signals=(signal.SIGINT, signal.SIGTERM)):
    """Within the block, the signals raise :class:`Interrupted` (in the main thread; elsewhere
    this does nothing). The previous handlers come back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise Interrupted(signum)
    previous = {s: signal.signal(s, handler) for s in signals}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
