"""A raw (not rectified) stereo camera pair: its calibration, and the rectification that turns
its images into the rectified pairs the matcher takes.

* :func:`calibrate` finds a chessboard in pairs of views (OpenCV ``findChessboardCorners``,
  ``cornerSubPix``) and runs ``stereoCalibrate``: a :class:`StereoRig` (K1, D1, K2, D2, R, T,
  the image size and the RMS reprojection error), written by :func:`write_rig`.
* :func:`read_rig` reads a raw stereo calibration: the file :func:`write_rig` writes; OpenCV's
  own ``stereoCalibrate`` output in YAML, XML or JSON (M1/K1, D1, M2/K2, D2, R, T); a pair of ROS
  ``camera_info`` YAML files (K, D, R, P: their rectification is used as it is); Kalibr's
  ``camchain.yaml`` (pinhole cameras, radtan distortion).
* :class:`Rectifier` rectifies pairs of that size (``stereoRectify`` with zero disparity at
  infinity, ``initUndistortRectifyMap`` once per image size, ``remap``) and gives the rectified
  pair's :class:`~stereojax.data.datasets.Calibration` for depth, in the units of T.

Conventions (OpenCV's): a point X in the left camera's frame is ``R X + T`` in the right
camera's; R1 and R2 rotate the raw cameras' frames into the rectified ones, P1 and P2 project
rectified points, and Q maps (x, y, d, 1) to 3-D points.
"""

from __future__ import annotations

import glob
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereojax.data.datasets import Calibration
from stereojax.errors import StereoInputError

#: calibrate() warns when the RMS reprojection error is above this (px) or fewer pairs were usable
RMS_WARN_PX = 1.0
MIN_PAIRS = 8
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


@dataclass(frozen=True)
class StereoRig:
    """A raw stereo pair's calibration (OpenCV's conventions; T in the units of the board's squares,
    metres when ``square`` was given in metres)."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    size: tuple[int, int]            # (width, height) of the images it was made for
    rms: float | None = None
    #: given rectification (a pair of ROS camera_info files): R1, R2, P1, P2; None = stereoRectify
    given: dict | None = field(default=None, compare=False)

    def __post_init__(self):
        for name, shape in (("K1", (3, 3)), ("K2", (3, 3)), ("R", (3, 3))):
            a = np.asarray(getattr(self, name), np.float64)
            if a.shape != shape:
                raise StereoInputError(f"stereo calibration: {name} must be 3x3, found shape {a.shape}")
            object.__setattr__(self, name, a)
        t = np.asarray(self.T, np.float64).reshape(-1)
        if t.shape != (3,) or not np.isfinite(t).all() or not np.linalg.norm(t) > 0:
            raise StereoInputError(f"stereo calibration: T must be 3 finite numbers, not all 0, found {t.tolist()}")
        object.__setattr__(self, "T", t)
        for name in ("D1", "D2"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), np.float64).reshape(-1))
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise StereoInputError(f"stereo calibration: the image size must be positive, found {w}x{h}")
        object.__setattr__(self, "size", (w, h))

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T))


# ---- calibrate ----------------------------------------------------------------------------------

def image_list(spec) -> list[Path]:
    """The images of a folder (sorted by name) or of a glob pattern such as ``'cal/left*.jpg'``."""
    spec = str(spec)
    if os.path.isdir(spec):
        files = sorted(p for p in Path(spec).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    else:
        files = sorted(Path(p) for p in glob.glob(spec) if Path(p).suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise StereoInputError(f"no images in {spec!r} (a folder, or a quoted glob pattern such as 'cal/left*.jpg')")
    return files


def parse_board(text: str) -> tuple[int, int]:
    """``9x6`` -> (9, 6): inner corners per row and per column."""
    try:
        cols, rows = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise StereoInputError(f"--board takes the inner corners as COLSxROWS, e.g. 9x6, got {text!r}") from None
    if cols < 2 or rows < 2:
        raise StereoInputError(f"--board needs at least 2x2 inner corners, got {text!r}")
    return cols, rows


def _grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise StereoInputError(f"cannot read the image {path}")
    return img


def find_corners(grey: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """The board's inner corners ``f32[N, 1, 2]`` to a tenth of a pixel, or None where not found."""
    found, corners = cv2.findChessboardCorners(grey, board, cv2.CALIB_CB_ADAPTIVE_THRESH
                                               | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    return cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), crit)


@dataclass
class CalibrationReport:
    """What :func:`calibrate` used and dropped, and its warnings (one line each)."""

    used: list[tuple[str, str]]
    dropped: list[tuple[str, str, str]]        # (left, right, why)
    warnings: list[str]


def calibrate(left, right, board=(9, 6), square: float = 1.0) -> tuple[StereoRig, CalibrationReport]:
    """Calibrate a stereo pair from chessboard views.

    left, right: folders or glob patterns (see :func:`image_list`), or lists of image paths,
    paired in sorted order. board: inner corners (columns, rows). square: the side of a square
    in the unit T should have (e.g. metres).

    Raises:
        StereoInputError: different numbers of images, images of different sizes, or fewer than
            3 pairs where the board was found in both views.
    """
    lefts = sorted(Path(p) for p in left) if isinstance(left, list | tuple) else image_list(left)
    rights = sorted(Path(p) for p in right) if isinstance(right, list | tuple) else image_list(right)
    if len(lefts) != len(rights):
        raise StereoInputError(f"{len(lefts)} left and {len(rights)} right images: calibration pairs them in "
                               "sorted order, so both sides need the same number")
    if not square > 0:
        raise StereoInputError(f"--square must be a positive length, got {square}")
    board = tuple(board)
    grid = np.zeros((board[0] * board[1], 3), np.float32)
    grid[:, :2] = np.mgrid[0:board[0], 0:board[1]].T.reshape(-1, 2) * float(square)
    obj, pts_l, pts_r, used, dropped, size = [], [], [], [], [], None
    for lp, rp in zip(lefts, rights):
        gl, gr = _grey(lp), _grey(rp)
        if gl.shape != gr.shape:
            raise StereoInputError(f"{lp.name} is {gl.shape[1]}x{gl.shape[0]} but {rp.name} is "
                                   f"{gr.shape[1]}x{gr.shape[0]}")
        if size is None:
            size = (gl.shape[1], gl.shape[0])
        elif size != (gl.shape[1], gl.shape[0]):
            raise StereoInputError(f"{lp.name} is {gl.shape[1]}x{gl.shape[0]}, the first pair {size[0]}x{size[1]}: "
                                   "one calibration is for one image size")
        cl, cr = find_corners(gl, board), find_corners(gr, board)
        if cl is None or cr is None:
            side = "either view" if cl is None and cr is None else ("the left view" if cl is None else "the right view")
            dropped.append((lp.name, rp.name, f"no {board[0]}x{board[1]} board in {side}"))
            continue
        obj.append(grid)
        pts_l.append(cl)
        pts_r.append(cr)
        used.append((lp.name, rp.name))
    if len(used) < 3:
        raise StereoInputError(f"the {board[0]}x{board[1]} board was found in both views of only {len(used)} of "
                               f"{len(lefts)} pairs; calibration needs at least 3 (check --board: inner corners)")
    _, k1, d1, _, _ = cv2.calibrateCamera(obj, pts_l, size, None, None)
    _, k2, d2, _, _ = cv2.calibrateCamera(obj, pts_r, size, None, None)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6)
    rms, k1, d1, k2, d2, r, t, _, _ = cv2.stereoCalibrate(obj, pts_l, pts_r, k1, d1, k2, d2, size,
                                                          flags=cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
    rig = StereoRig(k1, d1, k2, d2, r, t, size, float(rms))
    warns = []
    if rms > RMS_WARN_PX:
        warns.append(f"RMS reprojection error {rms:.2f} px is above {RMS_WARN_PX:g} px: check the board size "
                     "and that the views are sharp")
    if len(used) < MIN_PAIRS:
        warns.append(f"only {len(used)} usable pairs (fewer than {MIN_PAIRS}); dropped: "
                     + (", ".join(f"{a}/{b} ({why})" for a, b, why in dropped) or "none"))
    return rig, CalibrationReport(used, dropped, warns)


# ---- files --------------------------------------------------------------------------------------

def write_rig(path, rig: StereoRig, extra: dict | None = None) -> None:
    """The calibration file of ``stereojax calibrate``: OpenCV FileStorage YAML (or JSON for a
    ``.json`` path) with K1, D1, K2, D2, R, T, image_width, image_height and rms."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        data = {"K1": rig.K1.tolist(), "D1": rig.D1.tolist(), "K2": rig.K2.tolist(), "D2": rig.D2.tolist(),
                "R": rig.R.tolist(), "T": rig.T.tolist(), "image_width": rig.size[0],
                "image_height": rig.size[1], "rms": rig.rms, **(extra or {})}
        path.write_text(json.dumps(data, indent=2) + "\n")
        return
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        for name in ("K1", "D1", "K2", "D2", "R"):
            fs.write(name, getattr(rig, name).reshape((3, 3) if name[0] in "KR" else (1, -1)))
        fs.write("T", rig.T.reshape(3, 1))
        fs.write("image_width", int(rig.size[0]))
        fs.write("image_height", int(rig.size[1]))
        if rig.rms is not None:
            fs.write("rms", float(rig.rms))
        for k, v in (extra or {}).items():
            fs.write(k, v)
    finally:
        fs.release()


def write_rig_atomic(path, rig: StereoRig, extra: dict | None = None) -> None:
    """:func:`write_rig` into a temporary file beside ``path``, then renamed: an interrupted or
    failed run leaves the old file or none, never half of one."""
    path = Path(path)
    if not path.parent.is_dir():
        raise StereoInputError(f"the folder of {path} does not exist")
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    try:
        write_rig(tmp, rig, extra)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _yaml(path: Path) -> dict | None:
    """A plain YAML file (ROS, Kalibr) as a dict; None when it is OpenCV's own YAML or not YAML."""
    import yaml

    text = path.read_text(errors="replace")
    if text.lstrip().startswith("%YAML"):
        return None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    return data if isinstance(data, dict) else None


def _storage_entries(path: Path) -> dict | None:
    """The entries of an OpenCV FileStorage file (YAML, XML or JSON) as arrays; None if it is not one."""
    head = path.read_text(errors="replace")[:64].lstrip()
    if path.suffix.lower() not in (".yaml", ".yml", ".xml", ".json") and not head.startswith(("%YAML", "<?xml")):
        return None
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):       # OpenCV raises SystemError for text it cannot parse
        return None
    try:
        if not fs.isOpened():
            return None
        root, out = fs.root(), {}
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap() and not node.empty():
                m = node.mat()
                if m is not None:
                    out[key] = np.asarray(m, np.float64)
            elif node.isReal() or node.isInt():
                out[key] = float(node.real())
            elif node.isSeq():
                out[key] = np.asarray([node.at(i).real() for i in range(node.size())], np.float64)
        return out
    finally:
        fs.release()


def _json_entries(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(errors="replace"))
    except (ValueError, OSError):
        return None
    if not isinstance(data, dict):
        return None
    out = {}
    for k, v in data.items():
        if isinstance(v, dict) and "data" in v:        # OpenCV's JSON matrices {"rows", "cols", "data"}
            a = np.asarray(v["data"], np.float64)
            out[k] = a.reshape(int(v["rows"]), int(v["cols"])) if "rows" in v and "cols" in v else a
        elif isinstance(v, list | int | float):
            out[k] = np.asarray(v, np.float64) if isinstance(v, list) else float(v)
    return out


def _entries(path: Path) -> dict:
    """Every numeric entry of a calibration file, however it is stored."""
    if path.suffix.lower() == ".json":
        found = _json_entries(path)
        if found:
            return found
    found = _storage_entries(path)
    if found:
        return found
    data = _yaml(path) if path.suffix.lower() in (".yaml", ".yml") else None
    return data or {}


RAW_KEYS = {"K1": ("K1", "M1"), "D1": ("D1",), "K2": ("K2", "M2"), "D2": ("D2",), "R": ("R",), "T": ("T",)}


def _pick(entries: dict, names) -> object:
    for n in names:
        if n in entries:
            return entries[n]
    return None


def is_raw_stereo(entries: dict) -> bool:
    """A raw stereo calibration is told apart by its entries: two cameras with distortion, R and T."""
    return all(_pick(entries, names) is not None for names in RAW_KEYS.values())


def _size_of(path: Path, entries: dict) -> tuple[int, int]:
    w = entries.get("image_width", entries.get("width"))
    h = entries.get("image_height", entries.get("height"))
    if w is None and "image_size" in entries:
        w, h = np.asarray(entries["image_size"]).reshape(-1)[:2]
    if w is None or h is None:
        raise StereoInputError(f"calibration file {path}: no image size (image_width and image_height)")
    return int(w), int(h)


def _from_raw_entries(path: Path, entries: dict) -> StereoRig:
    missing = [names[0] for names in RAW_KEYS.values() if _pick(entries, names) is None]
    if missing:
        raise StereoInputError(f"calibration file {path}: missing {', '.join(missing)}")
    k = {key: _pick(entries, names) for key, names in RAW_KEYS.items()}
    rms = entries.get("rms")
    return StereoRig(k["K1"], k["D1"], k["K2"], k["D2"], k["R"], k["T"], _size_of(path, entries),
                     None if rms is None else float(rms))


def _ros_camera(path: Path) -> dict:
    data = _yaml(path)
    need = ("camera_matrix", "distortion_coefficients", "rectification_matrix", "projection_matrix",
            "image_width", "image_height")
    if data is None or not all(k in data for k in need[:2]):
        raise StereoInputError(f"{path}: not a ROS camera_info YAML file (camera_matrix, distortion_coefficients, "
                               "rectification_matrix, projection_matrix)")
    missing = [k for k in need if k not in data]
    if missing:
        raise StereoInputError(f"ROS camera_info {path}: missing {', '.join(missing)}")

    def mat(key, shape):
        try:
            return np.asarray(data[key]["data"], np.float64).reshape(shape)
        except (KeyError, TypeError, ValueError):
            raise StereoInputError(f"ROS camera_info {path}: {key} is not a {shape[0]}x{shape[1]} matrix") from None
    model = str(data.get("distortion_model", "plumb_bob"))
    if model not in ("plumb_bob", "rational_polynomial"):
        raise StereoInputError(f"ROS camera_info {path}: distortion_model {model!r} is not supported "
                               "(plumb_bob, rational_polynomial)")
    return {"K": mat("camera_matrix", (3, 3)), "D": np.asarray(data["distortion_coefficients"]["data"], np.float64),
            "R": mat("rectification_matrix", (3, 3)), "P": mat("projection_matrix", (3, 4)),
            "size": (int(data["image_width"]), int(data["image_height"]))}


def _from_ros(left: Path, right: Path) -> StereoRig:
    a, b = _ros_camera(left), _ros_camera(right)
    if a["size"] != b["size"]:
        raise StereoInputError(f"ROS camera_info {left} is for {a['size'][0]}x{a['size'][1]} images, {right} for "
                               f"{b['size'][0]}x{b['size'][1]}")
    fx, tx = b["P"][0, 0], b["P"][0, 3]
    if not tx < 0:
        raise StereoInputError(f"ROS camera_info {right}: projection_matrix P[0][3] = -fx * baseline must be "
                               f"negative for the right camera, found {tx} (are the files in the order left,right?)")
    base = -tx / fx
    # X_right_raw = R2^T (R1 X_left_raw - (B, 0, 0))
    r = b["R"].T @ a["R"]
    t = -b["R"].T @ np.array([base, 0.0, 0.0])
    return StereoRig(a["K"], a["D"], b["K"], b["D"], r, t, a["size"],
                     given={"R1": a["R"], "R2": b["R"], "P1": a["P"], "P2": b["P"]})


def _from_kalibr(path: Path, data: dict) -> StereoRig:
    cams = [data.get("cam0"), data.get("cam1")]
    if not all(isinstance(c, dict) for c in cams):
        raise StereoInputError(f"Kalibr camchain {path}: needs cam0 and cam1")
    out = []
    for name, c in zip(("cam0", "cam1"), cams):
        missing = [k for k in ("intrinsics", "distortion_coeffs", "resolution") if k not in c]
        if missing:
            raise StereoInputError(f"Kalibr camchain {path}: {name} misses {', '.join(missing)}")
        if c.get("camera_model", "pinhole") != "pinhole" or c.get("distortion_model", "radtan") != "radtan":
            raise StereoInputError(f"Kalibr camchain {path}: {name} is {c.get('camera_model')}/"
                                   f"{c.get('distortion_model')}; stereojax reads pinhole cameras with radtan "
                                   "distortion")
        try:
            fu, fv, pu, pv = (float(v) for v in c["intrinsics"])
            out.append((np.array([[fu, 0, pu], [0, fv, pv], [0, 0, 1]]),
                        np.asarray(c["distortion_coeffs"], np.float64), tuple(int(v) for v in c["resolution"])))
        except (TypeError, ValueError):
            raise StereoInputError(f"Kalibr camchain {path}: {name}'s intrinsics (4 numbers), distortion_coeffs "
                                   "and resolution (2 numbers) must be numbers") from None
    if "T_cn_cnm1" not in cams[1]:
        raise StereoInputError(f"Kalibr camchain {path}: cam1 misses T_cn_cnm1 (cam0 -> cam1)")
    tr = np.asarray(cams[1]["T_cn_cnm1"], np.float64)
    if tr.shape != (4, 4):
        raise StereoInputError(f"Kalibr camchain {path}: T_cn_cnm1 must be 4x4, found {tr.shape}")
    if out[0][2] != out[1][2]:
        raise StereoInputError(f"Kalibr camchain {path}: cam0 and cam1 have different resolutions")
    return StereoRig(out[0][0], out[0][1], out[1][0], out[1][1], tr[:3, :3], tr[:3, 3], out[0][2])


def split_calib_arg(spec: str) -> list[Path]:
    """``--calib FILE`` or ``--calib LEFT.yaml,RIGHT.yaml`` (a pair of ROS camera_info files)."""
    parts = [Path(p) for p in str(spec).split(",") if p]
    if len(parts) not in (1, 2):
        raise StereoInputError(f"--calib takes one file or two comma-separated ROS camera_info files, got {spec!r}")
    for p in parts:
        if not p.is_file():
            raise StereoInputError(f"calibration file {p} does not exist")
    return parts


def read_rig(spec) -> tuple[StereoRig | None, str]:
    """(the raw stereo calibration of ``spec``, its format's name), or (None, why not) when the file
    is not a raw stereo calibration (it may then be a rectified pair's, for depth only)."""
    parts = split_calib_arg(spec) if isinstance(spec, str) else [Path(spec)]
    if len(parts) == 2:
        return _from_ros(*parts), "ROS camera_info pair (K, D, R, P)"
    path = parts[0]
    data = _yaml(path) if path.suffix.lower() in (".yaml", ".yml") else None
    if data is not None and "cam0" in data:
        return _from_kalibr(path, data), "Kalibr camchain.yaml"
    if data is not None and "camera_matrix" in data:
        raise StereoInputError(f"{path} is one ROS camera_info file; give both cameras' as --calib LEFT.yaml,RIGHT.yaml")
    entries = _entries(path)
    if is_raw_stereo(entries):
        return _from_raw_entries(path, entries), "stereo calibration (K1, D1, K2, D2, R, T)"
    partial = [names[0] for names in RAW_KEYS.values() if _pick(entries, names) is not None]
    if len(partial) >= 3:   # looks like one, with entries missing: name them
        _from_raw_entries(path, entries)
    return None, "not a raw stereo calibration"


# ---- rectify ------------------------------------------------------------------------------------

class Rectifier:
    """Rectifies the raw pairs of one :class:`StereoRig` (maps built once per image size).

    ``rectify(left, right)`` -> the rectified pair (same size, colour kept); ``calibration`` the
    rectified pair's :class:`Calibration` for depth (focal and principal point of P1, baseline
    |P2[0, 3] / P2[0, 0]| in the units of T); ``to_json()`` R1, R2, P1, P2 and Q;
    ``to_original(points)`` rotates rectified left-camera points into the raw left camera's frame.

    alpha: OpenCV's free scaling (0: only valid pixels, the default; 1: every source pixel kept).
    """

    def __init__(self, rig: StereoRig, alpha: float = 0.0):
        self.rig, self.alpha = rig, float(alpha)
        if rig.given is not None:
            g = rig.given
            self.R1, self.R2, self.P1, self.P2 = (np.asarray(g[k], np.float64) for k in ("R1", "R2", "P1", "P2"))
            f, cx1, cy, cx2 = self.P1[0, 0], self.P1[0, 2], self.P1[1, 2], self.P2[0, 2]
            tx = self.P2[0, 3] / self.P2[0, 0]
            self.Q = np.array([[1, 0, 0, -cx1], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, -1 / tx, (cx1 - cx2) / tx]])
        else:
            self.R1, self.R2, self.P1, self.P2, self.Q, _, _ = cv2.stereoRectify(
                rig.K1, rig.D1.reshape(1, -1), rig.K2, rig.D2.reshape(1, -1), rig.size, rig.R, rig.T.reshape(3, 1),
                flags=cv2.CALIB_ZERO_DISPARITY,
                alpha=self.alpha)
        if abs(self.P2[1, 3]) > 1e-6 * max(1.0, abs(self.P2[0, 3])):
            raise StereoInputError("this calibration rectifies vertically (the cameras sit above each other); "
                                   "stereojax matches along rows: rotate both images by 90 degrees first")
        if self.P2[0, 3] > 0:
            raise StereoInputError("in this calibration the right camera sits to the left of the left one "
                                   f"(T = {np.round(rig.T, 4).tolist()}): are the left and right images swapped?")
        self._maps: dict = {}

    @property
    def size(self) -> tuple[int, int]:
        return self.rig.size

    @property
    def calibration(self) -> Calibration:
        f = float(self.P1[0, 0])
        return Calibration(baseline=abs(float(self.P2[0, 3] / self.P2[0, 0])), focal=f,
                           doffs=float(self.P2[0, 2] - self.P1[0, 2]), cx=float(self.P1[0, 2]),
                           cy=float(self.P1[1, 2]))

    def _map(self, side: int):
        if side not in self._maps:
            k, d, r, p = ((self.rig.K1, self.rig.D1, self.R1, self.P1) if side == 0
                          else (self.rig.K2, self.rig.D2, self.R2, self.P2))
            self._maps[side] = cv2.initUndistortRectifyMap(k, d.reshape(1, -1), r, p, self.size, cv2.CV_32FC1)
        return self._maps[side]

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rectified pair (linear interpolation; pixels from outside the raw image are black).

        Raises:
            StereoInputError: images of another size than the calibration's.
        """
        for name, img in (("left", left), ("right", right)):
            h, w = np.shape(img)[:2]
            if (w, h) != self.size:
                raise StereoInputError(f"the {name} image is {w}x{h} but the calibration is for {self.size[0]}x"
                                       f"{self.size[1]} images")
        out = []
        for side, img in enumerate((left, right)):
            mx, my = self._map(side)
            out.append(cv2.remap(np.ascontiguousarray(img), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
        return out[0], out[1]

    def rectify_points(self, points: np.ndarray, side: int = 0) -> np.ndarray:
        """Raw pixel positions ``[N, 2]`` of one camera -> their rectified positions."""
        k, d, r, p = (self.rig.K1, self.rig.D1, self.R1, self.P1) if side == 0 else (self.rig.K2, self.rig.D2,
                                                                                      self.R2, self.P2)
        pts = np.asarray(points, np.float64).reshape(-1, 1, 2)
        return cv2.undistortPoints(pts, k, d.reshape(1, -1), R=r, P=p).reshape(-1, 2)

    def to_original(self, xyz: np.ndarray) -> np.ndarray:
        """Points ``[..., 3]`` in the rectified left camera's frame -> the raw left camera's frame."""
        return np.asarray(xyz) @ self.R1           # R1^T x for row vectors: x @ R1

    def to_json(self) -> dict:
        return {"image_width": self.size[0], "image_height": self.size[1], "alpha": self.alpha,
                "R1": self.R1.tolist(), "R2": self.R2.tolist(), "P1": self.P1.tolist(), "P2": self.P2.tolist(),
                "Q": np.asarray(self.Q).tolist(), "baseline": self.calibration.baseline,
                "focal": self.calibration.focal, "given": self.rig.given is not None}


# ---- a raw rig made from a rectified pair (to test rectification end to end) ---------------------

def _rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation from angles in degrees about x, y and z."""
    r, _ = cv2.Rodrigues(np.radians(np.array([rx, ry, rz], np.float64)))
    return r


@dataclass(frozen=True)
class RawCamera:
    """One raw camera of :func:`simulate_raw_pair`: intrinsics, distortion, and its rotation
    away from the rectified camera (degrees about x, y, z)."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)
    angles: tuple = (0.0, 0.0, 0.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], np.float64)


def simulate_raw_pair(left, right, calib: Calibration, cam_l: RawCamera, cam_r: RawCamera):
    """A raw (unrectified) pair and its exact stereo calibration, made from a rectified pair with a
    known ``calib``: each raw camera sees the rectified camera's view through its own rotation
    (R_i: raw -> rectified), intrinsics and distortion. Returns (raw_left, raw_right, StereoRig,
    R_l): ``R_l`` rotates the raw left camera's frame into the original rectified one."""
    h, w = np.shape(left)[:2]
    cx = calib.cx if calib.cx is not None else (w - 1) / 2
    cy = calib.cy if calib.cy is not None else (h - 1) / 2
    p_rect = np.array([[calib.focal, 0, cx], [0, calib.focal, cy], [0, 0, 1]], np.float64)
    raw, rots = [], []
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    for img, cam, shift in ((left, cam_l, 0.0), (right, cam_r, calib.doffs)):
        rot = _rotation(*cam.angles)
        where = cv2.undistortPoints(grid, cam.K, np.asarray(cam.dist, np.float64).reshape(1, -1), R=rot,
                                    P=p_rect).reshape(h, w, 2).astype(np.float32)
        where[..., 0] += np.float32(shift)
        raw.append(cv2.remap(np.ascontiguousarray(img), where[..., 0], where[..., 1], cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT))
        rots.append(rot)
    r_l, r_r = rots
    b = np.array([calib.baseline, 0.0, 0.0])
    rig = StereoRig(cam_l.K, np.asarray(cam_l.dist), cam_r.K, np.asarray(cam_r.dist), r_r.T @ r_l, -r_r.T @ b, (w, h))
    return raw[0], raw[1], rig, r_l
