"""Exact median filter of a disparity map."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stereojax.filters.neighbourhood import edge_windows


def median_filter(disp: jax.Array, size: int = 5) -> jax.Array:
    """Exact median over a size x size window (edge replicated); ``f32[H, W]``.

    Uses forgetful selection (Paeth): keep n // 2 + 2 candidates, repeatedly drop their
    minimum and maximum and take in the next window value. Only element-wise min/max, so
    XLA fuses it into one pass (about 100x faster on CPU than sorting the windows).
    """
    if size <= 1:
        return disp
    values = list(edge_windows(disp.astype(jnp.float32), size // 2))
    keep = len(values) // 2 + 2
    buf, rest = values[:keep], values[keep:]
    while True:
        for i in range(1, len(buf)):              # minimum to the front
            buf[0], buf[i] = jnp.minimum(buf[0], buf[i]), jnp.maximum(buf[0], buf[i])
        for i in range(1, len(buf) - 1):          # maximum to the back
            buf[i], buf[-1] = jnp.minimum(buf[i], buf[-1]), jnp.maximum(buf[i], buf[-1])
        buf = buf[1:-1]
        if not rest:
            return buf[0]
        buf.append(rest.pop(0))
