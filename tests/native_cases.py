"""The inputs of the native-vs-JAX kernel tests (issue 51, "Equality"): real crops of KITTI 2015
and Middlebury, band offsets from the coarse pass or a smooth random field, a pair padded on the
right and bottom as the Predictor pads it, and the comparison that reports its largest relative
difference."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

#: the crops' size, full range and band width (small, so that the JAX kernels compile fast)
H, W, D, K = 60, 120, 32, 12
#: the real (rows, columns) of the padded cases: the crop cut to this and padded back to H x W
VALID = (47, 101)
#: name -> (folder under the data root, KITTI frame or None for a Middlebury scene, top, left)
CROPS = {
    "kitti2015": ("kitti2015/training", "000003", 200, 500),
    "middlebury": ("middlebury/Cones_2003Q", None, 120, 150),
}


@functools.lru_cache(maxsize=None)
def _crop(data_root, name):
    from stereojax.data import load_kitti2015, load_middlebury
    from stereojax.data.images import as_grey

    folder, frame, y, x = CROPS[name]
    s = load_kitti2015(data_root / folder, frame) if frame else load_middlebury(data_root / folder)
    c = (slice(y, y + H), slice(x, x + W))
    left, right = as_grey(s.left, "left")[c], as_grey(s.right, "right")[c]
    assert left.shape == (H, W), (name, left.shape)
    return left, right


def pad_edge(img: np.ndarray, valid) -> np.ndarray:
    """``img`` cut to its real ``valid`` (rows, columns) and edge-padded back to its shape on the
    right and bottom, as the Predictor pads a pair to its size bucket."""
    rows, cols = valid
    return np.pad(img[:rows, :cols], ((0, img.shape[0] - rows), (0, img.shape[1] - cols)), mode="edge")


def real_pairs(data_root, padded: bool):
    """[(name, left, right)] grey ``f32[H, W]`` crops (0..255), padded to VALID when asked."""
    out = []
    for name in CROPS:
        left, right = _crop(data_root, name)
        if padded:
            left, right = pad_edge(left, VALID), pad_edge(right, VALID)
        out.append((name, left, right))
    return out


def valid_array(padded: bool):
    return jnp.array(VALID, jnp.int32) if padded else None


def real_part(a, padded: bool, valid=VALID):
    """The real pixels of ``a`` ``[H, W, ...]`` (all of them when nothing is padded)."""
    a = np.asarray(a)
    return a[:valid[0], :valid[1]] if padded else a


def garbage_padding(cost: np.ndarray, padded: bool, seed: int = 0, valid=VALID) -> np.ndarray:
    """``cost`` with random values in its padding (nothing there may reach the real pixels)."""
    if not padded:
        return cost
    rng = np.random.default_rng(seed)
    out = rng.random(cost.shape).astype(cost.dtype)
    out[:valid[0], :valid[1]] = cost[:valid[0], :valid[1]]
    return out


def smooth_offsets(shape, max_disp=D, k=K, seed=0) -> np.ndarray:
    """``i32[H, W]`` band offsets in 0 .. D - K: a coarse random field upsampled by 8, with
    one-disparity jitter (smooth with jumps, as a coarse pass gives)."""
    h, w = shape
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, max_disp - k + 1, (-(-h // 8), -(-w // 8)))
    off = np.repeat(np.repeat(coarse, 8, axis=0), 8, axis=1)[:h, :w] + rng.integers(-1, 2, (h, w))
    return np.clip(off, 0, max_disp - k).astype(np.int32)


@functools.lru_cache(maxsize=None)
def _coarse_fn(max_disp, k):
    import stereojax
    from stereojax import chain

    cfg = stereojax.preset("census", max_disp)
    cfg = dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=k), kernels="xla")
    return jax.jit(lambda l, r, v: chain.bands(l, r, cfg, v)[0])


def coarse_offsets(left, right, valid=None, max_disp=D, k=K) -> np.ndarray:
    """``i32[H, W]`` band offsets of the chain's coarse pass (census preset, JAX kernels)."""
    off = np.asarray(_coarse_fn(max_disp, k)(jnp.asarray(left), jnp.asarray(right), valid))
    assert off.min() >= 0 and off.max() <= max_disp - k
    return off


#: the volumes of the tests: kind -> (D, K, band offsets from): K = 48, the shipped band width, is
#: a code path of its own in the native kernels (compiled as a constant)
KINDS = {"full": (D, D, None), "coarse": (D, K, "coarse"), "random": (D, K, "random"),
         "full48": (48, 48, None), "coarse48": (64, 48, "coarse")}


@functools.lru_cache(maxsize=None)
def _census_fn(max_disp):
    from stereojax.matching_cost import classical

    return jax.jit(lambda l, r: classical.census_cost_xla(l, r, max_disp))


def volume(left, right, kind: str, padded: bool, seed=0):
    """(the full census cost ``f32[H, W, D]`` with random values in the padding, the CostVolume of
    ``kind`` (:data:`KINDS`) cut from it)."""
    from stereojax.volume import CostVolume, band_from_full

    max_disp, k, source = KINDS[kind]
    full = np.asarray(_census_fn(max_disp)(jnp.asarray(left), jnp.asarray(right)))
    full = garbage_padding(full, padded, seed)
    valid = valid_array(padded)
    if source is None:
        return full, CostVolume.full(jnp.asarray(full), valid)
    off = offsets(source, left, right, padded, seed, max_disp, k)
    vol = band_from_full(jnp.asarray(full), jnp.asarray(off), k, valid)
    assert vol.banded and vol.k == k < vol.max_disp == max_disp
    return full, vol


def offsets(kind: str, left, right, padded: bool, seed=0, max_disp=D, k=K) -> np.ndarray:
    """The band offsets of ``kind`` "coarse" or "random" (random values in the padding)."""
    if kind == "coarse":
        off = coarse_offsets(left, right, valid_array(padded), max_disp, k)
    else:
        off = smooth_offsets(left.shape, max_disp, k, seed)
    if padded:
        rng = np.random.default_rng(seed + 1)
        junk = rng.integers(0, max_disp - k + 1, off.shape).astype(np.int32)
        junk[:VALID[0], :VALID[1]] = off[:VALID[0], :VALID[1]]
        off = junk
    return off


def max_rel(got, want) -> float:
    """The largest |got - want| / |want| over the entries with want != 0."""
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    nz = want != 0
    err = np.abs(got - want)
    rel = float((err[nz] / np.abs(want[nz])).max()) if nz.any() else 0.0
    return max(rel, float(err[~nz].max()) if (~nz).any() else 0.0)


def assert_close(got, want, rtol=1e-5, what=""):
    """``got`` == ``want`` to ``rtol`` relative (absolute 1e-6 of the largest |want|); prints
    and returns the largest relative difference."""
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape, (got.shape, want.shape)
    assert np.all(np.isfinite(got)), f"{what}: non-finite native output"
    np.testing.assert_allclose(got, want, rtol=rtol, atol=1e-6 * float(np.abs(want).max()), err_msg=what)
    rel = max_rel(got, want)
    print(f"max rel diff {what}: {rel:.3g}")
    return rel


def assert_equal(got, want, what=""):
    got, want = np.asarray(got), np.asarray(want)
    np.testing.assert_array_equal(got, want, err_msg=what)
    print(f"max rel diff {what}: 0 (bit-equal)")


def cbca_float64(cost, arms, iterations: int) -> np.ndarray:
    """Full-range CBCA (cross_based.cbca) in float64 with integral images: the exact value, to
    judge the float32 kernels by (the arms of padding pixels, which may run past the image, are
    cut at its border)."""
    left, right, up, down = (np.asarray(a) for a in arms)
    h, w = left.shape
    y, x = np.arange(h)[:, None], np.arange(w)[None, :]

    def hsum(v):
        s = np.concatenate([np.zeros_like(v[:, :1]), np.cumsum(v, axis=1)], axis=1)
        return s[y, np.minimum(x + right + 1, w)] - s[y, np.maximum(x - left, 0)]

    def vsum(v):
        s = np.concatenate([np.zeros_like(v[:1]), np.cumsum(v, axis=0)], axis=0)
        return s[np.minimum(y + down + 1, h), x] - s[np.maximum(y - up, 0), x]

    support = vsum(hsum(np.ones((h, w))))
    c = np.asarray(cost, np.float64)
    for _ in range(iterations):
        c = vsum(hsum(c)) / support[..., None]
    return c
