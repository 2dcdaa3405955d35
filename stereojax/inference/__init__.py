"""Inference: input checks, size buckets, the compiled programs of a chain, the Predictor,
memory checks and tiling. It runs what :mod:`stereojax.chain` gives it and names no method;
it never imports :mod:`stereojax.learning` or :mod:`stereojax.app`."""

from stereojax.inference.predictor import Predictor, disparity, stages

__all__ = ["Predictor", "disparity", "stages"]
