"""Warnings that leave a trace: every warning shown while a frame is computed is also kept, per
thread, so that ``predict`` writes it into the frame's ``timings.json`` and ``frame.json`` and
counts it in a batch's ``summary.json`` (issue "No silent choices").

:func:`recording` installs one forwarding hook in front of :func:`warnings.showwarning` (the
warning is still shown as before) and collects the messages of the calling thread, so the frames
that :func:`stereojax.devices.map_frames` runs on several devices keep their own warnings.
:class:`~stereojax.errors.InputWarning` is shown every time it is raised, not once per place
in the code: in a batch every frame's warning counts.
"""

from __future__ import annotations

import threading
import warnings
from contextlib import contextmanager

from stereojax.errors import InputWarning

_LOCAL = threading.local()
_BASE: dict = {}


def _hook(message, category, filename, lineno, file=None, line=None):
    log = getattr(_LOCAL, "log", None)
    if log is not None:
        log.append(str(message))
    _BASE["show"](message, category, filename, lineno, file, line)


def _install() -> None:
    if warnings.showwarning is not _hook:
        _BASE["show"] = warnings.showwarning
        warnings.showwarning = _hook
    warnings.filterwarnings("always", category=InputWarning)


@contextmanager
def recording():
    """Collect (and still show) the warnings of this thread while the block runs; yields the
    list the messages go into."""
    _install()
    previous = getattr(_LOCAL, "log", None)
    _LOCAL.log = []
    try:
        yield _LOCAL.log
    finally:
        _LOCAL.log = previous
