"""Reading and writing images, disparity maps and visualisations (numpy and OpenCV only).

Conventions
-----------
* Images are returned as grey ``u8[H, W]`` / ``u16[H, W]`` or RGB ``u8[H, W, 3]`` /
  ``u16[H, W, 3]`` arrays (OpenCV's BGR order is converted to RGB on reading and back on
  writing).
* Disparity maps are ``f32[H, W]`` with a separate ``bool[H, W]`` validity mask.
* Every writer goes through :func:`atomic_output`: the file is written under a temporary
  name in the destination folder and renamed into place only when complete, so an
  interrupted or failed write leaves either the old file or nothing, never half a file.
* A bad input file raises :class:`~stereojax.errors.StereoInputError`; an output that cannot
  be written raises :class:`~stereojax.errors.OutputError`. Both carry a one-line message.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from stereojax.errors import OutputError, StereoError, StereoInputError, wxh

__all__ = [
    "atomic_output", "read_image", "read_pfm", "write_pfm", "read_kitti_disparity",
    "write_kitti_disparity", "colorize_disparity", "write_color_disparity", "error_map",
    "write_error_map", "write_png", "KITTI_ERROR_COLORS",
]

PathLike = str | os.PathLike


# ---- atomic output -----------------------------------------------------------------------------

def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


@contextlib.contextmanager
def atomic_output(path: PathLike) -> Iterator[Path]:
    """Write a file atomically.

    Yields a temporary path in the same folder as ``path`` and with the same extension (so
    ``cv2.imwrite`` or ``np.save`` pick the same format). When the ``with`` block ends
    normally the temporary file is renamed onto ``path`` with :func:`os.replace`; when it
    raises, the temporary file is deleted and the exception propagates (an ``OSError`` raised
    by the block becomes :class:`OutputError`). The destination folder is created if needed.

    Raises:
        OutputError: the folder cannot be created or written, ``path`` is a folder, or the
            write or the final rename fails. Message: ``"cannot write <path>: <reason>"``.
    """
    path = Path(path)
    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: cannot create folder {folder}: {_reason(exc)}") from None
    if path.is_dir():
        raise OutputError(f"cannot write {path}: it is an existing folder")
    tmp = folder / f".{path.stem}.tmp-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}"
    try:
        # O_EXCL: never clobber another writer's temporary file; mode 0o666 & ~umask like open()
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {_reason(exc)}") from None
    try:
        yield tmp
    except BaseException as exc:
        _unlink_quietly(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, StereoError):
            raise OutputError(f"cannot write {path}: {_reason(exc)}") from None
        raise
    try:
        os.replace(tmp, path)
    except OSError as exc:
        _unlink_quietly(tmp)
        raise OutputError(f"cannot write {path}: {_reason(exc)}") from None


def _unlink_quietly(p: Path) -> None:
    try:
        os.unlink(p)
    except OSError:
        pass


# ---- low-level reading -------------------------------------------------------------------------

def _read_bytes(path: PathLike, what: str) -> bytes:
    """The bytes of an input file, or StereoInputError for a missing, folder or empty path."""
    p = Path(path)
    if not p.exists():
        raise StereoInputError(f"cannot read {what} {p}: no such file")
    if p.is_dir():
        raise StereoInputError(f"cannot read {what} {p}: expected a file, found a folder")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise StereoInputError(f"cannot read {what} {p}: {_reason(exc)}") from None
    if not data:
        raise StereoInputError(f"cannot read {what} {p}: the file is empty (0 bytes)")
    return data


_PNG_SIG = b"\x89PNG\r\n\x1a\n"


def _check_complete(data: bytes, p: Path, what: str) -> None:
    """Detect truncation that decoders tolerate silently (they return a partial image)."""
    if data.startswith(_PNG_SIG):
        if data.rfind(b"IEND") < 0:
            raise StereoInputError(f"cannot read {what} {p}: truncated PNG (no IEND chunk)")
    elif data.startswith(b"\xff\xd8"):
        # entropy-coded data byte-stuffs 0xFF, so FF D9 near the end is the end-of-image marker
        if data.rfind(b"\xff\xd9", max(0, len(data) - 4096)) < 0:
            raise StereoInputError(f"cannot read {what} {p}: truncated JPEG (no end-of-image marker)")


def _decode(data: bytes, p: Path, what: str) -> np.ndarray:
    _check_complete(data, p, what)
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    if img is None or img.size == 0:
        raise StereoInputError(f"cannot read {what} {p}: not a decodable image "
                               "(corrupt, truncated or not an image file)")
    return img


def _to_rgb(img: np.ndarray) -> np.ndarray:
    """OpenCV's grey / grey+alpha / BGR / BGRA to grey or RGB (alpha dropped)."""
    if img.ndim == 2:
        return img
    c = img.shape[2]
    if c == 1:
        return np.ascontiguousarray(img[:, :, 0])
    if c == 2:
        return np.ascontiguousarray(img[:, :, 0])
    if c == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return cv2.cvtColor(img[:, :, :4], cv2.COLOR_BGRA2RGB)


def read_image(path: PathLike) -> np.ndarray:
    """Read an image file as grey ``[H, W]`` or RGB ``[H, W, 3]``.

    The stored bit depth is kept (``uint8`` or ``uint16``); an alpha channel is dropped.

    Raises:
        StereoInputError: missing path, a folder, an empty file, a truncated or corrupt file,
            a file that is not an image, or an image that is neither 8- nor 16-bit.
    """
    p = Path(path)
    img = _decode(_read_bytes(p, "image"), p, "image")
    if img.dtype not in (np.uint8, np.uint16):
        raise StereoInputError(f"cannot read image {p}: expected 8- or 16-bit integer pixels, "
                               f"found {img.dtype}")
    return _to_rgb(img)


# ---- PFM ---------------------------------------------------------------------------------------

def read_pfm(path: PathLike) -> np.ndarray:
    """Read a PFM file as ``f32[H, W]`` (``Pf``) or ``f32[H, W, 3]`` (``PF``).

    Rows are stored bottom-up and are flipped to top-down; a negative scale means
    little-endian data, a positive one big-endian (its magnitude is ignored, as the
    Middlebury tools do). Non-finite values (Middlebury's ``inf`` = unknown) are kept.

    Raises:
        StereoInputError: missing/empty file, bad header, or fewer data bytes than the
            header announces.
    """
    p = Path(path)
    data = _read_bytes(p, "PFM file")
    tokens, pos, n = [], 0, min(len(data), 256)
    while len(tokens) < 4:
        while pos < n and data[pos:pos + 1].isspace():
            pos += 1
        start = pos
        while pos < n and not data[pos:pos + 1].isspace():
            pos += 1
        if start == pos or pos >= len(data):
            raise StereoInputError(f"cannot read PFM file {p}: incomplete header "
                                   "(expected 'PF' or 'Pf', width, height, scale)")
        tokens.append(data[start:pos])
    pos += 1  # the single whitespace byte after the scale
    kind, ws, hs, ss = tokens
    if kind not in (b"PF", b"Pf"):
        raise StereoInputError(f"cannot read PFM file {p}: expected magic 'PF' or 'Pf', "
                               f"found {kind[:8]!r}")
    try:
        w, h, scale = int(ws), int(hs), float(ss)
    except ValueError:
        raise StereoInputError(f"cannot read PFM file {p}: bad header values "
                               f"{ws[:16]!r} {hs[:16]!r} {ss[:16]!r}") from None
    if w <= 0 or h <= 0 or not np.isfinite(scale) or scale == 0:
        raise StereoInputError(f"cannot read PFM file {p}: expected positive size and non-zero "
                               f"scale, found {w}x{h}, scale {scale}")
    c = 3 if kind == b"PF" else 1
    expected = w * h * c * 4
    rest = len(data) - pos
    if rest == expected + 1 and data[pos:pos + 1] == b"\n":  # header ended with "\r\n"
        pos += 1
        rest -= 1
    if rest < expected:
        raise StereoInputError(f"cannot read PFM file {p}: truncated, expected {expected} data "
                               f"bytes for {w}x{h}x{c}, found {rest}")
    dtype = np.dtype("<f4") if scale < 0 else np.dtype(">f4")
    arr = np.frombuffer(data, dtype, count=w * h * c, offset=pos)
    arr = arr.reshape((h, w, 3) if c == 3 else (h, w))[::-1]
    return np.ascontiguousarray(arr, dtype=np.float32)


def write_pfm(path: PathLike, arr: np.ndarray) -> None:
    """Write ``f32[H, W]`` or ``f32[H, W, 3]`` as a little-endian PFM (rows bottom-up, scale -1).

    Raises:
        StereoInputError: ``arr`` is not 2-D or ``[H, W, 3]``.
        OutputError: the file cannot be written.
    """
    a = np.asarray(arr)
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or a.size == 0:
        raise StereoInputError(f"write_pfm expects a non-empty [H, W] or [H, W, 3] array, "
                               f"found shape {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise StereoInputError(f"write_pfm expects numbers, found dtype {a.dtype}")
    h, w = a.shape[:2]
    header = f"{'PF' if a.ndim == 3 else 'Pf'}\n{w} {h}\n-1.0\n".encode("ascii")
    body = np.ascontiguousarray(a[::-1], dtype="<f4").tobytes()
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header)
            f.write(body)


# ---- KITTI disparity PNG -----------------------------------------------------------------------

def read_kitti_disparity(path: PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a KITTI disparity PNG: returns ``(f32[H, W] disparity, bool[H, W] valid)``.

    The file is a 16-bit single-channel PNG with ``disparity = value / 256``; ``0`` means no
    disparity (``valid`` False, disparity 0).

    Raises:
        StereoInputError: unreadable file, or a PNG that is not uint16 single-channel.
    """
    p = Path(path)
    img = _decode(_read_bytes(p, "KITTI disparity"), p, "KITTI disparity")
    if img.dtype != np.uint16 or img.ndim != 2:
        shape = wxh(img.shape)
        raise StereoInputError(f"{p} is not a KITTI disparity map: expected a uint16 single-channel "
                               f"PNG, found {img.dtype} {shape}")
    valid = img > 0
    return img.astype(np.float32) / np.float32(256.0), valid


def write_kitti_disparity(path: PathLike, disp: np.ndarray, valid: np.ndarray | None = None) -> None:
    """Write ``f32[H, W]`` disparity as a KITTI uint16 PNG.

    Stored value: ``round(disp * 256)`` clipped to 65535. Pixels where ``valid`` is False or the
    disparity is NaN, infinite or negative are stored as 0 (= no disparity). As in the KITTI
    devkit, a valid pixel never becomes 0: a disparity below 1/512 px is stored as 1.

    Raises:
        StereoInputError: ``disp`` is not 2-D, or ``valid`` has another shape.
        OutputError: the file cannot be written.
    """
    d = _as_disp(disp, "disparity")
    ok = np.isfinite(d) & (d >= 0)
    if valid is not None:
        ok &= _as_mask(valid, d.shape, "valid")
    with np.errstate(invalid="ignore", over="ignore"):
        v = np.clip(np.rint(np.where(ok, d, 0.0).astype(np.float64) * 256.0), 1, 65535)
    out = np.where(ok, v, 0).astype(np.uint16)
    _write_image(path, out)


# ---- colour visualisations ---------------------------------------------------------------------

def _turbo_lut() -> np.ndarray:
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(256, 1), cv2.COLORMAP_TURBO)
    return lut.reshape(256, 3)[:, ::-1].copy()  # BGR -> RGB


_TURBO = _turbo_lut()


def colorize_disparity(disp: np.ndarray, max_disp: float | None = None,
                       valid: np.ndarray | None = None) -> np.ndarray:
    """Colour-code ``f32[H, W]`` disparity as ``u8[H, W, 3]`` RGB with the Turbo colour map.

    ``0`` maps to dark blue and ``max_disp`` (default: the largest valid disparity) to dark
    red; larger values saturate. Pixels where ``valid`` is False or the disparity is NaN,
    infinite or negative are black.

    Raises:
        StereoInputError: bad shapes, or ``max_disp`` not a positive number.
    """
    d = _as_disp(disp, "disparity")
    ok = np.isfinite(d) & (d >= 0)
    if valid is not None:
        ok &= _as_mask(valid, d.shape, "valid")
    if max_disp is None:
        max_disp = float(d[ok].max()) if ok.any() else 1.0
    max_disp = float(max_disp)
    if not np.isfinite(max_disp) or max_disp < 0:
        raise StereoInputError(f"max_disp must be a positive number, got {max_disp}")
    max_disp = max(max_disp, 1e-6)
    with np.errstate(invalid="ignore"):
        idx = np.rint(np.clip(np.where(ok, d, 0.0) / max_disp, 0.0, 1.0) * 255).astype(np.uint8)
    rgb = _TURBO[idx]
    rgb[~ok] = 0
    return rgb


def write_color_disparity(path: PathLike, disp: np.ndarray, max_disp: float | None = None,
                          valid: np.ndarray | None = None) -> None:
    """Write :func:`colorize_disparity` of ``f32[H, W]`` disparity as an RGB image file."""
    write_png(path, colorize_disparity(disp, max_disp=max_disp, valid=valid))


#: KITTI devkit log-colour scale: (lower, upper) bounds of the normalised error
#: ``min(err / tau_abs, err / (tau_rel * |gt|))`` and the RGB colour of that band.
#: Normalised error >= 1 is a KITTI outlier (orange to red).
KITTI_ERROR_COLORS = (
    (0.0, 0.0625, (49, 54, 149)),
    (0.0625, 0.125, (69, 117, 180)),
    (0.125, 0.25, (116, 173, 209)),
    (0.25, 0.5, (171, 217, 233)),
    (0.5, 1.0, (224, 243, 248)),
    (1.0, 2.0, (254, 224, 144)),
    (2.0, 4.0, (253, 174, 97)),
    (4.0, 8.0, (244, 109, 67)),
    (8.0, 16.0, (215, 48, 39)),
    (16.0, np.inf, (165, 0, 38)),
)


def error_map(disp: np.ndarray, gt: np.ndarray, gt_valid: np.ndarray, tau: tuple[float, float] = (3, 0.05),
              noc_valid: np.ndarray | None = None, dilate: bool = True) -> np.ndarray:
    """KITTI-devkit-style error image ``u8[H, W, 3]`` RGB of ``f32[H, W]`` disparity.

    Each ground-truth pixel is coloured by its normalised error
    ``min(|d - gt| / tau[0], |d - gt| / (tau[1] * |gt|))`` on the devkit's log scale
    (:data:`KITTI_ERROR_COLORS`): blues for small errors, pale yellow to dark red for
    outliers (normalised error >= 1, i.e. > 3 px and > 5 %). A missing estimate (NaN or
    infinite ``disp``) counts as the largest error. Pixels without ground truth are black.
    When ``noc_valid`` is given, ground-truth pixels outside it (occluded) are drawn at half
    brightness, as the devkit does. With ``dilate`` (default), black pixels next to
    ground-truth pixels take the colour of their worst neighbour (3x3), which makes sparse
    KITTI ground truth readable; ground-truth pixels themselves are never changed.

    Raises:
        StereoInputError: shapes differ or a tau is not positive.
    """
    d = _as_disp(disp, "disparity")
    g = _as_disp(gt, "ground truth", d.shape)
    gv = _as_mask(gt_valid, d.shape, "gt_valid") & np.isfinite(g)
    t_abs, t_rel = (float(t) for t in tau)
    if not (t_abs > 0 and t_rel > 0):
        raise StereoInputError(f"tau must be two positive numbers (px, fraction), got {tau}")
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        err = np.abs(d.astype(np.float64) - g)
        err = np.where(np.isfinite(err), err, np.inf)
        rel = np.where(g != 0, err / (t_rel * np.abs(g)), np.inf)
        n_err = np.minimum(err / t_abs, rel)
    bounds = np.array([c[0] for c in KITTI_ERROR_COLORS[1:]])
    level = np.searchsorted(bounds, np.where(gv, n_err, 0.0), side="right")  # 0..9
    colors = np.array([c[2] for c in KITTI_ERROR_COLORS], np.uint8)
    noc = np.ones_like(gv) if noc_valid is None else _as_mask(noc_valid, d.shape, "noc_valid")
    # code 0: no GT; 1..10: occluded level 0..9; 11..20: non-occluded level 0..9
    code = np.where(gv, level + 1 + 10 * noc, 0).astype(np.uint8)
    if dilate:
        grown = cv2.dilate(code, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        code = np.where(gv, code, grown)
    palette = np.zeros((21, 3), np.uint8)
    palette[1:11] = colors // 2
    palette[11:21] = colors
    return palette[code]


def error_legend(tau: tuple[float, float] = (3, 0.05)) -> np.ndarray:
    """``u8[H, W, 3]`` legend of :func:`error_map`'s colours: one row per band of
    :data:`KITTI_ERROR_COLORS`, labelled with its normalised error and, for an outlier band, the
    words that say so; a title gives the normalisation."""
    row, width = 24, 460
    title = [f"error = min(|d - gt| / {tau[0]:g} px, |d - gt| / ({100 * tau[1]:g} % of gt))",
             "black: no ground truth"]
    img = np.full((row * (len(KITTI_ERROR_COLORS) + len(title)) + 8, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for i, text in enumerate(title):
        cv2.putText(img, text, (6, row * (i + 1) - 7), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for i, (lo, hi, colour) in enumerate(KITTI_ERROR_COLORS):
        y = row * (i + len(title)) + 4
        img[y:y + row - 4, 6:60] = colour
        band = f"{lo:g} - {hi:g}" if np.isfinite(hi) else f">= {lo:g}"
        note = "  outlier (> 3 px and > 5 %)" if lo >= 1.0 else ""
        cv2.putText(img, band + note, (70, y + row - 9), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def write_error_map(path: PathLike, disp: np.ndarray, gt: np.ndarray, gt_valid: np.ndarray,
                    tau: tuple[float, float] = (3, 0.05), noc_valid: np.ndarray | None = None,
                    dilate: bool = True) -> None:
    """Write :func:`error_map` as an RGB image file."""
    write_png(path, error_map(disp, gt, gt_valid, tau=tau, noc_valid=noc_valid, dilate=dilate))


# ---- generic image writer ----------------------------------------------------------------------

def write_png(path: PathLike, image: np.ndarray) -> None:
    """Write a grey ``[H, W]``, RGB ``[H, W, 3]`` or RGBA ``[H, W, 4]`` image.

    ``uint8`` and ``uint16`` are written as they are, ``bool`` as 0/255. The format follows the
    extension (``.png`` keeps 16 bits; other OpenCV formats such as ``.jpg`` work too).

    Raises:
        StereoInputError: wrong shape or dtype.
        OutputError: unknown extension, or the file cannot be written.
    """
    img = np.asarray(image)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.dtype not in (np.uint8, np.uint16):
        raise StereoInputError(f"write_png expects uint8, uint16 or bool pixels, found {img.dtype}")
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3, 4))) or img.size == 0:
        raise StereoInputError(f"write_png expects a non-empty [H, W], [H, W, 3] or [H, W, 4] image, "
                               f"found shape {img.shape}")
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGBA2BGRA)
    _write_image(path, img)


def _write_image(path: PathLike, img_bgr: np.ndarray) -> None:
    p = Path(path)
    ext = p.suffix.lower()
    if not ext:
        raise OutputError(f"cannot write {p}: no file extension to choose the image format")
    try:
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(img_bgr))
    except cv2.error:
        ok, buf = False, None
    if not ok:
        raise OutputError(f"cannot write {p}: OpenCV cannot encode a {img_bgr.dtype} image as '{ext}'")
    with atomic_output(p) as tmp:
        tmp.write_bytes(buf.tobytes())


# ---- argument checks ---------------------------------------------------------------------------

def _as_disp(a, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim != 2:
        raise StereoInputError(f"{name} must be a 2-D [H, W] array, found shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
            or arr.dtype == bool):
        raise StereoInputError(f"{name} must be numeric, found dtype {arr.dtype}")
    if shape is not None and arr.shape != tuple(shape):
        raise StereoInputError(f"{name} is {wxh(arr.shape)} but the disparity is {wxh(shape)}")
    return arr.astype(np.float32, copy=False)


def _as_mask(m, shape: tuple[int, ...], name: str) -> np.ndarray:
    arr = np.asarray(m)
    if arr.shape != tuple(shape):
        raise StereoInputError(f"{name} mask must have shape {tuple(shape)}, found {arr.shape}")
    return arr.astype(bool, copy=False)


def json_default(obj):
    """``json.dumps`` fallback for numpy scalars and arrays."""
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json(path: PathLike, data) -> None:
    """Write ``data`` as indented JSON, atomically."""

    with atomic_output(path) as tmp:
        Path(tmp).write_text(json.dumps(data, indent=2, sort_keys=True, default=json_default) + "\n")
