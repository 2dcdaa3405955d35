"""Disparity selection and refinement: WTA, left-right check and filling, sub-pixel, filters.

Conventions: disparity maps are ``f32[H, W]`` or ``i32[H, W]``; a left pixel (y, x) with
disparity d matches the right pixel (y, x - d).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .volume import BIG

# labels of the left-right check
CORRECT, MISMATCH, OCCLUSION = 0, 1, 2


def wta(cost: jax.Array) -> jax.Array:
    """``i32[H, W]`` winner-takes-all disparity of ``f32[H, W, D]`` cost (first minimum wins)."""
    return jnp.argmin(cost, axis=-1).astype(jnp.int32)


def confidence(cost: jax.Array, disp_wta: jax.Array, disp_right: jax.Array | None,
               lr_tolerance: float = 1.0, absolute=None) -> jax.Array:
    """Per-pixel confidence in [0, 1] of the winner-takes-all disparity, ``f32[H, W]``.

    The product of two terms: the *margin* of the aggregated cost ``f32[H, W, D]`` between its
    best disparity d1 and the best one at least 2 away, as ``(c2 - c1) / c2`` (0 when a rival
    is as good; 1 when the winner costs nothing), and the *left-right agreement*
    ``exp(-max(|d1 - D_R(x - d1)| - lr_tolerance, 0))`` (1 where the two views agree, smaller
    the more they differ; 0.5 where the match x - d1 leaves the right image and cannot be
    checked). Without a right view (``disp_right`` None) the margin alone. ``absolute``: the
    absolute disparity of ``disp_wta`` when ``cost`` is a band (``disp_wta`` its index)."""
    h, w, max_disp = cost.shape
    d1 = disp_wta.astype(jnp.int32)
    c1 = jnp.take_along_axis(cost, d1[..., None], axis=-1)[..., 0]
    near = jnp.abs(jnp.arange(max_disp)[None, None, :] - d1[..., None]) <= 1
    c2 = jnp.min(jnp.where(near, jnp.inf, cost), axis=-1)
    c2 = jnp.where(jnp.isfinite(c2), c2, c1)               # D <= 3: no rival
    margin = jnp.where(c2 > 0, jnp.clip((c2 - c1) / jnp.maximum(c2, 1e-12), 0.0, 1.0), 0.0)
    if disp_right is None:
        return margin
    if absolute is not None:
        d1 = absolute.astype(jnp.int32)
    xr = jnp.arange(w)[None, :] - d1
    dr = jnp.take_along_axis(disp_right.astype(jnp.float32), jnp.clip(xr, 0, w - 1), axis=1)
    agree = jnp.exp(-jnp.maximum(jnp.abs(d1.astype(jnp.float32) - dr) - lr_tolerance, 0.0))
    return margin * jnp.where(xr >= 0, agree, 0.5)


def right_cost_from_left(cost: jax.Array, invalid: float = 1.0, valid_width=None) -> jax.Array:
    """Right-view volume from the left one: C_R[y, x, d] = C_L[y, x + d, d].

    Entries with x + d >= W (or >= ``valid_width``, the real width of a pair padded on the
    right) get ``invalid``. Returns ``f32[H, W, D]``.
    """
    h, w, max_disp = cost.shape
    # per-disparity [H, W] slices (padding a slice, not the volume, keeps memory at one volume
    # and lets XLA fuse the skew into a consumer such as argmin)
    cols = [jnp.pad(cost[:, d:, d], ((0, 0), (0, d)), constant_values=invalid) for d in range(max_disp)]
    vol = jnp.stack(cols, axis=-1)
    if valid_width is None:
        return vol
    inside = jnp.arange(w)[:, None] + jnp.arange(max_disp)[None, :] < valid_width      # [W, D]
    return jnp.where(inside[None], vol, invalid)


def lr_check(disp_left: jax.Array, disp_right: jax.Array, max_disp: int,
             tolerance: float = 1.0) -> jax.Array:
    """Label every left pixel CORRECT, MISMATCH or OCCLUSION (MC-CNN's rule); ``i32[H, W]``.

    correct: |d - D_R(x - d)| <= tolerance. Otherwise mismatch if some disparity d' < max_disp
    has D_R(x - d') == d' (the pixel would be visible at another disparity), else occlusion.
    """
    h, w = disp_left.shape
    x = jnp.arange(w)[None, :]
    d = jnp.round(disp_left).astype(jnp.int32)
    xr = x - d
    dr = jnp.take_along_axis(disp_right, jnp.clip(xr, 0, w - 1), axis=1)
    correct = (xr >= 0) & (jnp.abs(disp_left - dr) <= tolerance)

    # "some d' has D_R(x - d') == d'" is "some right pixel x' = x - d' lands on x = x' + D_R(x')":
    # one scatter of the right pixels onto their left matches instead of a loop over the range
    r = jnp.round(disp_right).astype(jnp.int32)
    target = jnp.where((r >= 0) & (r < max_disp), x + r, w)                   # w: dropped
    rows = jnp.broadcast_to(jnp.arange(h)[:, None], (h, w))
    seen = jnp.zeros((h, w), jnp.bool_).at[rows, target].set(True, mode="drop")
    return jnp.where(correct, CORRECT, jnp.where(seen, MISMATCH, OCCLUSION)).astype(jnp.int32)


def _propagate(values: jax.Array, valid: jax.Array, axis: int, reverse: bool):
    """Nearest valid value along ``axis`` seen so far (scan order), and whether one exists."""
    def body(carry, xs):
        last, have = carry
        v, ok = xs
        last = jnp.where(ok, v, last)
        have = have | ok
        return (last, have), (last, have)

    v = jnp.moveaxis(values, axis, 0)
    ok = jnp.moveaxis(valid, axis, 0)
    init = (jnp.zeros_like(v[0]), jnp.zeros_like(ok[0]))
    _, (last, have) = jax.lax.scan(body, init, (v, ok), reverse=reverse)
    return jnp.moveaxis(last, 0, axis), jnp.moveaxis(have, 0, axis)


def _propagate_diagonal(values, valid, dy: int, dx: int):
    """Nearest valid value met walking from p in direction (-dy, -dx) (scan along y, shifting x)."""
    def shift(a, fill):
        if dx == 1:
            return jnp.concatenate([jnp.full_like(a[:1], fill), a[:-1]], axis=0)
        return jnp.concatenate([a[1:], jnp.full_like(a[:1], fill)], axis=0)

    def body(carry, xs):
        last, have = carry
        last, have = shift(last, 0), shift(have, False)
        v, ok = xs
        last = jnp.where(ok, v, last)
        have = have | ok
        return (last, have), (last, have)

    init = (jnp.zeros_like(values[0]), jnp.zeros_like(valid[0]))
    _, (last, have) = jax.lax.scan(body, init, (values, valid), reverse=(dy == -1))
    return last, have


#: Batcher's odd-even merge sort of 8 values: 19 compare-exchanges (tests/test_kernels.py checks
#: it on every 0/1 input, which proves it sorts everything)
SORT8 = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (1, 2), (5, 6),
         (0, 4), (1, 5), (2, 6), (3, 7), (2, 4), (3, 5), (1, 2), (3, 4), (5, 6))


def sort8(values: list) -> list:
    """8 arrays of one shape sorted elementwise (ascending) by :data:`SORT8`: elementwise min and
    max, about 8x faster on the CPU than ``jnp.sort`` over a stacked axis of 8."""
    v = list(values)
    for i, j in SORT8:
        v[i], v[j] = jnp.minimum(v[i], v[j]), jnp.maximum(v[i], v[j])
    return v


def fill_disparity(disp: jax.Array, labels: jax.Array) -> jax.Array:
    """Fill non-CORRECT pixels of ``f32[H, W]`` disparity (MC-CNN's interpolation).

    Occluded pixels take the nearest correct disparity to their left (the background; to
    their right where the row has none on the left). Mismatched pixels take the median of the
    nearest correct disparities found along 8 directions. Pixels with no correct pixel in any
    direction keep their value.
    """
    disp = disp.astype(jnp.float32)
    good = labels == CORRECT
    left_v, left_ok = _propagate(disp, good, axis=1, reverse=False)
    right_v, right_ok = _propagate(disp, good, axis=1, reverse=True)
    up_v, up_ok = _propagate(disp, good, axis=0, reverse=False)
    down_v, down_ok = _propagate(disp, good, axis=0, reverse=True)
    diag = [_propagate_diagonal(disp, good, dy, dx) for dy, dx in ((1, 1), (1, -1), (-1, 1), (-1, -1))]

    occl_fill = jnp.where(left_ok, left_v, jnp.where(right_ok, right_v, disp))

    cands = jnp.stack([left_v, right_v, up_v, down_v] + [v for v, _ in diag])
    oks = jnp.stack([left_ok, right_ok, up_ok, down_ok] + [o for _, o in diag])
    # median over the available candidates: sort with missing ones pushed to +inf
    srt = jnp.stack(sort8(list(jnp.where(oks, cands, jnp.float32(BIG)))))
    n = oks.sum(0)
    lo = jnp.take_along_axis(srt, jnp.clip((n - 1) // 2, 0, 7)[None], axis=0)[0]
    hi = jnp.take_along_axis(srt, jnp.clip(n // 2, 0, 7)[None], axis=0)[0]
    mism_fill = jnp.where(n > 0, 0.5 * (lo + hi), disp)

    return jnp.where(labels == OCCLUSION, occl_fill, jnp.where(labels == MISMATCH, mism_fill, disp))


def subpixel(cost: jax.Array, disp: jax.Array) -> jax.Array:
    """Parabola fit through the costs at d - 1, d, d + 1 around integer ``disp``; ``f32[H, W]``.

    d_sub = d - (C+ - C-) / (2 (C+ - 2 C + C-)), applied where 0 < d < D - 1, neither
    neighbour lies outside the pixel's limits (:data:`~stereojax.volume.BIG`) and the
    parabola opens upwards; the offset is clamped to [-0.5, 0.5].
    """
    max_disp = cost.shape[-1]
    d = jnp.clip(jnp.round(disp).astype(jnp.int32), 0, max_disp - 1)
    c0 = jnp.take_along_axis(cost, d[..., None], axis=-1)[..., 0]
    cm = jnp.take_along_axis(cost, jnp.clip(d - 1, 0, max_disp - 1)[..., None], axis=-1)[..., 0]
    cp = jnp.take_along_axis(cost, jnp.clip(d + 1, 0, max_disp - 1)[..., None], axis=-1)[..., 0]
    denom = cp - 2.0 * c0 + cm
    ok = (d > 0) & (d < max_disp - 1) & (denom > 1e-12) & (jnp.maximum(cm, cp) < 0.5 * BIG)
    offset = jnp.clip((cp - cm) / (2.0 * jnp.where(ok, denom, 1.0)), -0.5, 0.5)
    return d.astype(jnp.float32) - jnp.where(ok, offset, 0.0)


def _windows(image: jax.Array, radius: int) -> jax.Array:
    """``[K, H, W]`` stack of the (2r+1)^2 edge-replicated shifts of ``image``."""
    h, w = image.shape
    padded = jnp.pad(image, radius, mode="edge")
    k = 2 * radius + 1
    return jnp.stack([padded[i:i + h, j:j + w] for i in range(k) for j in range(k)])


def median_filter(disp: jax.Array, size: int = 5) -> jax.Array:
    """Exact median over a size x size window (edge replicated); ``f32[H, W]``.

    Uses forgetful selection (Paeth): keep n // 2 + 2 candidates, repeatedly drop their
    minimum and maximum and take in the next window value. Only element-wise min/max, so
    XLA fuses it into one pass (about 100x faster on CPU than sorting the windows).
    """
    if size <= 1:
        return disp
    values = list(_windows(disp.astype(jnp.float32), size // 2))
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


def bilateral_filter(disp: jax.Array, guide: jax.Array, radius: int, sigma_space: float,
                     sigma_range: float) -> jax.Array:
    """Joint bilateral filter of disparity ``f32[H, W]`` guided by grey image ``f32[H, W]``.

    Weight of neighbour q for p: exp(-|p - q|^2 / 2 s_s^2) * exp(-(I(p) - I(q))^2 / 2 s_r^2).
    """
    if radius == 0:
        return disp
    k = 2 * radius + 1
    dy, dx = jnp.meshgrid(jnp.arange(k) - radius, jnp.arange(k) - radius, indexing="ij")
    spatial = jnp.exp(-(dy ** 2 + dx ** 2) / (2.0 * sigma_space ** 2)).reshape(-1, 1, 1)
    g = _windows(guide.astype(jnp.float32), radius)
    wgt = spatial * jnp.exp(-((g - guide[None]) ** 2) / (2.0 * sigma_range ** 2))
    disp = disp.astype(jnp.float32)
    # written as a correction of the centre value, so that constant regions stay exact
    d = _windows(disp, radius) - disp[None]
    return disp + (wgt * d).sum(0) / wgt.sum(0)


# ---- per-pixel disparity bands (stereojax.volume.CostVolume) ---------------------------------

def wta_volume(vol) -> jax.Array:
    """``i32[H, W]`` winner-takes-all absolute disparity of a CostVolume (first minimum wins)."""
    return wta(vol.cost) + (vol.offset if vol.banded else 0)


def right_wta(vol, right_offset, invalid: float = 1.0) -> jax.Array:
    """``i32[H, W]`` WTA disparity of the right view, from the left volume:
    C_R(x, d) = C_L(x + d, d), for d in the right view's band ``[right_offset, right_offset + K)``
    (full range: :func:`right_cost_from_left`). Entries with x + d beyond the real width get
    ``invalid``, as in the full range; entries where d lies outside the left pixel's band get
    :data:`~stereojax.volume.BIG`."""
    vw = None if vol.valid is None else vol.valid[1]
    if not vol.banded:
        return wta(right_cost_from_left(vol.cost, invalid, vw))
    h, w, k = vol.cost.shape
    width = w if vw is None else vw
    d = right_offset[..., None] + jnp.arange(k, dtype=jnp.int32)               # [H, W, K]
    xl = jnp.arange(w)[None, :, None] + d
    in_image = xl < width
    xl = jnp.clip(xl, 0, w - 1)
    off_l = jnp.take_along_axis(vol.offset, xl.reshape(h, -1), axis=1).reshape(h, w, k)
    j = d - off_l
    in_band = (j >= 0) & (j < k)
    flat = (xl * k + jnp.clip(j, 0, k - 1)).reshape(h, -1)
    c = jnp.take_along_axis(vol.cost.reshape(h, w * k), flat, axis=1).reshape(h, w, k)
    c = jnp.where(in_image, jnp.where(in_band, c, BIG), invalid)
    return wta(c) + right_offset


def subpixel_volume(vol, disp: jax.Array) -> jax.Array:
    """:func:`subpixel` on a CostVolume: the parabola through the costs at d - 1, d, d + 1 when
    all three lie in the pixel's band (so not at a band's edge, nor at 0 or D - 1); elsewhere
    the integer disparity."""
    if not vol.banded:
        return subpixel(vol.cost, disp)
    k = vol.k
    d = jnp.clip(jnp.round(disp).astype(jnp.int32), 0, vol.max_disp - 1)
    j = d - vol.offset
    take = lambda i: jnp.take_along_axis(vol.cost, jnp.clip(i, 0, k - 1)[..., None], axis=-1)[..., 0]
    c0, cm, cp = take(j), take(j - 1), take(j + 1)
    denom = cp - 2.0 * c0 + cm
    ok = (j > 0) & (j < k - 1) & (denom > 1e-12) & (jnp.maximum(cm, cp) < 0.5 * BIG)
    offset = jnp.clip((cp - cm) / (2.0 * jnp.where(ok, denom, 1.0)), -0.5, 0.5)
    return d.astype(jnp.float32) - jnp.where(ok, offset, 0.0)


def confidence_volume(vol, disp_wta: jax.Array, disp_right, lr_tolerance: float = 1.0) -> jax.Array:
    """:func:`confidence` on a CostVolume: the margin between the best entry of the band and the
    best one at least 2 away within the band, times the left-right agreement."""
    if not vol.banded:
        return confidence(vol.cost, disp_wta, disp_right, lr_tolerance)
    return confidence(vol.cost, disp_wta - vol.offset, None if disp_right is None else disp_right,
                      lr_tolerance, absolute=disp_wta)
