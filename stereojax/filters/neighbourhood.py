"""Shifted copies of an image over a square window: the shared step of the filters."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def edge_windows(image: jax.Array, radius: int) -> jax.Array:
    """``[K, H, W]`` stack of the (2r+1)^2 edge-replicated shifts of ``image``."""
    h, w = image.shape
    padded = jnp.pad(image, radius, mode="edge")
    k = 2 * radius + 1
    return jnp.stack([padded[i:i + h, j:j + w] for i in range(k) for j in range(k)])
