"""What a long command shows while it works: one line per phase on stdout (stderr stays for
warnings and errors), "what is being done ... how long it took"."""

from __future__ import annotations

import time


class Phases:
    """``start(what)`` prints "stereojax: what ..."; ``done()`` ends the line with the seconds
    it took and returns them; ``interrupted()`` ends a line left open by a phase that did not
    finish (Ctrl-C), so that the message after it starts on its own line. ``quiet=True`` only
    times."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self._open = False

    def start(self, what: str):
        self._t0, self._what = time.perf_counter(), what
        if not self.quiet:
            # open before the print: a Ctrl-C that lands right after it (the signal is handled at
            # the next bytecode) must still find the line open
            self._open = True
            print(f"stereojax: {what} ...", end="", flush=True)

    def done(self) -> float:
        secs = time.perf_counter() - self._t0
        if not self.quiet:
            print(f" {secs:.1f} s", flush=True)
            self._open = False
        return secs

    def interrupted(self) -> None:
        if self._open:
            print(" interrupted", flush=True)
            self._open = False
