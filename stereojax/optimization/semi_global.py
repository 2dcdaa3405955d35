"""Semi-global matching (Hirschmueller 2008) along 4 or 8 paths with ``lax.fori_loop``.

For a path direction r, with C the matching cost ``f32[H, W, D]``:

    L_r(p, d) = C(p, d) + min(L_r(p - r, d),
                              L_r(p - r, d - 1) + P1, L_r(p - r, d + 1) + P1,
                              min_k L_r(p - r, k) + P2) - min_k L_r(p - r, k)

and the result is the mean of L_r over the paths (so it stays on the scale of C). A path
starts at the image border with L_r = C. Horizontal paths loop over x with an ``[H, D]``
carry; vertical and diagonal paths loop over y with a ``[W, D]`` carry (a diagonal path
shifts that carry by one column per row). Every path adds its L_r into one accumulator
volume in place (the accumulator is part of the loop carry and updated with
``dynamic_update_slice``), so the whole of SGM needs about one volume of extra memory.

Adaptive penalties (MC-CNN): with D1 = |I_L(p) - I_L(p - r)| and D2 = |I_R(p - d) -
I_R(p - d - r)|, both below ``grad_threshold``: P1, P2; one above: P1/q1, P2/q1; both above:
P1/q2, P2/q2. On diagonal paths only D1 is used. ``vertical_factor`` divides P1 on vertical
paths. Right-image columns left of the image (x - d < 0) repeat column 0, as the cost does.

Two kernels: the JAX kernel below (the reference, and the path on every platform other than
the CPU) and the native C++ kernel beside it (``semi_global.cc``, an XLA FFI call); the public
functions :func:`sgm` and :func:`sgm_volume` pick one by their ``kernels`` setting
(:mod:`stereojax.kernels`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from stereojax import kernels as kernels_mod
from stereojax.volume import BIG as _BIG, real_bounds, windows


def _path_step(prev: jax.Array, c: jax.Array, p1, p2) -> jax.Array:
    """One SGM recurrence step. prev, c: ``f32[N, D]``; p1, p2 broadcast to ``[N, D]``."""
    m = prev.min(axis=-1, keepdims=True)
    big = jnp.full_like(prev[:, :1], _BIG)
    lower = jnp.concatenate([big, prev[:, :-1]], axis=1)     # L(d - 1)
    upper = jnp.concatenate([prev[:, 1:], big], axis=1)      # L(d + 1)
    best = jnp.minimum(jnp.minimum(prev, jnp.minimum(lower, upper) + p1), m + p2)
    return c + best - m


def _step_into(total, cost, prev, i, axis: int, p1, p2):
    """One step of a path at row (axis 0) or column (axis 1) ``i``: the path cost there from
    ``prev``, added into ``total``; returns (path cost, total)."""
    out = _path_step(prev, jax.lax.dynamic_index_in_dim(cost, i, axis, keepdims=False), p1, p2)
    return out, _add_line(total, out, i, axis)


def _penalties(cfg, big_left, big_right, p1_scale=1.0):
    """Per-pixel (p1, p2) from boolean 'large gradient' maps (MC-CNN's rule).

    big_left: bool[N]; big_right: bool[N, D] or None (diagonal paths).
    """
    p1 = cfg.p1 / p1_scale
    if not cfg.adaptive:
        return jnp.float32(p1), jnp.float32(cfg.p2)
    n_big = big_left.astype(jnp.int32)[:, None]
    if big_right is not None:
        n_big = n_big + big_right.astype(jnp.int32)
    div = jnp.where(n_big == 0, 1.0, jnp.where(n_big == 1, cfg.q1, cfg.q2)).astype(jnp.float32)
    return p1 / div, cfg.p2 / div


def _gradient_big(grey, dy, dx, threshold):
    """bool[H, W]: |I(p) - I(p - r)| >= threshold for r = (dy, dx); False where p - r is outside."""
    h, w = grey.shape
    padded = jnp.pad(grey, 1, mode="edge")
    prev = padded[1 - dy: 1 - dy + h, 1 - dx: 1 - dx + w]
    big = jnp.abs(grey - prev) >= threshold
    ys, xs = jnp.arange(h)[:, None] - dy, jnp.arange(w)[None, :] - dx
    return big & (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)


def _row_path(cost, total, big_left, big_right, cfg, dy, shift=0, p1_scale=1.0, real=None):
    """Add one path that moves along y (dy = +1 down, -1 up) to ``total`` f32[H, W, D].

    big_left: bool[H, W]; big_right: bool[H, W] gradient map of the right image (None:
    not used); shift: the carry moves by ``shift`` columns per row (diagonal paths).
    """
    h, w, max_disp = cost.shape
    match_col = jnp.maximum(jnp.arange(w)[:, None] - jnp.arange(max_disp)[None, :], 0)   # [W, D]

    # rows r0 .. r1 - 1 are real (all without padding); the path runs over them only, so it
    # starts afresh where it enters the real pixels
    r0, r1 = (0, h) if real is None else (real[0], real[1])

    def body(i, carry):
        prev, total = carry
        y = r0 + i if dy == 1 else r1 - 1 - i
        if shift == 1:
            prev = jnp.concatenate([jnp.zeros_like(prev[:1]), prev[:-1]], axis=0)
        elif shift == -1:
            prev = jnp.concatenate([prev[1:], jnp.zeros_like(prev[:1])], axis=0)
        if real is not None and shift:   # a diagonal predecessor in the padding columns
            x_prev = jnp.arange(w) - shift
            prev = jnp.where(((x_prev < real[2]) | (x_prev >= real[3]))[:, None], 0.0, prev)
        bl = jax.lax.dynamic_index_in_dim(big_left, y, 0, keepdims=False)
        br = None
        if big_right is not None:
            br = jax.lax.dynamic_index_in_dim(big_right, y, 0, keepdims=False)[match_col]
        return _step_into(total, cost, prev, y, 0, *_penalties(cfg, bl, br, p1_scale))

    init = jnp.zeros((w, max_disp), cost.dtype)
    return jax.lax.fori_loop(0, r1 - r0, body, (init, total))[1]


def _column_path(cost, total, big_left, big_right, cfg, dx, real=None):
    """Add one horizontal path (dx = +1 left to right, -1 right to left) to ``total``."""
    h, w, max_disp = cost.shape
    if big_right is not None:
        # padded[:, D + x'] = big_right[:, max(x', -D)...]: columns left of the image repeat 0
        padded = jnp.pad(big_right, ((0, 0), (max_disp, 0)), mode="edge")

    # columns c0 .. c1 - 1 are real: the path runs over them only (see _row_path)
    c0, c1 = (0, w) if real is None else (real[2], real[3])

    def body(i, carry):
        prev, total = carry
        x = c0 + i if dx == 1 else c1 - 1 - i
        bl = jax.lax.dynamic_index_in_dim(big_left, x, 1, keepdims=False)
        br = None
        if big_right is not None:
            # columns x - d for d = 0 .. D-1, i.e. padded columns x + D - d, reversed slice
            br = jax.lax.dynamic_slice_in_dim(padded, x + 1, max_disp, axis=1)[:, ::-1]
        return _step_into(total, cost, prev, x, 1, *_penalties(cfg, bl, br))

    init = jnp.zeros((h, max_disp), cost.dtype)
    return jax.lax.fori_loop(0, c1 - c0, body, (init, total))[1]


def sgm_xla(cost: jax.Array, left: jax.Array, right: jax.Array, cfg, real=None) -> jax.Array:
    """The JAX kernel of :func:`sgm`. Semi-global matching of the left-view cost ``f32[H, W, D]``; returns ``f32[H, W, D]``.

    left, right: ``f32[H, W]`` grey images (for the adaptive penalties). cfg: SGMConfig.
    real: (first row, end row, first column, end column) of the real pixels of a pair padded to
    a size bucket (traced integers; None: all real); the paths run over them only, so they get
    exactly the result of the unpadded pair (the padding keeps 0).
    """
    if cfg.directions == 0:
        return cost
    thr = cfg.grad_threshold

    def right_big(dy, dx):
        return _gradient_big(right, dy, dx, thr) if cfg.adaptive else None

    total = jnp.zeros_like(cost)
    for dx in (1, -1):
        total = _column_path(cost, total, _gradient_big(left, 0, dx, thr), right_big(0, dx), cfg, dx,
                             real=real)
    for dy in (1, -1):
        total = _row_path(cost, total, _gradient_big(left, dy, 0, thr), right_big(dy, 0), cfg, dy,
                          p1_scale=cfg.vertical_factor, real=real)
    if cfg.directions == 8:
        for dy, dx in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            # the predecessor of column x on the previous row is x - dx: shift the carry by dx
            total = _row_path(cost, total, _gradient_big(left, dy, dx, thr), None, cfg, dy, shift=dx,
                              real=real)
    return total / cfg.directions


# ---- per-pixel disparity bands ---------------------------------------------------------------
# A pixel's costs cover its band [offset, offset + K). The recurrence reads the predecessor's
# path costs at the same absolute disparities d - 1, d, d + 1 (index d - offset_prev); outside
# the predecessor's band they are _BIG. min_k runs over the predecessor's band. A fresh start
# (the first line of a path, a diagonal entering from the side, a predecessor in the padding)
# is a predecessor of cost 0 with the pixel's own band, which gives L = C as in the full range.

def _band_step(prev, prev_off, c, off, p1, p2):
    """One banded SGM step: prev ``f32[N, K]`` with bands ``prev_off`` ``i32[N]``, the cost
    ``c`` ``f32[N, K]`` with bands ``off``; returns the path cost ``f32[N, K]`` in ``off``'s bands.

    The predecessor's L(d) and min(L(d - 1), L(d + 1)) are computed in its own band, padded with
    _BIG by K + 1 on each side, and each pixel reads its band of each as one window (a band shift
    |s| > K + 1 would read only padding, so it is clipped to K + 1). Two windows measured faster
    than three element gathers, and than one window of stacked pairs (docs/results.md)."""
    n, k = c.shape
    m = prev.min(axis=-1, keepdims=True)
    ext = jnp.pad(prev, ((0, 0), (k + 2, k + 2)), constant_values=_BIG)             # [N, 3K + 4]
    start = jnp.clip(off - prev_off, -(k + 1), k + 1) + k + 1
    same = windows(ext[:, 1:-1], start, k)
    near = windows(jnp.minimum(ext[:, :-2], ext[:, 2:]), start, k)
    best = jnp.minimum(jnp.minimum(same, near + p1), m + p2)
    return c + best - m


def _add_line(total, out, i, axis: int):
    """``total`` with ``out`` added to its row (axis 0) or column (axis 1) ``i``, in place."""
    line = jax.lax.dynamic_index_in_dim(total, i, axis, keepdims=False)
    return jax.lax.dynamic_update_index_in_dim(total, line + out, i, axis)


def _match_lines(big_right, max_disp: int):
    """``bool[H, W + D - 1]``: each row of ``big_right`` left-padded with its column 0 (the match
    columns x - d < 0 repeat column 0, as the cost does) and reversed, so that the pixel x with
    band offset o reads its match columns x - o - k, k = 0 .. K - 1, as one window starting at
    W - 1 - x + o (:func:`_match_window`)."""
    return jnp.pad(big_right, ((0, 0), (max_disp - 1, 0)), mode="edge")[:, ::-1]


def _match_window(lines, w: int, x, off, k: int):
    """bool[N, K]: big_right at the match columns x - off - k (k = 0 .. K - 1) from ``lines``
    (:func:`_match_lines` of an image ``w`` wide): one row ``[L]`` shared by the N pixels at
    columns ``x`` ``i32[N]`` (the row sweep), or N rows ``[N, L]`` at one column ``x`` (the
    column sweep). One window per pixel instead of K element gathers."""
    start = w - 1 - x + off
    if lines.ndim == 1:
        return jax.vmap(lambda st: jax.lax.dynamic_slice_in_dim(lines, st, k))(start)
    return windows(lines, start, k)


def _band_row_sweep(vol, total, specs, cfg, real=None):
    """Every path that moves along y, in one ``fori_loop`` over the rows (the paths are
    independent; one loop instead of one per path saves the per-step overhead, which dominates
    at small K). specs: (dy, shift, p1_scale, big_left bool[H, W], big_right bool[H, W] or None)."""
    cost, offset = vol.cost, vol.offset
    h, w, k = cost.shape
    r0, r1 = (0, h) if real is None else (real[0], real[1])
    xs = jnp.arange(w)

    def row_of(i, dy):
        return r0 + i if dy == 1 else r1 - 1 - i

    def body(i, carry):
        prevs, poffs, total = carry
        outs, offs_out, add = [], [], {}
        for (dy, shift, p1_scale, big_left, big_right), prev, poff in zip(specs, prevs, poffs):
            y = row_of(i, dy)
            off_y = jax.lax.dynamic_index_in_dim(offset, y, 0, keepdims=False)          # [W]
            if shift == 1:
                prev = jnp.concatenate([jnp.zeros_like(prev[:1]), prev[:-1]], axis=0)
                poff = jnp.concatenate([off_y[:1], poff[:-1]])
            elif shift == -1:
                prev = jnp.concatenate([prev[1:], jnp.zeros_like(prev[:1])], axis=0)
                poff = jnp.concatenate([poff[1:], off_y[-1:]])
            if shift:   # the first line starts afresh: the zero carry has the pixels' own bands
                poff = jnp.where(i == 0, off_y, poff)
            if real is not None and shift:
                x_prev = xs - shift
                fresh = (x_prev < real[2]) | (x_prev >= real[3])
                prev = jnp.where(fresh[:, None], 0.0, prev)
                poff = jnp.where(fresh, off_y, poff)
            bl = jax.lax.dynamic_index_in_dim(big_left, y, 0, keepdims=False)
            br = None
            if big_right is not None:
                line = jax.lax.dynamic_index_in_dim(big_right, y, 0, keepdims=False)
                br = _match_window(line, w, xs, off_y, k)
            c = jax.lax.dynamic_index_in_dim(cost, y, 0, keepdims=False)
            out = _band_step(prev, poff, c, off_y, *_penalties(cfg, bl, br, p1_scale))
            outs.append(out)
            offs_out.append(off_y)
            add[dy] = add[dy] + out if dy in add else out
        # one accumulator per direction of travel: two in-place updates of one buffer in the same
        # step made XLA copy it every step (measured 14 s instead of 0.4 s on a KITTI frame)
        totals = {dy: _add_line(total[dy], out, row_of(i, dy), 0) for dy, out in add.items()}
        return outs, offs_out, totals

    init_prev = [jnp.zeros((w, k), cost.dtype) for _ in specs]
    init_off = [jax.lax.dynamic_index_in_dim(offset, row_of(0, sp[0]), 0, keepdims=False) for sp in specs]
    dys = sorted({sp[0] for sp in specs})
    totals = {dy: (total if j == 0 else jnp.zeros_like(total)) for j, dy in enumerate(dys)}
    totals = jax.lax.fori_loop(0, r1 - r0, body, (init_prev, init_off, totals))[2]
    return sum(totals.values())


def _band_column_sweep(vol, total, specs, cfg, real=None):
    """Both horizontal paths (specs: (dx, big_left, big_right)) in one ``fori_loop`` over x."""
    cost, offset = vol.cost, vol.offset
    h, w, k = cost.shape
    c0, c1 = (0, w) if real is None else (real[2], real[3])

    def col_of(i, dx):
        return c0 + i if dx == 1 else c1 - 1 - i

    def body(i, carry):
        prevs, poffs, total = carry
        outs, offs_out = [], []
        for (dx, big_left, big_right), prev in zip(specs, prevs):
            x = col_of(i, dx)
            off_x = jax.lax.dynamic_index_in_dim(offset, x, 1, keepdims=False)          # [H]
            bl = jax.lax.dynamic_index_in_dim(big_left, x, 1, keepdims=False)
            br = None
            if big_right is not None:
                br = _match_window(big_right, w, x, off_x, k)
            c = jax.lax.dynamic_index_in_dim(cost, x, 1, keepdims=False)
            outs.append(_band_step(prev, poffs[len(outs)], c, off_x, *_penalties(cfg, bl, br)))
            offs_out.append(off_x)
        # one accumulator per path (see _band_row_sweep)
        totals = [_add_line(t, out, col_of(i, sp[0]), 1) for t, sp, out in zip(total, specs, outs)]
        return outs, offs_out, totals

    init_prev = [jnp.zeros((h, k), cost.dtype) for _ in specs]
    init_off = [jax.lax.dynamic_index_in_dim(offset, col_of(0, sp[0]), 1, keepdims=False) for sp in specs]
    totals = [total] + [jnp.zeros_like(total) for _ in specs[1:]]
    totals = jax.lax.fori_loop(0, c1 - c0, body, (init_prev, init_off, totals))[2]
    return sum(totals)


def sgm_volume_xla(vol, left: jax.Array, right: jax.Array, cfg):
    """The JAX kernel of :func:`sgm_volume`. SGM of a :class:`~stereojax.volume.CostVolume` (left view); returns one with the same bands.

    Full range: :func:`sgm`. Bands: see the comment above :func:`_band_step`; a band covering
    the whole range gives :func:`sgm`. The paths run over the volume's real pixels only.
    """
    if cfg.directions == 0:
        return vol
    real = real_bounds(vol.valid)
    if not vol.banded:
        return vol.with_cost(sgm_xla(vol.cost, left, right, cfg, real))
    thr = cfg.grad_threshold

    def right_big(dy, dx):   # in the layout of _match_lines
        return _match_lines(_gradient_big(right, dy, dx, thr), vol.max_disp) if cfg.adaptive else None

    total = jnp.zeros_like(vol.cost)
    total = _band_column_sweep(vol, total, [(dx, _gradient_big(left, 0, dx, thr), right_big(0, dx))
                                            for dx in (1, -1)], cfg, real)
    rows = [(dy, 0, cfg.vertical_factor, _gradient_big(left, dy, 0, thr), right_big(dy, 0)) for dy in (1, -1)]
    if cfg.directions == 8:
        rows += [(dy, dx, 1.0, _gradient_big(left, dy, dx, thr), None)
                 for dy, dx in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
    total = _band_row_sweep(vol, total, rows, cfg, real)
    return vol.with_cost(total / cfg.directions)


# ---- the native kernel (semi_global.cc) and the switch ----------------------------------------

def penalty_table(cfg) -> np.ndarray:
    """``f32[18]``: P1 (3) then P2 (3) by the number of large grey-level steps (0, 1, 2), for the
    horizontal, vertical and diagonal paths, computed as :func:`_penalties` computes them."""
    rows = []
    for scale in (1.0, cfg.vertical_factor, 1.0):
        p1, p2 = np.float32(cfg.p1 / scale), np.float32(cfg.p2)
        div = np.array([1.0, cfg.q1, cfg.q2] if cfg.adaptive else [1.0, 1.0, 1.0], np.float32)
        rows += [p1 / div, p2 / div] if cfg.adaptive else [np.full(3, p1, np.float32), np.full(3, p2, np.float32)]
    return np.concatenate(rows).astype(np.float32)


def _bounds(shape, real) -> jax.Array:
    h, w = shape
    if real is None:
        return jnp.array([0, h, 0, w], jnp.int32)
    return jnp.stack([jnp.asarray(r, jnp.int32) for r in real])


def sgm_native(cost, offset, left, right, cfg, real=None, max_disp=None, banded=True) -> jax.Array:
    """The native kernel (``semi_global.cc``): SGM of the band ``[offset, offset + K)`` costs
    ``f32[H, W, K]`` (the full range: offset 0, K = D, ``banded=False``); the result of
    :func:`sgm_volume_xla` / :func:`sgm_xla`."""
    h, w, k = cost.shape
    call = jax.ffi.ffi_call("stereojax_sgm", jax.ShapeDtypeStruct(cost.shape, jnp.float32),
                            vmap_method="sequential")
    return call(cost.astype(jnp.float32), offset.astype(jnp.int32), left.astype(jnp.float32),
                right.astype(jnp.float32), _bounds((h, w), real),
                directions=np.int32(cfg.directions), max_disp=np.int32(max_disp or k),
                banded=np.int32(bool(banded)), adaptive=np.int32(bool(cfg.adaptive)),
                threshold=np.float32(cfg.grad_threshold), penalties=penalty_table(cfg),
                threads=np.int32(min(kernels_mod.threads(), 2)))


def sgm(cost: jax.Array, left: jax.Array, right: jax.Array, cfg, real=None, kernels: str = "auto") -> jax.Array:
    """Semi-global matching of the left-view cost ``f32[H, W, D]``; returns ``f32[H, W, D]``.

    left, right: ``f32[H, W]`` grey images (for the adaptive penalties). cfg: SGMConfig.
    real: (first row, end row, first column, end column) of the real pixels of a pair padded to
    a size bucket (traced integers; None: all real); the paths run over them only, so they get
    exactly the result of the unpadded pair (the padding keeps 0). kernels: see
    :mod:`stereojax.kernels`.
    """
    if cfg.directions == 0:
        return cost

    def native(c, l, r):
        return sgm_native(c, jnp.zeros(c.shape[:2], jnp.int32), l, r, cfg, real, banded=False)

    return kernels_mod.select(kernels, native, functools.partial(sgm_xla, cfg=cfg, real=real), cost, left, right)


def sgm_volume(vol, left: jax.Array, right: jax.Array, cfg, kernels: str = "auto"):
    """SGM of a :class:`~stereojax.volume.CostVolume` (left view); returns one with the same
    bands (see :func:`sgm_volume_xla`), with the kernel of the ``kernels`` setting."""
    if cfg.directions == 0:
        return vol

    def native(v, l, r):
        return v.with_cost(sgm_native(v.cost, v.offset, l, r, cfg, real_bounds(v.valid), v.max_disp, v.banded))

    return kernels_mod.select(kernels, native, functools.partial(sgm_volume_xla, cfg=cfg), vol, left, right)
