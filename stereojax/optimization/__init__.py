"""Cost optimisation: semi-global matching along 4 or 8 paths (``jax.lax.scan``)."""

from stereojax.optimization.semi_global import sgm, sgm_volume

__all__ = ["sgm", "sgm_volume"]
