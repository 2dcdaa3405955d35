"""Refinement: sub-pixel disparity from a parabola through the costs around the winner."""

from stereojax.refinement.parabola import subpixel, subpixel_volume

__all__ = ["subpixel", "subpixel_volume"]
