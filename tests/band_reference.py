"""Per-pixel disparity bands in plain numpy: random band cases and the loop references of the band
kernels (aggregation, SGM, right-view WTA, sub-pixel, neutral border), shared by the band tests of
tests/aggregation, tests/optimization and tests/system/test_bands.py."""

import numpy as np
import jax.numpy as jnp

from stereojax.aggregation import cross_based as aggregation
from stereojax.volume import BIG

from . import reference as ref

H, W, D = 7, 11, 9


def _case(seed, k, h=H, w=W, d=D):
    rng = np.random.default_rng(seed)
    full = rng.random((h, w, d)).astype(np.float32)
    # smooth-ish bands with jumps, as a coarse pass gives
    base = rng.integers(0, d - k + 1, (h, 1))
    off = np.clip(base + rng.integers(-1, 2, (h, w)), 0, d - k).astype(np.int32)
    grey = rng.integers(0, 256, (h, w)).astype(np.float32)
    right = rng.integers(0, 256, (h, w)).astype(np.float32)
    return full, off, grey, right


def _band(full, off, k):
    return np.take_along_axis(full, off[..., None] + np.arange(k), axis=-1)


# ---- numpy references of the band kernels ---------------------------------------------------

def ref_cbca_band(band, off, arms, iterations):
    """Two passes per iteration; a neighbour whose band misses p's disparity counts with p's
    own value (horizontal: p's cost; vertical: p's horizontal mean times q's arm count)."""
    left, right, up, down = arms
    h, w, k = band.shape
    c = band.astype(np.float64)
    hn = (left + right + 1).astype(np.float64)
    support = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            support[y, x] = hn[y - up[y, x]: y + down[y, x] + 1, x].sum()
    for _ in range(iterations):
        hs = np.zeros_like(c)
        for y in range(h):
            for x in range(w):
                for j in range(k):
                    d = off[y, x] + j
                    for xx in range(x - left[y, x], x + right[y, x] + 1):
                        jj = d - off[y, xx]
                        hs[y, x, j] += c[y, xx, jj] if 0 <= jj < k else c[y, x, j]
        out = np.zeros_like(c)
        for y in range(h):
            for x in range(w):
                for j in range(k):
                    d = off[y, x] + j
                    for yy in range(y - up[y, x], y + down[y, x] + 1):
                        jj = d - off[yy, x]
                        out[y, x, j] += hs[yy, x, jj] if 0 <= jj < k else hs[y, x, j] / hn[y, x] * hn[yy, x]
                    out[y, x, j] /= support[y, x]
        c = out
    return c.astype(np.float32)


def ref_sgm_band(band, off, d, left, right, directions, p1, p2, **kw):
    """Banded SGM = full-range SGM on a volume whose entries outside each band are far larger
    than any path cost (they never win a min, and min_k is the band's), read back at the bands."""
    h, w, k = band.shape
    full = np.full((h, w, d), 1e4, np.float64)
    for y in range(h):
        for x in range(w):
            full[y, x, off[y, x]: off[y, x] + k] = band[y, x]
    out = ref.sgm(full, left, right, directions, p1, p2, **kw)
    return _band(out, off, k)


def ref_right_wta(band, off, off_r, invalid=1.0):
    h, w, k = band.shape
    out = np.zeros((h, w), np.int32)
    for y in range(h):
        for xr in range(w):
            best, arg = np.inf, 0
            for j in range(k):
                d = off_r[y, xr] + j
                x = xr + d
                if x >= w:
                    c = invalid
                elif 0 <= d - off[y, x] < k:
                    c = band[y, x, d - off[y, x]]
                else:
                    c = BIG
                if c < best:
                    best, arg = c, j
            out[y, xr] = off_r[y, xr] + arg
    return out


def ref_subpixel_band(band, off, disp, d_max=D):
    h, w, k = band.shape
    out = np.zeros((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            d = min(max(int(round(disp[y, x])), 0), d_max - 1)
            j = d - off[y, x]
            out[y, x] = d
            if 0 < j < k - 1:
                cm, c0, cp = band[y, x, j - 1], band[y, x, j], band[y, x, j + 1]
                den = cp - 2 * c0 + cm
                if den > 1e-12:
                    out[y, x] = d - np.clip((cp - cm) / (2 * den), -0.5, 0.5)
    return out


def ref_neutral_band(band, off, share=0.5):
    h, w, k = band.shape
    out = band.copy()
    for y in range(h):
        for x in range(w):
            inside = [j for j in range(k) if x - (off[y, x] + j) >= 0]
            if not inside:
                continue
            vals = band[y, x, inside]
            fill = vals.min() + share * (vals.mean() - vals.min())
            for j in range(k):
                if j not in inside:
                    out[y, x, j] = fill
    return out


def _arms(grey, tau=60.0, length=3):
    return aggregation.cross_arms(jnp.asarray(grey), tau, length)
