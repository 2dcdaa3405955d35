"""Cost aggregation: cross-based cost aggregation (CBCA) over each pixel's cross-shaped support."""

from stereojax.aggregation.cross_based import Arms, cbca, cbca_volume, cross_arms

__all__ = ["Arms", "cbca", "cbca_volume", "cross_arms"]
