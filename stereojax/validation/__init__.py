"""Validation: the left-right check, filling of the pixels it rejects, and a per-pixel confidence."""

from stereojax.validation.confidence_measure import confidence, confidence_volume
from stereojax.validation.filling import fill_disparity
from stereojax.validation.left_right import CORRECT, MISMATCH, OCCLUSION, lr_check

__all__ = [
    "CORRECT", "MISMATCH", "OCCLUSION", "lr_check", "fill_disparity", "confidence",
    "confidence_volume"
]
