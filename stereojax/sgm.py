"""Semi-global matching (Hirschmueller 2008) along 4 or 8 paths with ``lax.scan``.

For a path direction r, with C the matching cost ``f32[H, W, D]``:

    L_r(p, d) = C(p, d) + min(L_r(p - r, d),
                              L_r(p - r, d - 1) + P1, L_r(p - r, d + 1) + P1,
                              min_k L_r(p - r, k) + P2) - min_k L_r(p - r, k)

and the result is the mean of L_r over the paths (so it stays on the scale of C). A path
starts at the image border with L_r = C. Horizontal paths scan over x with an ``[H, D]``
carry; vertical and diagonal paths scan over y with a ``[W, D]`` carry (a diagonal path
shifts that carry by one column per row).

Adaptive penalties (MC-CNN): with D1 = |I_L(p) - I_L(p - r)| and D2 = |I_R(p - d) -
I_R(p - d - r)|, both below ``grad_threshold``: P1, P2; one above: P1/q1, P2/q1; both above:
P1/q2, P2/q2. On diagonal paths only D1 is used. ``vertical_factor`` divides P1 on vertical
paths.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .cost import shifted_stack

_BIG = 1e9   # finite stand-in for +inf outside the disparity range


def _path_step(prev: jax.Array, c: jax.Array, p1: jax.Array, p2: jax.Array) -> jax.Array:
    """One SGM recurrence step. prev, c: ``f32[N, D]``; p1, p2 broadcast to ``[N, D]``."""
    m = prev.min(axis=-1, keepdims=True)
    big = jnp.full_like(prev[:, :1], _BIG)
    lower = jnp.concatenate([big, prev[:, :-1]], axis=1)     # L(d - 1)
    upper = jnp.concatenate([prev[:, 1:], big], axis=1)      # L(d + 1)
    best = jnp.minimum(jnp.minimum(prev, jnp.minimum(lower, upper) + p1), m + p2)
    return c + best - m


def _penalties(cfg, big_left, big_right, p1_scale=1.0):
    """Per-pixel (p1, p2) from boolean 'large gradient' maps (MC-CNN's rule)."""
    p1 = cfg.p1 / p1_scale
    if not cfg.adaptive:
        return jnp.float32(p1), jnp.float32(cfg.p2)
    n_big = big_left.astype(jnp.int32)[:, None] + big_right.astype(jnp.int32)
    div = jnp.where(n_big == 0, 1.0, jnp.where(n_big == 1, cfg.q1, cfg.q2)).astype(jnp.float32)
    return p1 / div, cfg.p2 / div


def _scan(cost_t, big_left_t, big_right_t, cfg, reverse=False, carry_shift=0, p1_scale=1.0):
    """Run one path over the leading axis of ``cost_t`` f32[T, N, D]; returns f32[T, N, D].

    big_left_t: bool[T, N]; big_right_t: bool[T, N, D] (or None when not adaptive).
    carry_shift: +1 / -1 shifts the carry one position along N per step (diagonal paths).
    """
    def body(prev, xs):
        c, bl, br = xs
        if carry_shift == 1:
            prev = jnp.concatenate([jnp.zeros_like(prev[:1]), prev[:-1]], axis=0)
        elif carry_shift == -1:
            prev = jnp.concatenate([prev[1:], jnp.zeros_like(prev[:1])], axis=0)
        p1, p2 = _penalties(cfg, bl, br, p1_scale)
        out = _path_step(prev, c, p1, p2)
        return out, out

    init = jnp.zeros(cost_t.shape[1:], cost_t.dtype)
    _, out = jax.lax.scan(body, init, (cost_t, big_left_t, big_right_t), reverse=reverse)
    return out


def _gradient_big(grey, dy, dx, threshold):
    """bool[H, W]: |I(p) - I(p - r)| >= threshold for r = (dy, dx); False where p - r is outside."""
    h, w = grey.shape
    padded = jnp.pad(grey, 1, mode="edge")
    prev = padded[1 - dy: 1 - dy + h, 1 - dx: 1 - dx + w]
    big = jnp.abs(grey - prev) >= threshold
    ys, xs = jnp.arange(h)[:, None] - dy, jnp.arange(w)[None, :] - dx
    return big & (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)


def sgm(cost: jax.Array, left: jax.Array, right: jax.Array, cfg) -> jax.Array:
    """Semi-global matching of the left-view cost ``f32[H, W, D]``; returns ``f32[H, W, D]``.

    left, right: ``f32[H, W]`` grey images (for the adaptive penalties). cfg: SGMConfig.
    """
    if cfg.directions == 0:
        return cost
    h, w, max_disp = cost.shape
    thr = cfg.grad_threshold

    def right_big(dy, dx):
        # big_right[y, x, d] = large gradient of the right image at (y, x - d) along r
        if not cfg.adaptive:
            return jnp.zeros((h, w, max_disp), jnp.bool_)
        return shifted_stack(_gradient_big(right, dy, dx, thr), max_disp, "left")

    no_right = jnp.zeros((h, w, max_disp), jnp.bool_)
    total = jnp.zeros_like(cost)

    # horizontal paths: scan over x
    cost_x = jnp.swapaxes(cost, 0, 1)                                         # [W, H, D]
    for dx, rev in ((1, False), (-1, True)):
        bl = jnp.swapaxes(_gradient_big(left, 0, dx, thr), 0, 1)
        br = jnp.swapaxes(right_big(0, dx), 0, 1)
        total = total + jnp.swapaxes(_scan(cost_x, bl, br, cfg, reverse=rev), 0, 1)

    # vertical paths: scan over y
    for dy, rev in ((1, False), (-1, True)):
        bl = _gradient_big(left, dy, 0, thr)
        total = total + _scan(cost, bl, right_big(dy, 0), cfg, reverse=rev,
                              p1_scale=cfg.vertical_factor)

    if cfg.directions == 8:
        for dy, dx in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            bl = _gradient_big(left, dy, dx, thr)
            br = no_right
            # scanning down (dy = 1) the predecessor of x is x - dx: shift the carry by dx;
            # scanning up (reverse) the same holds with the path's own dx.
            total = total + _scan(cost, bl, br, cfg, reverse=(dy == -1), carry_shift=dx)
    return total / cfg.directions
