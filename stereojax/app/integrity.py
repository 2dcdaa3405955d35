"""What a finished output holds, recorded so that a resumed run can tell a complete file from a
damaged one: each file's size and SHA-256 digest, as rsync, git and restic check what they skip.

A record's ``files`` maps a file name (relative to its folder) to ``{"size", "sha256"}``. On
resume the sizes are compared (a stat per file, cheap); with ``verify`` the digests are read
again too. Anything that fails is computed again, and the caller says which file failed.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

_CHUNK = 1 << 20


def digest(path) -> str:
    """The SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def file_entries(folder: Path, names) -> dict:
    """``{name: {"size", "sha256"}}`` of the files ``names`` in ``folder``."""
    folder = Path(folder)
    return {n: {"size": (folder / n).stat().st_size, "sha256": digest(folder / n)} for n in names}


def damaged(folder: Path, files, verify: bool = False) -> str | None:
    """None when every recorded file is there with its recorded size (and, with ``verify``, its
    recorded digest), else one phrase naming the first file that is not."""
    folder = Path(folder)
    if not isinstance(files, dict) or not files:
        return "no file sizes and digests recorded"
    for name, want in files.items():
        path = folder / name
        try:
            size = path.stat().st_size
        except OSError:
            return f"{name} is missing"
        if not isinstance(want, dict) or size != want.get("size"):
            return f"{name} is {size} bytes, recorded {want.get('size') if isinstance(want, dict) else '?'}"
        if verify and digest(path) != want.get("sha256"):
            return f"{name} does not match its recorded SHA-256"
    return None
