"""Loaders for rectified stereo pairs with ground truth: KITTI 2012/2015, Middlebury, a built-in pair.

Every loader returns a :class:`StereoSample`. Ground-truth disparity is ``f32[H, W]`` with a
``bool[H, W]`` validity mask; the disparity is 0 wherever the mask is False (so the arrays are
always finite). The folder layouts are those of the official archives:

* KITTI 2015 ``training/``: ``image_2``/``image_3`` (``<frame>_10.png``), ``disp_noc_0``,
  ``disp_occ_0``, optional ``calib_cam_to_cam/<frame>.txt``.
* KITTI 2012 ``training/``: ``image_0``/``image_1`` (grey) or ``colored_0``/``colored_1``,
  ``disp_noc``, ``disp_occ``, optional ``calib/<frame>.txt``.
* Middlebury (MiddEval3 style) ``<root>/<scene>/``: ``im0.png``, ``im1.png``, ``disp0GT.pfm``,
  optional ``mask0nocc.png`` and ``calib.txt``.

A missing *ground-truth* file is not an error: ``gt`` is then None and the evaluation layer
decides what to do. Missing or unreadable *images* raise
:class:`~stereojax.errors.StereoInputError`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from stereojax.data import io
from stereojax.errors import ConfigError, StereoInputError, wxh

__all__ = [
    "Calibration", "StereoSample", "load_pair", "list_kitti2015", "load_kitti2015",
    "list_kitti2012", "load_kitti2012", "list_middlebury", "load_middlebury",
    "load_builtin_sample", "load_dataset", "ground_truth_of", "DatasetFrames", "DATASETS",
]

PathLike = str | os.PathLike
DATASETS = ("kitti2015", "kitti2012", "middlebury")


@dataclass(frozen=True)
class Calibration:
    """Rectified stereo calibration.

    Attributes:
        baseline: distance between the camera centres, metres (> 0).
        focal: focal length, pixels (> 0).
        doffs: x-difference of the principal points ``cx_right - cx_left`` in pixels
            (Middlebury's ``doffs``; 0 for KITTI). Depth is ``baseline * focal / (d + doffs)``.
        cx, cy: principal point of the left camera, pixels; None = image centre.
    """

    baseline: float
    focal: float
    doffs: float = 0.0
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self):
        for name in ("baseline", "focal"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) and v > 0):
                raise StereoInputError(f"calibration {name} must be a positive number, got {v!r}")
        if not math.isfinite(self.doffs):
            raise StereoInputError(f"calibration doffs must be finite, got {self.doffs!r}")

    @classmethod
    def from_options(cls, baseline: float | None, focal: float | None, doffs: float = 0.0) -> "Calibration | None":
        """The calibration of ``--baseline/--focal/--doffs`` (None when neither is given)."""

        if (baseline is None) != (focal is None):
            raise ConfigError("--baseline and --focal must be given together")
        if baseline is None:
            return None
        if baseline <= 0 or focal <= 0:
            raise ConfigError(f"--baseline and --focal must be > 0, got {baseline}, {focal}")
        return cls(baseline=baseline, focal=focal, doffs=doffs)


@dataclass
class StereoSample:
    """One rectified stereo pair, with ground truth when known.

    Attributes:
        name: frame id or scene name.
        left, right: ``u8[H, W, 3]`` RGB or ``u8[H, W]`` grey (``u16`` if stored so).
        gt: ``f32[H, W]`` left-view disparity in pixels, 0 where invalid; None if unknown.
        gt_valid: ``bool[H, W]`` pixels with ground truth; None if ``gt`` is None.
        gt_noc_valid: ``bool[H, W]`` pixels with non-occluded ground truth, when known.
        calib: :class:`Calibration`, when known.
        max_disp_hint: a suitable number of disparities to search, when known.
        gt_right: ``f32[H, W]`` right-view disparity (Middlebury ``disp1GT.pfm``; a right pixel
            x matches the left pixel x + d), 0 where invalid; None if unknown.
        gt_right_noc_valid: ``bool[H, W]`` right pixels with non-occluded ground truth, when known.
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray | None = None
    gt_valid: np.ndarray | None = None
    gt_noc_valid: np.ndarray | None = None
    calib: Calibration | None = None
    max_disp_hint: int | None = None
    gt_right: np.ndarray | None = None
    gt_right_noc_valid: np.ndarray | None = None

    def mirrored(self) -> "StereoSample":
        """The right view as a pair of its own: both images flipped left-right and swapped, so the
        flipped right image is the reference and a pixel x still matches x - d in the other image.
        Its ground truth is the flipped ``gt_right`` (all its finite pixels valid, the
        non-occluded ones in ``gt_noc_valid``). For training on both views' ground truth.

        Raises:
            StereoInputError: the sample has no right-view ground truth.
        """
        if self.gt_right is None:
            raise StereoInputError(f"{self.name}: no right-view ground truth (disp1GT.pfm) to mirror")

        def flip(a):
            return None if a is None else np.ascontiguousarray(a[:, ::-1])

        return StereoSample(name=f"{self.name}_rightview", left=flip(self.right), right=flip(self.left),
                            gt=flip(self.gt_right), gt_valid=flip(self.gt_right > 0),
                            gt_noc_valid=flip(self.gt_right_noc_valid), calib=None,
                            max_disp_hint=self.max_disp_hint, gt_right=flip(self.gt),
                            gt_right_noc_valid=flip(self.gt_noc_valid))

    def crop(self, rows: int, cols: int) -> "StereoSample":
        """The bottom-centre ``rows x cols`` crop (images and ground truth alike; the
        calibration is dropped, its principal point no longer fits)."""
        h, w = self.left.shape[:2]
        y0, x0 = max(h - rows, 0), max((w - cols) // 2, 0)
        sl = (slice(y0, y0 + rows), slice(x0, x0 + cols))

        def cut(a):
            return None if a is None else np.ascontiguousarray(a[sl])

        return dataclasses.replace(self, left=cut(self.left), right=cut(self.right), gt=cut(self.gt),
                                   gt_valid=cut(self.gt_valid), gt_noc_valid=cut(self.gt_noc_valid), calib=None,
                                   gt_right=cut(self.gt_right), gt_right_noc_valid=cut(self.gt_right_noc_valid))


#: a pixel whose two ground-truth maps disagree by more than this (px) is occluded in the other view
#: (the tolerance of Middlebury's own occlusion masks, Scharstein and Szeliski 2003)
LR_GT_TOLERANCE = 1.0


def lr_noc_mask(disp: np.ndarray, valid: np.ndarray, other: np.ndarray, sign: int = -1,
                tol: float = LR_GT_TOLERANCE) -> np.ndarray:
    """Non-occluded pixels of one view from a left-right check of the two ground-truth maps.

    A pixel x of the view with ``disp`` (valid where ``valid``) sees the pixel
    ``x + sign * disp`` of the other view (sign -1 for the left view, +1 for the right view); it
    is non-occluded when that pixel lies in the image, has ground truth (``other > 0``) and its
    disparity there, linearly interpolated, differs by at most ``tol`` px.
    Returns ``bool[H, W]``.
    """
    h, w = disp.shape
    xs = np.arange(w, dtype=np.float32)[None, :] + sign * disp
    inside = valid & (xs >= 0) & (xs <= w - 1)
    x0 = np.clip(np.floor(xs), 0, w - 1).astype(np.int64)
    x1 = np.minimum(x0 + 1, w - 1)
    f = np.clip(xs - x0, 0.0, 1.0)
    rows = np.arange(h)[:, None]
    o0, o1 = other[rows, x0], other[rows, x1]
    both = (o0 > 0) & (o1 > 0)
    seen = np.where(both, (1 - f) * o0 + f * o1, np.where(f < 0.5, o0, o1))
    return inside & (seen > 0) & (np.abs(seen - disp) <= tol)


# ---- helpers -----------------------------------------------------------------------------------

def _size(img: np.ndarray) -> str:
    return wxh(img.shape[:2])


def _check_pair(left: np.ndarray, right: np.ndarray) -> None:
    if left.shape[:2] != right.shape[:2]:
        raise StereoInputError(f"left is {_size(left)} but right is {_size(right)}; "
                               "a rectified pair has equal sizes")


def _check_gt(gt: np.ndarray, left: np.ndarray, path: Path) -> None:
    if gt.shape[:2] != left.shape[:2]:
        raise StereoInputError(f"ground truth {path} is {_size(gt)} but the image is {_size(left)}")


def _gt_arg(gt: str) -> str:
    if gt not in ("noc", "occ"):
        raise StereoInputError(f"gt must be 'noc' or 'occ', got {gt!r}")
    return gt


def _available(ids: list[str]) -> str:
    if not ids:
        return "none"
    shown = ", ".join(ids[:12])
    return shown + (f", ... ({len(ids)} in all)" if len(ids) > 12 else "")


def _unknown_frame(frame: str, root: Path, ids: list[str]) -> StereoInputError:
    return StereoInputError(f"unknown frame {frame!r} in {root}; available: {_available(ids)}")


def _no_kitti_frame(frame: str, root: Path, what: str, layout: str, lister) -> StereoInputError:
    """The error of a KITTI frame that is not in ``root``: a folder that does not exist, or that
    holds no pair at all, is said as such (not as an unknown frame with "available: none")."""
    if not root.is_dir():
        return StereoInputError(f"no such folder: {root} (expected a {what} training/ folder)")
    ids = lister(root)
    if not ids:
        return StereoInputError(f"no {what} pairs in {root}: expected {layout} with <frame>_10.png images")
    return _unknown_frame(frame, root, ids)


def _frame_id(frame) -> str:
    if isinstance(frame, (int, np.integer)):
        return f"{int(frame):06d}"
    frame = str(frame)
    return frame[:-3] if frame.endswith("_10") else frame


_FRAME_RE = re.compile(r"^(\d+)_10\.png$")


def _frames_in(folder: Path) -> set[str]:
    if not folder.is_dir():
        return set()
    return {m.group(1) for f in folder.iterdir() if (m := _FRAME_RE.match(f.name))}


def _read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError as exc:
        raise StereoInputError(f"cannot read {what} {path}: {exc.strerror or exc}") from None


def kitti_matrices(path: Path) -> dict[str, np.ndarray]:
    """``KEY: v1 v2 ...`` lines of a KITTI calibration file -> {KEY: float64[n]} (numeric only)."""
    out = {}
    for line in _read_text(path, "calibration file").splitlines():
        key, sep, rest = line.partition(":")
        if not sep:
            continue
        try:
            out[key.strip()] = np.array([float(v) for v in rest.split()], np.float64)
        except ValueError:
            continue  # e.g. "calib_time: 09-Jan-2012 13:57:47"
    return out


def calib_from_projections(path: Path, key_left: str, key_right: str) -> Calibration:
    mats = kitti_matrices(path)
    for k in (key_left, key_right):
        if k not in mats or mats[k].size != 12:
            found = "missing" if k not in mats else f"{mats[k].size} values"
            raise StereoInputError(f"calibration file {path}: expected {k} with 12 values (3x4 "
                                   f"projection matrix), found {found}")
    pl, pr = mats[key_left].reshape(3, 4), mats[key_right].reshape(3, 4)
    focal = float(pl[0, 0])
    if not focal > 0:
        raise StereoInputError(f"calibration file {path}: expected a positive focal length in "
                               f"{key_left}[0,0], found {focal}")
    # P = K [I | t] with t_x = -baseline for the right camera relative to the left one:
    # P[0, 3] = f * t_x, so baseline = (P_left[0,3] - P_right[0,3]) / f (about 0.54 m for KITTI)
    baseline = float((pl[0, 3] - pr[0, 3]) / focal)
    if not baseline > 0:
        raise StereoInputError(f"calibration file {path}: expected {key_right} to be right of "
                               f"{key_left} (positive baseline), found {baseline:.4f} m")
    return Calibration(baseline=baseline, focal=focal, doffs=float(pr[0, 2] - pl[0, 2]),
                       cx=float(pl[0, 2]), cy=float(pl[1, 2]))


def _read_kitti_gt(path: Path, left: np.ndarray):
    if not path.is_file():
        return None, None
    disp, valid = io.read_kitti_disparity(path)
    _check_gt(disp, left, path)
    return disp, valid


# ---- single pair -------------------------------------------------------------------------------

def load_pair(left_path: PathLike, right_path: PathLike) -> StereoSample:
    """Load a rectified pair without ground truth (name: the left file's stem).

    Raises:
        StereoInputError: an image cannot be read, or the two sizes differ
            ("left is 1242x375 but right is 1226x370; ...").
    """
    left, right = io.read_image(left_path), io.read_image(right_path)
    _check_pair(left, right)
    return StereoSample(name=Path(left_path).stem, left=left, right=right)


# ---- KITTI 2015 --------------------------------------------------------------------------------

def list_kitti2015(root: PathLike) -> list[str]:
    """Sorted frame ids (e.g. ``"000021"``) of ``root`` (a KITTI 2015 ``training`` folder) that
    have both ``image_2/<id>_10.png`` and ``image_3/<id>_10.png``."""
    root = Path(root)
    return sorted(_frames_in(root / "image_2") & _frames_in(root / "image_3"))


def load_kitti2015(root: PathLike, frame: str | int, gt: str = "noc") -> StereoSample:
    """Load KITTI 2015 frame ``frame`` (``"000021"``) from a ``training`` folder.

    ``gt="noc"`` reads ``disp_noc_0``, ``gt="occ"`` reads ``disp_occ_0`` (all pixels); when the
    file is missing ``gt`` is None. ``gt_noc_valid`` comes from ``disp_noc_0`` when present.
    Calibration (P_rect_02 / P_rect_03) is read from ``calib_cam_to_cam/<frame>.txt`` if present.

    Returns:
        StereoSample with ``left``/``right`` ``u8[375, 1242, 3]`` (for the usual frame size).
    Raises:
        StereoInputError: unknown frame, unreadable image or GT, mismatched sizes.
    """
    root, frame, gt = Path(root), _frame_id(frame), _gt_arg(gt)
    name = f"{frame}_10.png"
    if not ((root / "image_2" / name).is_file() and (root / "image_3" / name).is_file()):
        raise _no_kitti_frame(frame, root, "KITTI 2015", "image_2/ and image_3/", list_kitti2015)
    left, right, disp, valid, noc_valid = _kitti_views(root, ("image_2", "image_3"), ("disp_noc_0", "disp_occ_0"),
                                                       name, gt)
    calib_path = root / "calib_cam_to_cam" / f"{frame}.txt"
    calib = calib_from_projections(calib_path, "P_rect_02", "P_rect_03") if calib_path.is_file() else None
    return StereoSample(name=frame, left=left, right=right, gt=disp, gt_valid=valid,
                        gt_noc_valid=noc_valid, calib=calib)


def _kitti_views(root: Path, images: tuple[str, str], gts: tuple[str, str], name: str, gt: str):
    """(left, right, gt disparity, gt valid, noc valid) of a KITTI frame: the images from the
    folders ``images``, the ground truth from ``gts`` = (noc folder, occ folder)."""
    left, right = io.read_image(root / images[0] / name), io.read_image(root / images[1] / name)
    _check_pair(left, right)
    noc, noc_valid = _read_kitti_gt(root / gts[0] / name, left)
    disp, valid = (noc, noc_valid) if gt == "noc" else _read_kitti_gt(root / gts[1] / name, left)
    return left, right, disp, valid, noc_valid


# ---- KITTI 2012 --------------------------------------------------------------------------------

def _kitti2012_views(root: Path, frame: str) -> tuple[str, str] | None:
    name = f"{frame}_10.png"
    for a, b in (("image_0", "image_1"), ("colored_0", "colored_1")):
        if (root / a / name).is_file() and (root / b / name).is_file():
            return a, b
    return None


def list_kitti2012(root: PathLike) -> list[str]:
    """Sorted frame ids of a KITTI 2012 ``training`` folder having ``image_0``+``image_1`` or
    ``colored_0``+``colored_1`` images."""
    root = Path(root)
    grey = _frames_in(root / "image_0") & _frames_in(root / "image_1")
    colour = _frames_in(root / "colored_0") & _frames_in(root / "colored_1")
    return sorted(grey | colour)


def load_kitti2012(root: PathLike, frame: str | int, gt: str = "noc") -> StereoSample:
    """Load KITTI 2012 frame ``frame`` from a ``training`` folder.

    Images come from the grey ``image_0``/``image_1`` when present (``u8[H, W]``), else from
    ``colored_0``/``colored_1`` (``u8[H, W, 3]``). ``gt="noc"`` reads ``disp_noc``, ``"occ"``
    reads ``disp_occ``; a missing file gives ``gt=None``. Calibration from ``calib/<frame>.txt``:
    rows P0/P1 for the grey cameras, P2/P3 for the colour ones (P0/P1 if those are absent).

    Raises:
        StereoInputError: unknown frame, unreadable image or GT, mismatched sizes.
    """
    root, frame, gt = Path(root), _frame_id(frame), _gt_arg(gt)
    views = _kitti2012_views(root, frame)
    if views is None:
        raise _no_kitti_frame(frame, root, "KITTI 2012", "image_0/ and image_1/ (or colored_0/ and colored_1/)",
                              list_kitti2012)
    name = f"{frame}_10.png"
    left, right, disp, valid, noc_valid = _kitti_views(root, views, ("disp_noc", "disp_occ"), name, gt)
    calib = None
    calib_path = root / "calib" / f"{frame}.txt"
    if calib_path.is_file():
        keys = ("P0", "P1")
        if views[0] == "colored_0":
            mats = kitti_matrices(calib_path)
            if "P2" in mats and "P3" in mats:
                keys = ("P2", "P3")
        calib = calib_from_projections(calib_path, *keys)
    return StereoSample(name=frame, left=left, right=right, gt=disp, gt_valid=valid,
                        gt_noc_valid=noc_valid, calib=calib)


# ---- Middlebury --------------------------------------------------------------------------------

def list_middlebury(root: PathLike) -> list[str]:
    """Sorted names of the scene folders in ``root`` that hold ``im0.png`` and ``im1.png``."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(d.name for d in root.iterdir()
                  if d.is_dir() and (d / "im0.png").is_file() and (d / "im1.png").is_file())


def parse_middlebury_calib(path: Path) -> tuple[Calibration, int | None]:
    fields = {}
    for line in _read_text(path, "calibration file").splitlines():
        key, sep, value = line.partition("=")
        if sep:
            fields[key.strip()] = value.strip()

    def number(key, required=True):
        if key not in fields:
            if required:
                raise StereoInputError(f"calibration file {path}: expected a '{key}=' line, found none")
            return None
        try:
            return float(fields[key])
        except ValueError:
            raise StereoInputError(f"calibration file {path}: expected a number for {key}, "
                                   f"found {fields[key][:40]!r}") from None

    if "cam0" not in fields:
        raise StereoInputError(f"calibration file {path}: expected a 'cam0=[f 0 cx; 0 f cy; 0 0 1]' "
                               "line, found none")
    try:
        k = np.array([float(v) for v in fields["cam0"].strip("[] ").replace(";", " ").split()])
    except ValueError:
        k = np.zeros(0)
    if k.size != 9:
        raise StereoInputError(f"calibration file {path}: expected cam0 as a 3x3 matrix "
                               f"'[f 0 cx; 0 f cy; 0 0 1]', found {fields['cam0'][:60]!r}")
    baseline_mm = number("baseline")
    doffs = number("doffs", required=False) or 0.0
    ndisp = number("ndisp", required=False)
    calib = Calibration(baseline=baseline_mm / 1000.0, focal=float(k[0]), doffs=doffs,
                        cx=float(k[2]), cy=float(k[5]))
    return calib, (int(ndisp) if ndisp is not None and ndisp > 0 else None)


def load_middlebury(scene_dir: PathLike, gt: str = "occ") -> StereoSample:
    """Load a Middlebury scene folder (MiddEval3 layout).

    ``disp0GT.pfm`` gives the left ground truth (non-finite = invalid). ``mask0nocc.png``
    (255 = non-occluded) gives ``gt_noc_valid`` when present. ``gt="occ"`` (default) makes
    ``gt_valid`` every pixel with finite ground truth; ``gt="noc"`` restricts it to the
    non-occluded mask, and gives ``gt=None`` when the scene has no mask. ``disp1GT.pfm`` (right
    view, when present) gives ``gt_right`` and its non-occluded pixels; without ``mask0nocc.png``
    the left mask comes from a left-right check of the two maps (:func:`lr_noc_mask`, the 2005/2006
    scenes). ``calib.txt`` gives
    the calibration (baseline converted from mm to metres) and ``ndisp`` -> ``max_disp_hint``.

    Raises:
        StereoInputError: missing images, unreadable files, mismatched sizes, bad calib.txt.
    """
    scene = Path(scene_dir)
    gt = _gt_arg(gt)
    if not scene.is_dir():
        raise StereoInputError(f"Middlebury scene folder {scene} does not exist")
    if not ((scene / "im0.png").is_file() and (scene / "im1.png").is_file()):
        raise StereoInputError(f"Middlebury scene folder {scene}: expected im0.png and im1.png")
    left, right = io.read_image(scene / "im0.png"), io.read_image(scene / "im1.png")
    _check_pair(left, right)
    disp = valid = noc_valid = None
    if (scene / "disp0GT.pfm").is_file():
        raw = io.read_pfm(scene / "disp0GT.pfm")
        if raw.ndim != 2:
            raise StereoInputError(f"{scene / 'disp0GT.pfm'}: expected a single-channel (Pf) "
                                   f"disparity map, found shape {raw.shape}")
        _check_gt(raw, left, scene / "disp0GT.pfm")
        valid = np.isfinite(raw) & (raw > 0)
        disp = np.where(valid, raw, 0).astype(np.float32)
        if (scene / "mask0nocc.png").is_file():
            mask = io.read_image(scene / "mask0nocc.png")
            if mask.ndim == 3:
                mask = mask[:, :, 0]
            _check_gt(mask, left, scene / "mask0nocc.png")
            noc_valid = valid & (mask == mask.dtype.type(np.iinfo(mask.dtype).max))
    disp1 = noc1 = None
    if disp is not None and (scene / "disp1GT.pfm").is_file():
        raw1 = io.read_pfm(scene / "disp1GT.pfm")
        _check_gt(raw1, left, scene / "disp1GT.pfm")
        valid1 = np.isfinite(raw1) & (raw1 > 0)
        disp1 = np.where(valid1, raw1, 0).astype(np.float32)
        noc1 = lr_noc_mask(disp1, valid1, disp, sign=+1)
        if noc_valid is None:   # no mask0nocc.png: the left-right check of the two maps
            noc_valid = lr_noc_mask(disp, valid, disp1, sign=-1)
    if gt == "noc":
        if noc_valid is None:
            disp = valid = None
        else:
            valid = noc_valid
    calib, ndisp = (None, None)
    if (scene / "calib.txt").is_file():
        calib, ndisp = parse_middlebury_calib(scene / "calib.txt")
    return StereoSample(name=scene.name, left=left, right=right, gt=disp, gt_valid=valid,
                        gt_noc_valid=noc_valid, calib=calib, max_disp_hint=ndisp, gt_right=disp1,
                        gt_right_noc_valid=noc1)


# ---- built-in sample ---------------------------------------------------------------------------

#: Calibration of scikit-image's quarter-size Middlebury 2014 Motorcycle pair (from the
#: docstring of ``skimage.data.stereo_motorcycle``).
MOTORCYCLE_CALIB = Calibration(baseline=0.193001, focal=994.978, doffs=31.086, cx=311.193, cy=254.877)


def load_builtin_sample() -> StereoSample:
    """scikit-image's Middlebury 2014 Motorcycle pair (quarter size), with ground truth.

    Returns a StereoSample named ``"motorcycle"``: ``u8[500, 741, 3]`` images, ``f32[500, 741]``
    ground truth (7.2 to 59.9 px; its ``inf`` pixels, about 7 %, are invalid), the calibration
    that scikit-image documents and ``max_disp_hint=64`` (GT maximum + 1, rounded up to a
    multiple of 16).
    """
    try:
        from skimage import data as skdata

        left, right, raw = skdata.stereo_motorcycle()
    except Exception as exc:  # missing package or data file
        raise StereoInputError(f"the built-in Motorcycle sample needs scikit-image's data: {exc}") from None
    raw = np.asarray(raw, np.float32)
    valid = np.isfinite(raw) & (raw > 0)
    gt = np.where(valid, raw, 0).astype(np.float32)
    hint = int(math.ceil((math.ceil(float(gt[valid].max())) + 1) / 16) * 16) if valid.any() else None
    return StereoSample(name="motorcycle", left=np.ascontiguousarray(left), right=np.ascontiguousarray(right),
                        gt=gt, gt_valid=valid, gt_noc_valid=None, calib=MOTORCYCLE_CALIB,
                        max_disp_hint=hint)


# ---- whole data sets ---------------------------------------------------------------------------

#: disparities searched on KITTI (the largest KITTI 2015 GT disparity is about 230 px at full size)
#: where the experiments, `stereojax bench` and the Makefile look for the shared data sets
#: (KITTI 2015/2012, Middlebury) unless told otherwise with --data: beside the checkout
DEFAULT_DATA = "../shared/data"
KITTI_MAX_DISP = 228


def search_range(dataset: str, sample: StereoSample, requested: int | None = None) -> int:
    """Number of disparities to search for ``sample`` of ``dataset``: ``requested`` when given,
    228 on KITTI, else the sample's hint (Middlebury ``ndisp``), else 1.1 x its largest GT
    disparity, else a third of the image width (at most 228)."""
    if requested is not None:
        return int(requested)
    if dataset.startswith("kitti"):
        return KITTI_MAX_DISP
    if sample.max_disp_hint:
        return int(sample.max_disp_hint)
    if sample.gt is not None and sample.gt_valid is not None and sample.gt_valid.any():
        return int(np.ceil(sample.gt[sample.gt_valid].max() * 1.1)) + 1
    return min(KITTI_MAX_DISP, sample.left.shape[1] // 3)


_LAYOUT = {
    "kitti2015": ("image_2/ and image_3/", list_kitti2015),
    "kitti2012": ("image_0/ and image_1/ (or colored_0/ and colored_1/)", list_kitti2012),
    "middlebury": ("<scene>/im0.png and <scene>/im1.png", list_middlebury),
}


def _resolve_root(root: Path, dataset: str) -> tuple[Path, list[str]]:
    """Accept the data folder itself, its parent (``.../kitti2015``) or the shared data root."""
    subdirs = {"kitti2015": ["training"], "kitti2012": ["training"], "middlebury": []}[dataset]
    candidates = [root] + [root / s for s in subdirs] + [root / dataset] + [root / dataset / s for s in subdirs]
    lister = _LAYOUT[dataset][1]
    for c in candidates:
        ids = lister(c)
        if ids:
            return c, ids
    return root, []


#: where each data set keeps the non-occluded ground truth, in words (for the messages that name it)
NOC_SOURCE = {"kitti2015": "disp_noc_0/", "kitti2012": "disp_noc/",
              "middlebury": "mask0nocc.png, or disp1GT.pfm for a left-right check"}


def ground_truth_of(folder: PathLike, dataset: str, frame: str) -> str | None:
    """The ground truth a frame's files give, seen from their names only (nothing is read):
    ``"noc"`` when its non-occluded pixels are known (KITTI: ``disp_noc_0/`` or ``disp_noc/``;
    Middlebury: ``disp0GT.pfm`` with ``mask0nocc.png``, or with ``disp1GT.pfm``, whose left-right
    check gives the mask, :func:`load_middlebury`), ``"occ"`` when only all-pixel ground truth is
    there, None when there is none. ``folder`` holds the frames (a KITTI ``training`` folder, the
    folder of Middlebury scenes)."""
    folder = Path(folder)
    if dataset == "middlebury":
        scene = folder / frame
        if not (scene / "disp0GT.pfm").is_file():
            return None
        return "noc" if (scene / "mask0nocc.png").is_file() or (scene / "disp1GT.pfm").is_file() else "occ"
    noc, occ = ("disp_noc_0", "disp_occ_0") if dataset == "kitti2015" else ("disp_noc", "disp_occ")
    name = f"{_frame_id(frame)}_10.png"
    if (folder / noc / name).is_file():
        return "noc"
    return "occ" if (folder / occ / name).is_file() else None


class DatasetFrames(list):
    """What :func:`load_dataset` returns: a list of ``(frame id, loader)`` pairs, with ``gt_of``
    (``gt="auto"`` only, else None): frame id -> the ground truth its loader gives, ``"noc"``,
    ``"occ"`` (all pixels) or None (none), from :func:`ground_truth_of`."""

    def __init__(self, items=(), gt_of: dict | None = None):
        super().__init__(items)
        self.gt_of = gt_of


def load_dataset(root: PathLike, dataset: str, frames: list[str] | None = None,
                 gt: str = "noc") -> DatasetFrames:
    """List the frames of a data set as ``(frame id, loader)`` pairs; ``loader()`` reads the frame.

    ``dataset`` is ``"kitti2015"``, ``"kitti2012"`` or ``"middlebury"``. ``root`` may be the
    folder holding the frames (a KITTI ``training`` folder, the folder of Middlebury scenes),
    one level above it, or the shared data root (``.../data`` with ``kitti2015/training``
    inside). Frame ids are KITTI's ``"000021"`` or Middlebury scene names; ``frames=None``
    means all, in sorted order. ``gt`` is passed to the loader (Middlebury: ``"noc"`` restricts
    GT to the non-occluded mask and gives ``gt=None`` for scenes without one). ``gt="auto"``:
    per frame, the non-occluded ground truth where its files give it, else all pixels
    (:func:`ground_truth_of`, kept in the answer's ``gt_of``): each frame is read with the ``gt``
    its files give, so that ``gt_valid`` is what to score.

    Raises:
        StereoInputError: unknown dataset or gt, a root with no pairs (naming the subfolders
            looked for), or a frame id that is not there (listing the available ones).
    """
    if dataset not in _LAYOUT:
        raise StereoInputError(f"unknown dataset {dataset!r}; expected one of {', '.join(DATASETS)}")
    if gt not in ("noc", "occ", "auto"):
        raise StereoInputError(f"gt must be 'noc', 'occ' or 'auto', got {gt!r}")
    root = Path(root)
    if not root.is_dir():
        raise StereoInputError(f"{dataset} data folder {root} does not exist")
    folder, ids = _resolve_root(root, dataset)
    if not ids:
        raise StereoInputError(f"no {dataset} stereo pairs in {root}: looked for {_LAYOUT[dataset][0]} "
                               f"in it, in training/ and in {dataset}/")
    if frames is None:
        chosen = ids
    else:
        chosen = [_frame_id(f) if dataset != "middlebury" else str(f) for f in frames]
        missing = [f for f in chosen if f not in set(ids)]
        if missing:
            raise StereoInputError(f"unknown {dataset} frame(s) {', '.join(missing[:5])} in {folder}; "
                                   f"available: {_available(ids)}")

    gt_of = {f: ground_truth_of(folder, dataset, f) for f in chosen} if gt == "auto" else None

    def loader(frame: str) -> Callable[[], StereoSample]:
        g = (gt_of[frame] or "noc") if gt == "auto" else gt      # auto: noc where the files give it
        if dataset == "kitti2015":
            return lambda: load_kitti2015(folder, frame, gt=g)
        if dataset == "kitti2012":
            return lambda: load_kitti2012(folder, frame, gt=g)
        return lambda: load_middlebury(folder / frame, gt=g)

    return DatasetFrames([(f, loader(f)) for f in chosen], gt_of)


def parse_frames(spec: str | None):
    """'000021-000030' or '21-30' -> ids; comma lists allowed; None/'all' -> None (all frames)."""
    if spec is None or spec in ("", "all"):
        return None
    frames = []
    for part in spec.split(","):
        part = part.strip()
        if "-" in part:
            a, b = part.split("-", 1)
            if not (a.isdigit() and b.isdigit()) or int(b) < int(a):
                raise StereoInputError(f"bad frame range {part!r}; expected e.g. 000021-000030")
            width = max(len(a), 6)
            frames += [f"{i:0{width}d}" for i in range(int(a), int(b) + 1)]
        elif part:
            frames.append(f"{int(part):06d}" if part.isdigit() else part)
    return frames
