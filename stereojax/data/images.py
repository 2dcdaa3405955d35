"""Input images to grey ``f32[H, W]`` in 0..255, with one-line errors for what cannot be an image.

Shared by inference (:func:`stereojax.inference.prepare.prepare_pair`) and training
(:mod:`stereojax.learning.sampling`, :mod:`stereojax.learning.train`), so that training never imports the
inference module.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from stereojax.errors import StereoInputError


def as_grey(image: Any, name: str, float_scale: float | None = None) -> np.ndarray:
    """Validate one image and return grey ``f32[H, W]`` in 0..255 (numpy).

    uint8 is taken as it is, uint16 is divided by 257, float images are taken as 0..1 when
    their maximum is <= 1 (``float_scale`` None) and as 0..255 otherwise; ``float_scale``
    forces the factor (a pair decides it once for both images).
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[..., :3]
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise StereoInputError(f"{name} image must be HxW grey or HxWx3 colour, got shape {arr.shape}")
    if arr.dtype == np.bool_ or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise StereoInputError(f"{name} image must have an integer or float dtype, got {arr.dtype}")
    if arr.size == 0:
        raise StereoInputError(f"{name} image is empty (shape {arr.shape})")
    is_float = np.issubdtype(arr.dtype, np.floating)
    if is_float:
        bad = ~np.isfinite(arr)
        if bad.any():
            y, x = np.argwhere(bad)[0][:2]
            raise StereoInputError(f"{name} image contains {int(bad.sum())} NaN or infinite value(s) "
                                   f"(first at row {y}, column {x}); expected finite intensities")
        lo, hi = float(arr.min()), float(arr.max())
        if lo < 0 or hi > 255:
            raise StereoInputError(f"{name} float image must have intensities in [0, 1] or [0, 255], "
                                   f"found [{lo:g}, {hi:g}]")
        arr = arr.astype(np.float64)
        scale = float_scale if float_scale is not None else (255.0 if hi <= 1.0 else 1.0)
        if scale != 1.0:
            arr = arr * scale
    elif arr.dtype == np.uint16:
        arr = arr.astype(np.float64) / 257.0
    elif arr.dtype != np.uint8 and (arr.min() < 0 or arr.max() > 255):
        raise StereoInputError(f"{name} image of dtype {arr.dtype} must have intensities in "
                               f"[0, 255] (or be uint16), found [{arr.min()}, {arr.max()}]")
    else:
        arr = arr.astype(np.float64)
    if arr.ndim == 3:
        arr = arr[..., 0] * 0.299 + arr[..., 1] * 0.587 + arr[..., 2] * 0.114
        if not is_float:   # integer colour -> integer grey levels, as OpenCV's cvtColor
            arr = np.round(arr)
    return np.ascontiguousarray(arr, dtype=np.float32)


def pair_float_scale(left: np.ndarray, right: np.ndarray) -> float | None:
    """One scale for the float images of a pair: 0..1 only when every float image is."""
    floats = [a for a in (left, right) if np.issubdtype(a.dtype, np.floating) and a.size
              and np.all(np.isfinite(a))]
    if not floats:
        return None
    return 255.0 if max(float(a.max()) for a in floats) <= 1.0 else 1.0


def to_u8(image: np.ndarray) -> np.ndarray:
    """uint8 grey image from grey or RGB, uint8 / uint16 / float input (for OpenCV's matchers)."""
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = (img / 257.0).round().astype(np.uint8)
    elif img.dtype != np.uint8:
        scale = 255.0 if img.max() <= 1.0 else 1.0
        img = np.clip(img * scale, 0, 255).round().astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2GRAY)
    return img
