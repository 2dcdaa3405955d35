"""Plain numpy (loop) reference implementations of every jax kernel, for agreement tests.

Written for clarity, not speed: use them on tiny arrays only.
"""

from __future__ import annotations

import numpy as np


def census_cost(left, right, max_disp, radius, border="worst"):
    ry, rx = radius
    h, w = left.shape
    pl = np.pad(left, ((ry, ry), (rx, rx)), mode="edge")
    pr = np.pad(right, ((ry, ry), (rx, rx)), mode="edge")
    offs = [(dy, dx) for dy in range(-ry, ry + 1) for dx in range(-rx, rx + 1) if (dy, dx) != (0, 0)]

    def bits(p, img, y, x):
        return np.array([p[ry + y + dy, rx + x + dx] < img[y, x] for dy, dx in offs])

    out = np.ones((h, w, max_disp), np.float32)
    for y in range(h):
        for x in range(w):
            bl = bits(pl, left, y, x)
            for d in range(max_disp if border == "replicate" else min(max_disp, x + 1)):
                br = bits(pr, right, y, max(x - d, 0))
                out[y, x, d] = np.sum(bl != br) / len(offs)
    return out


def sad_cost(left, right, max_disp, radius, border="worst"):
    h, w = left.shape
    pl = np.pad(left, radius, mode="edge")
    out = np.ones((h, w, max_disp), np.float32)
    for d in range(max_disp):
        shifted = np.pad(right, ((0, 0), (d, 0)), mode="edge")[:, :w]
        ps = np.pad(shifted, radius, mode="edge")
        ad = np.abs(pl - ps) / 255.0
        k = 2 * radius + 1
        for y in range(h):
            for x in range(0 if border == "replicate" else d, w):
                out[y, x, d] = ad[y:y + k, x:x + k].mean()
    return out


def cross_arms(grey, tau, length):
    h, w = grey.shape
    arms = np.zeros((4, h, w), np.int32)
    for i, (dy, dx) in enumerate(((0, -1), (0, 1), (-1, 0), (1, 0))):
        for y in range(h):
            for x in range(w):
                k = 0
                while k < length:
                    yy, xx = y + dy * (k + 1), x + dx * (k + 1)
                    if not (0 <= yy < h and 0 <= xx < w) or abs(grey[yy, xx] - grey[y, x]) >= tau:
                        break
                    k += 1
                arms[i, y, x] = k
    return arms


def cbca(cost, arms, iterations):
    left, right, up, down = arms
    h, w, _ = cost.shape
    c = cost.astype(np.float64)
    for _ in range(iterations):
        hs = np.zeros_like(c)
        hn = np.zeros((h, w))
        for y in range(h):
            for x in range(w):
                hs[y, x] = c[y, x - left[y, x]: x + right[y, x] + 1].sum(0)
                hn[y, x] = left[y, x] + right[y, x] + 1
        out = np.zeros_like(c)
        for y in range(h):
            for x in range(w):
                ys = slice(y - up[y, x], y + down[y, x] + 1)
                out[y, x] = hs[ys, x].sum(0) / hn[ys, x].sum()
        c = out
    return c.astype(np.float32)


def sgm(cost, left, right, directions, p1, p2, adaptive=False, q1=1.0, q2=1.0, thr=1e9, vfac=1.0):
    """Straightforward per-path SGM; returns the mean over paths of L_r."""
    h, w, nd = cost.shape
    dirs = [(0, 1), (0, -1), (1, 0), (-1, 0)]
    if directions == 8:
        dirs += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    total = np.zeros((h, w, nd), np.float64)
    for dy, dx in dirs:
        lr = np.zeros((h, w, nd), np.float64)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = list(range(w)) if dx >= 0 else list(range(w - 1, -1, -1))
        if dy == 0:
            order = [(y, x) for y in range(h) for x in xs]
        else:
            order = [(y, x) for y in ys for x in range(w)]
        for y, x in order:
            py, px = y - dy, x - dx
            if not (0 <= py < h and 0 <= px < w):
                lr[y, x] = cost[y, x]
                continue
            prev = lr[py, px]
            m = prev.min()
            for d in range(nd):
                a1, a2 = p1, p2
                if dy != 0 and dx == 0:
                    a1 = p1 / vfac
                if adaptive:
                    big_l = abs(left[y, x] - left[py, px]) >= thr
                    big_r = False
                    if dy == 0 or dx == 0:
                        # right-image gradient along the path at the match (y, x - d);
                        # columns left of the image repeat column 0 (as the cost does)
                        xr = max(x - d, 0)
                        if 0 <= y - dy < h and 0 <= xr - dx < w:
                            big_r = abs(right[y, xr] - right[y - dy, xr - dx]) >= thr
                    n_big = int(big_l) + int(big_r)
                    div = 1.0 if n_big == 0 else (q1 if n_big == 1 else q2)
                    a1, a2 = a1 / div, a2 / div
                best = prev[d]
                if d > 0:
                    best = min(best, prev[d - 1] + a1)
                if d < nd - 1:
                    best = min(best, prev[d + 1] + a1)
                best = min(best, m + a2)
                lr[y, x, d] = cost[y, x, d] + best - m
        total += lr
    return (total / len(dirs)).astype(np.float32)


def lr_check(dl, dr, max_disp, tol):
    h, w = dl.shape
    out = np.zeros((h, w), np.int32)
    for y in range(h):
        for x in range(w):
            d = int(round(dl[y, x]))
            if x - d >= 0 and abs(dl[y, x] - dr[y, x - d]) <= tol:
                out[y, x] = 0
            elif any(x - k >= 0 and int(round(dr[y, x - k])) == k for k in range(max_disp)):
                out[y, x] = 1
            else:
                out[y, x] = 2
    return out


def fill(disp, labels):
    h, w = disp.shape
    out = disp.astype(np.float32).copy()
    good = labels == 0
    dirs = [(0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)]

    def nearest(y, x, dy, dx):
        yy, xx = y + dy, x + dx
        while 0 <= yy < h and 0 <= xx < w:
            if good[yy, xx]:
                return disp[yy, xx]
            yy, xx = yy + dy, xx + dx
        return None

    for y in range(h):
        for x in range(w):
            if labels[y, x] == 2:
                v = nearest(y, x, 0, -1)
                if v is None:
                    v = nearest(y, x, 0, 1)
                if v is not None:
                    out[y, x] = v
            elif labels[y, x] == 1:
                vals = [v for v in (nearest(y, x, dy, dx) for dy, dx in dirs) if v is not None]
                if vals:
                    out[y, x] = np.median(vals)
    return out


def subpixel(cost, disp):
    h, w, nd = cost.shape
    out = np.zeros((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            d = int(np.clip(round(disp[y, x]), 0, nd - 1))
            out[y, x] = d
            if 0 < d < nd - 1:
                cm, c0, cp = cost[y, x, d - 1], cost[y, x, d], cost[y, x, d + 1]
                den = cp - 2 * c0 + cm
                if den > 1e-12:
                    out[y, x] = d - np.clip((cp - cm) / (2 * den), -0.5, 0.5)
    return out


def median(img, size):
    r = size // 2
    p = np.pad(img, r, mode="edge")
    h, w = img.shape
    return np.array([[np.median(p[y:y + size, x:x + size]) for x in range(w)] for y in range(h)],
                    np.float32)


def bilateral(disp, guide, radius, ss, sr):
    h, w = disp.shape
    pd = np.pad(disp, radius, mode="edge")
    pg = np.pad(guide, radius, mode="edge")
    out = np.zeros((h, w), np.float64)
    for y in range(h):
        for x in range(w):
            num = den = 0.0
            for i in range(-radius, radius + 1):
                for j in range(-radius, radius + 1):
                    wt = np.exp(-(i * i + j * j) / (2 * ss ** 2)) * np.exp(
                        -(pg[y + radius + i, x + radius + j] - guide[y, x]) ** 2 / (2 * sr ** 2))
                    num += wt * pd[y + radius + i, x + radius + j]
                    den += wt
            out[y, x] = num / den
    return out.astype(np.float32)
