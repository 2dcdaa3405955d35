"""Stereo pairs on disk: two folders matched by file name, a KITTI ``training/`` or ``testing/``
folder, or a text list of pairs; what ``stereojax predict`` takes as its inputs."""

from __future__ import annotations

import shlex
from pathlib import Path

from stereojax.errors import StereoInputError

IMAGE_EXT = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")
# KITTI folder layouts, first match wins: (left view, right view, file pattern)
KITTI_VIEWS = (("image_2", "image_3"), ("image_0", "image_1"), ("colored_0", "colored_1"))


def images(folder: Path) -> dict[str, Path]:
    return {p.name: p for p in sorted(folder.iterdir())
            if p.is_file() and p.suffix.lower() in IMAGE_EXT}


class Pairs(list):
    """A list of ``(name, left, right)`` pairs, with ``unmatched``: the images of two folders
    that had no file of the same name in the other folder (``"left/NAME"`` or ``"right/NAME"``,
    sorted), which are not computed and are reported (:func:`unmatched_line`)."""

    def __init__(self, pairs=(), unmatched=()):
        super().__init__(pairs)
        self.unmatched = list(unmatched)


def unmatched_line(unmatched, shown: int = 5) -> str | None:
    """One line about the images without a partner, or None when there are none."""
    if not unmatched:
        return None
    n_left = sum(u.startswith("left/") for u in unmatched)
    first = ", ".join(unmatched[:shown]) + (f" and {len(unmatched) - shown} more" if len(unmatched) > shown else "")
    return (f"{len(unmatched)} image(s) without a partner of the same name ({n_left} left, "
            f"{len(unmatched) - n_left} right), not computed: {first}")


def folder_pairs(left_dir: Path, right_dir: Path) -> Pairs:
    """Pairs of two folders, matched by file name; the names without a partner are in
    ``unmatched`` (:class:`Pairs`)."""
    left, right = images(left_dir), images(right_dir)
    common = sorted(set(left) & set(right))
    if not common:
        raise StereoInputError(f"no image in {left_dir} has a file of the same name in {right_dir} "
                               f"({len(left)} and {len(right)} images)")
    unmatched = sorted([f"left/{n}" for n in set(left) - set(right)] + [f"right/{n}" for n in set(right) - set(left)])
    return Pairs([(Path(n).stem, left[n], right[n]) for n in common], unmatched)


def kitti_pairs(folder: Path) -> Pairs:
    """Pairs of a KITTI ``training/`` or ``testing/`` folder (image_2/3, image_0/1 or colored_0/1),
    or of a folder of Middlebury scenes (``SCENE/im0.png`` + ``SCENE/im1.png``, named by scene)."""
    for lv, rv in KITTI_VIEWS:
        if (folder / lv).is_dir() and (folder / rv).is_dir():
            return folder_pairs(folder / lv, folder / rv)
    scenes = sorted(d for d in folder.iterdir() if d.is_dir() and (d / "im0.png").is_file()
                    and (d / "im1.png").is_file()) if folder.is_dir() else []
    if scenes:
        return Pairs([(d.name, d / "im0.png", d / "im1.png") for d in scenes])
    raise StereoInputError(f"{folder} is not a KITTI training/ or testing/ folder (none of "
                           + ", ".join(f"{a}/ + {b}/" for a, b in KITTI_VIEWS) + " inside) nor a folder of "
                           "Middlebury scenes (SCENE/im0.png + SCENE/im1.png)")


def _split_line(line: str) -> list[str]:
    """The paths of one pair-list line: two tab-separated fields (spaces kept as they are), or
    two fields as a shell splits them (quotes and backslash escapes; ValueError if unbalanced)."""
    if "\t" in line:
        fields = [f.strip() for f in line.split("\t") if f.strip()]
        if len(fields) == 2:
            return fields
    return shlex.split(line, comments=False, posix=True)


def name_pairs(found) -> list[tuple[str, Path, Path]]:
    """``(name, left, right)`` for ``(left, right)`` paths: the left file's stem, or, where that
    stem repeats (Middlebury's ``SCENE/im0.png``), its folder's name; a name that still repeats
    gets ``_2``, ``_3``, ..."""
    stems: dict = {}
    for left, _ in found:
        stems[left.stem] = stems.get(left.stem, 0) + 1
    out, seen = [], {}
    for left, right in found:
        name = left.stem if stems[left.stem] == 1 or not left.parent.name else left.parent.name
        seen[name] = seen.get(name, 0) + 1
        out.append((name if seen[name] == 1 else f"{name}_{seen[name]}", left, right))
    return out


def list_pairs(path: Path) -> list[tuple[str, Path, Path]]:
    """Pairs of a text file (UTF-8), one ``LEFT RIGHT`` pair per line.

    A path with spaces is quoted as a shell would quote it (``"my left.png" 'my right.png'`` or
    ``my\\ left.png``), or the two paths are separated by a tab. Relative paths are relative to
    the list file's folder. Blank lines and lines starting with ``#`` are skipped. A malformed
    line is refused before anything runs, with its line number. Frames are named by
    :func:`name_pairs` (the left file's stem, or its folder where stems repeat)."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise StereoInputError(f"cannot read the pair list {path}: {exc}") from None
    found = []
    for n, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            parts = _split_line(line)
        except ValueError as exc:         # e.g. "No closing quotation"
            raise StereoInputError(f"{path}, line {n}: {exc} in {line!r}") from None
        if len(parts) != 2:
            raise StereoInputError(f"{path}, line {n}: expected 'LEFT RIGHT' (quote paths with spaces, "
                                   f"or separate the two by a tab), got {len(parts)} field(s) in {line!r}")
        left, right = (Path(p) if Path(p).is_absolute() else path.parent / p for p in parts)
        found.append((left, right))
    pairs = name_pairs(found)
    if not pairs:
        raise StereoInputError(f"the pair list {path} holds no pairs")
    return pairs


def find_pairs(inputs, pairs_file=None) -> tuple[list[tuple[str, Path, Path]], bool]:
    """(pairs as (name, left, right), whether it is a batch) from what ``stereojax predict`` is
    given: two images, two folders (matched by file name), a KITTI ``training/`` or ``testing/``
    folder, or a pair list (``pairs_file``, or one text file among the inputs)."""
    inputs = [Path(p) for p in inputs]
    if pairs_file:
        if inputs:
            raise StereoInputError("give either --pairs FILE or input paths, not both")
        return list_pairs(Path(pairs_file)), True
    if len(inputs) == 2 and inputs[0].is_dir() and inputs[1].is_dir():
        return folder_pairs(*inputs), True
    if len(inputs) == 2:
        return [("", inputs[0], inputs[1])], False
    if len(inputs) == 1 and inputs[0].is_dir():
        return kitti_pairs(inputs[0]), True
    if len(inputs) == 1 and inputs[0].is_file():
        return list_pairs(inputs[0]), True
    if len(inputs) == 1:
        raise StereoInputError(f"{inputs[0]} does not exist")
    raise StereoInputError("predict takes LEFT RIGHT (two images or two folders), a KITTI "
                           "training/ or testing/ folder, or --pairs FILE")
