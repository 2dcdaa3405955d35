"""Filters of the disparity map: exact median, and joint bilateral guided by the left image."""

from stereojax.filters.bilateral import bilateral_filter
from stereojax.filters.median import median_filter

__all__ = ["median_filter", "bilateral_filter"]
