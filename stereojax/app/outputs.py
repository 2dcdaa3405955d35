"""Writing a prediction: disparity (KITTI 16-bit PNG, PFM, colour map) and, with a
calibration, depth (PNG, npy) and a coloured point cloud; every file atomically."""

from __future__ import annotations

import fcntl
import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from stereojax.data import depth as depth_mod, io
from stereojax.errors import OutputBusyError, OutputError


def output_folder(path) -> Path:
    """Create the output folder and check that it is writable, before any long computation.
    A folder made here is remembered (:func:`remove_if_empty`): a run that fails before writing
    anything leaves no empty folder behind."""
    path = Path(path)
    missing = [p for p in (path, *path.parents) if not p.exists()]
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output folder {path}: {exc.strerror}") from None
    if not path.is_dir() or not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {path} is not writable")
    _CREATED.update(p.resolve() for p in missing)
    return path


#: output folders this process created (:func:`output_folder`)
_CREATED: set[Path] = set()


def remove_if_empty() -> list[Path]:
    """Remove the output folders this process created that are still empty (a run that failed
    before its first output); returns them."""
    gone = []
    for path in sorted(_CREATED, key=lambda p: -len(p.parts)):
        try:
            path.rmdir()             # only an empty folder goes
            gone.append(path)
        except OSError:
            pass
    _CREATED.clear()
    return gone


LOCK_NAME = ".stereojax.lock"
#: the folders whose lock this process holds, with how many blocks hold it (re-entrant)
_HELD: dict[Path, int] = {}


@contextmanager
def folder_lock(folder: Path, command: str = "stereojax"):
    """Hold the output folder's lock (``folder/.stereojax.lock``, an exclusive ``flock``) while
    the block runs, as a database does before it writes: a second process on the same folder
    gets :class:`~stereojax.errors.OutputBusyError` at once, naming the holder's PID. The
    operating system releases the lock when its process dies, however it dies, so a killed run
    never leaves the folder locked. A run that ends (done, failed or interrupted) removes the
    file; only a killed one leaves it, and the next run takes it over. Re-entrant: a block inside
    another on the same folder (the CLI's, then the batch's) holds the same lock."""
    key = Path(folder).resolve()
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield Path(folder) / LOCK_NAME
        finally:
            _HELD[key] -= 1
        return
    path = Path(folder) / LOCK_NAME
    fd = _take_lock(path, folder, command)
    _HELD[key] = 1
    try:
        yield path
    finally:
        del _HELD[key]
        try:
            os.unlink(path)  # while still locked: a process that opened this file before now
        except OSError:      # finds it gone once it holds the lock, and opens a fresh one
            pass
        os.close(fd)         # releases the lock


def _take_lock(path: Path, folder, command: str) -> int:
    """An open descriptor of ``path`` that holds its exclusive lock (OutputBusyError if taken)."""
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise OutputError(f"cannot create the lock file {path}: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "?"
            os.close(fd)
            raise OutputBusyError(f"output folder {folder} is in use by PID {holder} (another stereojax "
                                  f"{command}); wait for it to finish or choose another --out") from None
        try:
            current = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            current = False
        if current:                  # not a file its last holder removed after we opened it
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)


def pid_alive(pid: int) -> bool:
    """Whether a process with this PID runs on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def color_scale(disp, gt=None, gt_valid=None) -> float:
    """Disparity shown as the top colour: the largest true disparity when GT is known, else
    the 99.5th percentile of the estimate (so a few outliers do not wash out the picture)."""
    if gt is not None and gt_valid is not None and gt_valid.any():
        return float(gt[gt_valid].max())
    finite = np.asarray(disp)[np.isfinite(disp)]
    return max(float(np.percentile(finite, 99.5)), 1.0) if finite.size else 1.0


def blank_unconfident(disp, confidence, threshold: float):
    """The disparity with every pixel whose confidence is below ``threshold`` set to +inf (no
    estimate: 0 in KITTI PNGs and depth, inf in PFM, as Middlebury marks unknown pixels)."""
    if not threshold:
        return disp
    return np.where(np.asarray(confidence) >= threshold, disp, np.inf).astype(np.float32)


def write_confidence(out: Path, stem: str, confidence) -> list[str]:
    """``confidence.npy`` (float32 in [0, 1]) and ``confidence.png`` (grey, 255 = 1)."""

    conf = np.clip(np.asarray(confidence, np.float32), 0.0, 1.0)
    io.write_png(out / f"{stem}confidence.png", np.round(conf * 255).astype(np.uint8))
    with io.atomic_output(out / f"{stem}confidence.npy") as tmp:
        np.save(tmp, conf)
    return [f"{stem}confidence.png", f"{stem}confidence.npy"]


def color_legend(top: float) -> dict:
    """What ``disparity_color.png``'s colours mean (its sidecar ``disparity_color.json``): the
    colour map, the disparities of its two ends in pixels, and the colour of "no estimate"."""
    return {"image": "disparity_color.png", "colormap": "turbo", "unit": "px",
            "min": 0.0, "max": round(top, 3), "clipped_above": True, "no_estimate": [0, 0, 0],
            "note": "colour = colormap(d / max); disparities above max have the top colour"}


#: a pixel's depth is reliable when one pixel of disparity error moves it by at most 10 %
#: (Z = B f / d, so dZ / Z = dd / d: a disparity of at least 10 px) and, where a confidence map
#: is known, its confidence is at least 0.3 (the threshold measured in docs/results.md to keep
#: 93 % of KITTI's pixels while the error of the kept ones falls from 3.0 to 2.0 % > 3 px)
RELIABLE_MIN_DISP = 10.0
RELIABLE_MIN_CONFIDENCE = 0.3
#: the grey of an unreliable depth in depth_color.png: half brightness, whatever the depth (a far pixel
#: is never near black, which is "no depth")
UNRELIABLE_GREY = 128


def depth_reliable(disp, confidence=None) -> np.ndarray:
    """``bool[H, W]``: where the depth of a disparity map can be trusted (see
    :data:`RELIABLE_MIN_DISP`, :data:`RELIABLE_MIN_CONFIDENCE`)."""
    d = np.asarray(disp, np.float32)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(d) & (d >= RELIABLE_MIN_DISP)
    if confidence is not None:
        ok &= np.asarray(confidence) >= RELIABLE_MIN_CONFIDENCE
    return ok


def depth_color(z, reliable) -> tuple[np.ndarray, dict]:
    """``u8[H, W, 3]`` picture of depth ``z`` (metres) and its scale: near red, far blue (Turbo
    over the 1st..99th percentile of the reliable depths, clipped beyond); unreliable pixels in
    grey at half brightness (:data:`UNRELIABLE_GREY`, at every depth), pixels without depth black."""
    z = np.asarray(z, np.float32)
    has = np.isfinite(z) & (z > 0)
    shown = has & reliable
    pick = z[shown] if shown.any() else z[has] if has.any() else np.ones(1, np.float32)
    near, far = (float(v) for v in np.percentile(pick, [1, 99]))
    far = max(far, near + 1e-3)
    rgb = io.colorize_disparity(np.where(has, np.clip(far - z, 0, None), np.nan), max_disp=far - near)
    rgb = np.where((has & ~reliable)[..., None], np.uint8(UNRELIABLE_GREY), rgb).astype(np.uint8)
    legend = {"image": "depth_color.png", "colormap": "turbo, reversed", "unit": "m", "near": round(near, 3),
              "far": round(far, 3), "clipped": True, "no_depth": [0, 0, 0],
              "unreliable": [UNRELIABLE_GREY] * 3,
              "unreliable_means": "grey at half brightness, at every depth (depth_reliable.png = 0)",
              "reliable_when": f"disparity >= {RELIABLE_MIN_DISP:g} px (1 px of disparity error is at most 10 % of "
                               f"the depth) and confidence >= {RELIABLE_MIN_CONFIDENCE:g} where known",
              "reliable_to_m": round(float(z[shown].max()), 3) if shown.any() else None,
              "reliable_share_pct": round(float(shown.sum() / max(has.sum(), 1) * 100), 2),
              "note": "colour = colormap((far - depth) / (far - near)), clipped to 0..1; near and far = the 1st "
                      "and 99th percentiles of the reliable depths"}
    return rgb, legend


def write_prediction(out: Path, stem: str, disp, calib=None, image=None, ply=False, color_max=None,
                     max_depth: float | None = None, confidence=None, to_original=None):
    """Write disparity (KITTI png, PFM, colour png and its scale ``disparity_color.json``) and,
    with ``calib``, depth files: ``depth.png`` (uint16, 1/256 m, KITTI's convention), ``depth.npy``
    (float32 metres), ``depth_color.png`` with its scale ``depth_color.json``, and
    ``depth_reliable.png`` (255 where the depth can be trusted, :func:`depth_reliable`, with the
    ``confidence`` map when given); returns the written names. Pixels without an estimate (NaN,
    inf, negative) are 0 in the PNGs and the depth; with ``max_depth``, so are points farther
    than that (metres), and they are left out of points.ply. points.ply holds only measurable points:
    without ``max_depth``, none farther than :func:`stereojax.data.depth.measurable_depth` (where
    ``d + doffs`` < :data:`~stereojax.data.depth.MEASURABLE_DISP` = 2 px, one pixel of disparity error
    would more than double the depth: about 190 m on KITTI); ``max_depth`` replaces that limit, farther or
    nearer. The depth files keep those far pixels (mask them with depth_reliable.png).
    to_original(xyz): points.ply in another
    frame (the raw left camera's, :meth:`stereojax.data.stereo_rig.Rectifier.to_original`).

    points.ply's axes: x right, y down, z forward (OpenCV's camera frame), metres, origin at the
    left camera's centre (the rectified one, unless ``to_original`` moves them)."""

    written = []
    io.write_kitti_disparity(out / f"{stem}disparity.png", disp)
    io.write_pfm(out / f"{stem}disparity.pfm", disp)
    top = float(color_max or color_scale(disp))
    io.write_color_disparity(out / f"{stem}disparity_color.png", disp, max_disp=top)
    io.write_json(out / f"{stem}disparity_color.json", color_legend(top))
    written += [f"{stem}disparity.png", f"{stem}disparity.pfm", f"{stem}disparity_color.png",
                f"{stem}disparity_color.json"]
    if calib is not None:
        z = depth_mod.disparity_to_depth(disp, calib.baseline, calib.focal, calib.doffs)
        if max_depth is not None:
            z = np.where(z <= max_depth, z, 0.0).astype(np.float32)
        depth_mod.write_depth(out / f"{stem}depth.png", z)
        depth_mod.write_depth(out / f"{stem}depth.npy", z)
        reliable = depth_reliable(disp, confidence)
        rgb, legend = depth_color(z, reliable)
        io.write_png(out / f"{stem}depth_color.png", rgb)
        io.write_json(out / f"{stem}depth_color.json", {**legend, "image": f"{stem}depth_color.png"})
        io.write_png(out / f"{stem}depth_reliable.png", reliable & (z > 0))
        written += [f"{stem}depth.png", f"{stem}depth.npy", f"{stem}depth_color.png", f"{stem}depth_color.json",
                    f"{stem}depth_reliable.png"]
        if ply and image is not None:
            far = max_depth if max_depth is not None else depth_mod.measurable_depth(calib)
            xyz, rgb = depth_mod.point_cloud(disp, image, calib, max_depth=far)
            if to_original is not None:
                xyz = np.asarray(to_original(xyz), np.float32)
            depth_mod.write_ply(out / f"{stem}points.ply", xyz, rgb)
            written.append(f"{stem}points.ply")
    return written


def write_rectified(out: Path, rectifier, left, right, frame: str = "rectified") -> list[str]:
    """The rectified pair (``left_rectified.png``, ``right_rectified.png``) and the rectification
    (``rectification.json``: R1, R2, P1, P2, Q, and the frame of points.ply); returns the names."""
    io.write_png(out / "left_rectified.png", left)
    io.write_png(out / "right_rectified.png", right)
    io.write_json(out / "rectification.json", {**rectifier.to_json(), "points_frame": frame})
    return ["left_rectified.png", "right_rectified.png", "rectification.json"]
