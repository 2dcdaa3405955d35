"""Models: the networks (``nets``), their checkpoints, and the registry of shipped weights
(``weights/``) with the chain settings that travel with them."""

from stereojax.models.registry import (BEST, SHIPPED, learned_config, load_model, resolve,
                                       shipped_weights, weights_path)

__all__ = [
    "BEST", "SHIPPED", "learned_config", "load_model", "resolve", "shipped_weights",
    "weights_path"
]
