"""Disparity selection: winner-takes-all of the left view, and of the right view from the left volume."""

from stereojax.disparity.right_view import right_cost_from_left, right_wta
from stereojax.disparity.winner_takes_all import wta, wta_volume

__all__ = ["wta", "wta_volume", "right_cost_from_left", "right_wta"]
