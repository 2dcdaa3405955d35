"""Calibration files for depth: what ``stereojax predict --calib FILE`` reads.

* KITTI raw ``calib_cam_to_cam.txt`` (``P_rect_02`` / ``P_rect_03``, the colour cameras);
* KITTI 2012/2015 per-frame ``calib/<frame>.txt`` (``P2``/``P3``, else ``P0``/``P1``);
* Middlebury ``calib.txt`` (``cam0``, ``cam1``, ``doffs``, ``baseline`` in mm);
* OpenCV YAML (``cv2.FileStorage``) or JSON with ``K`` (3x3 camera matrix of the rectified left
  camera, pixels) and ``baseline`` (metres), optionally ``doffs`` (pixels).

Every format gives a :class:`~stereojax.data.datasets.Calibration` in metres and pixels; depth is
then ``Z = baseline * focal / (d + doffs)`` in metres.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import cv2
import numpy as np

from stereojax.data.datasets import (Calibration, calib_from_projections, kitti_matrices,
                                     parse_middlebury_calib)
from stereojax.errors import ConfigError, InputWarning, StereoInputError

#: a baseline longer than this many metres is almost surely millimetres given as metres
MAX_PLAUSIBLE_BASELINE_M = 5.0
#: median depths outside this range (metres) suggest a calibration in the wrong units
PLAUSIBLE_DEPTH_M = (0.1, 1000.0)


def read_calibration(path) -> tuple[Calibration, str]:
    """(calibration, the format's name) of a calibration file, told apart by its content.

    Raises:
        StereoInputError: unreadable file, unknown format, or missing/invalid entries (one
            line naming the file and what was expected).
    """
    path = Path(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise StereoInputError(f"cannot read the calibration file {path}: {exc.strerror}") from None
    if "cam0" in text and "=" in text:
        return parse_middlebury_calib(path)[0], "Middlebury calib.txt (baseline in mm)"
    if "P_rect_02" in text:
        return calib_from_projections(path, "P_rect_02", "P_rect_03"), "KITTI calib_cam_to_cam.txt (P_rect_02/03)"
    if path.suffix.lower() in (".yaml", ".yml") or text.lstrip().startswith("%YAML"):
        return _from_opencv_yaml(path), "OpenCV YAML (K, baseline in m)"
    if text.lstrip().startswith("{"):
        return _from_json(path, text), "JSON (K, baseline in m)"
    mats = kitti_matrices(path)
    for left, right in (("P2", "P3"), ("P0", "P1")):
        if left in mats and right in mats:
            return calib_from_projections(path, left, right), f"KITTI calib/<frame>.txt ({left}/{right})"
    raise StereoInputError(f"calibration file {path}: not a format stereojax reads (KITTI calib_cam_to_cam.txt or "
                           "calib/<frame>.txt, Middlebury calib.txt, OpenCV YAML or JSON with K and baseline)")


def _from_k(path: Path, k, baseline, doffs=0.0) -> Calibration:
    k = np.asarray(k, np.float64)
    if k.shape != (3, 3):
        raise StereoInputError(f"calibration file {path}: expected K as a 3x3 matrix, found shape {k.shape}")
    if baseline is None:
        raise StereoInputError(f"calibration file {path}: expected a 'baseline' (metres), found none")
    try:
        return Calibration(baseline=float(baseline), focal=float(k[0, 0]), doffs=float(doffs or 0.0),
                           cx=float(k[0, 2]), cy=float(k[1, 2]))
    except StereoInputError as exc:
        raise StereoInputError(f"calibration file {path}: {exc}") from None


def _from_json(path: Path, text: str) -> Calibration:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StereoInputError(f"calibration file {path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or "K" not in data:
        raise StereoInputError(f"calibration file {path}: expected a JSON object with 'K' and 'baseline'")
    return _from_k(path, data["K"], data.get("baseline"), data.get("doffs", 0.0))


def _from_opencv_yaml(path: Path) -> Calibration:

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        if not fs.isOpened():
            raise StereoInputError(f"calibration file {path}: OpenCV cannot read it as YAML")
        node = fs.getNode("K")
        k = node.mat() if not node.empty() else None
        if k is None:
            raise StereoInputError(f"calibration file {path}: expected a 'K' matrix, found none")
        b = fs.getNode("baseline")
        d = fs.getNode("doffs")
        return _from_k(path, k, None if b.empty() else b.real(), 0.0 if d.empty() else d.real())
    finally:
        fs.release()


def calibration_from_options(calib_file=None, baseline: float | None = None, focal: float | None = None,
                             doffs: float = 0.0) -> tuple[Calibration | None, str]:
    """(calibration, where it came from) of ``--calib FILE`` or ``--baseline/--focal/--doffs``
    (None: no depth). An implausible baseline gives an :class:`~stereojax.errors.InputWarning`."""


    if calib_file is None:
        calib, source = Calibration.from_options(baseline, focal, doffs), "--baseline/--focal"
    elif baseline is not None or focal is not None:
        raise ConfigError("give either --calib or --baseline/--focal, not both")
    else:
        calib, source = read_calibration(calib_file)
    for line in plausibility_warnings(calib) if calib is not None else []:
        warnings.warn(line, InputWarning, stacklevel=2)
    return calib, source


def rectified_or_raw(calib_file, rectify: bool):
    """What ``--calib FILE`` (or ``LEFT.yaml,RIGHT.yaml``) holds, checked against ``--rectify``:
    (a :class:`~stereojax.data.stereo_rig.Rectifier` with ``--rectify``, else None; the format's name).
    A raw stereo calibration (two cameras with distortion, R and T) needs ``--rectify``, and
    ``--rectify`` needs one: either mismatch is a one-line :class:`StereoInputError`."""
    from stereojax.data.stereo_rig import Rectifier, read_rig

    rig, source = read_rig(str(calib_file))
    if rig is not None and not rectify:
        raise StereoInputError(f"{calib_file} is a raw stereo calibration ({source}): add --rectify to rectify "
                               "each pair with it before matching")
    if rig is None and rectify:
        raise StereoInputError(f"--rectify needs a raw stereo calibration (K1, D1, K2, D2, R, T; Kalibr camchain; "
                               f"two ROS camera_info files); {calib_file} is not one (a rectified pair's calibration "
                               "is given without --rectify)")
    return (Rectifier(rig) if rig is not None else None), source


def describe(calib: Calibration, source: str) -> str:
    """One line with the calibration and the units of the depth it gives."""
    return (f"depth in metres from {source}: baseline {calib.baseline:.4g} m, focal {calib.focal:.5g} px, "
            f"doffs {calib.doffs:.4g} px")


def plausibility_warnings(calib: Calibration | None = None, depth: np.ndarray | None = None) -> list[str]:
    """One line per sign of a calibration in the wrong units: a baseline over 5 m (millimetres
    given as metres?) when ``calib`` is given, a median depth outside 0.1-1000 m when ``depth``
    is given."""
    out = []
    if calib is not None and calib.baseline > MAX_PLAUSIBLE_BASELINE_M:
        out.append(f"baseline {calib.baseline:.4g} m is implausibly long; was it given in millimetres? "
                   f"(in metres: {calib.baseline / 1000:.4g})")
    if depth is not None:
        z = np.asarray(depth)[np.asarray(depth) > 0]
        if z.size:
            med = float(np.median(z))
            lo, hi = PLAUSIBLE_DEPTH_M
            if not lo <= med <= hi:
                out.append(f"median depth {med:.4g} m is outside {lo:g}-{hi:g} m; check the units of the "
                           "baseline (metres) and the focal length (pixels)")
    return out
