"""Synthetic inputs shared by the test modules:
textured images, pairs shifted by a known disparity, training samples, a tiny KITTI tree, pair
folders, the banded census chain, the CLI run in-process and a subprocess environment."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def textured(h, w, seed=0):
    """A smooth random texture (census needs local structure, not white noise only)."""
    import cv2

    rng = np.random.default_rng(seed)
    img = rng.random((h // 2 + 1, w // 2 + 1)).astype(np.float32)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR)
    return (img * 200 + rng.random((h, w)) * 40).astype(np.uint8)


def shifted_pair(d, h=40, w=64, seed=0):
    """(left, right) uint8 with left(x) == right(x - d); the right image's last d columns are noise."""
    left = textured(h, w, seed)
    rng = np.random.default_rng(seed + 1)
    right = rng.integers(0, 256, (h, w)).astype(np.uint8)
    right[:, : w - d] = left[:, d:]          # left(x) == right(x - d)
    return left, right


def offset_pair(d, h=48, w=96, seed=3):
    """left(x) == right(x - d) for any integer d (negative: the match lies to the right)."""
    big = textured(h, w + 2 * abs(d) + 2, seed)
    c = abs(d) + 1
    left = big[:, c: c + w]
    right = big[:, c + d: c + d + w]
    return left, right


def banded_census(max_disp=64, width=16):
    """The census preset with disparity bands ``width`` wide."""
    import dataclasses

    import stereojax

    cfg = stereojax.preset("census", max_disp)
    return dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=width))


def pair_folders(root: Path, names, right_names=None, h=48, w=80):
    """Folders ``root/L`` and ``root/R`` of shifted pairs named ``names`` (right images only for
    ``right_names`` when given)."""
    from stereojax.data import io

    for i, n in enumerate(names):
        left, right = shifted_pair(4, h=h, w=w, seed=i)
        io.write_png(root / "L" / f"{n}.png", left)
        if right_names is None or n in right_names:
            io.write_png(root / "R" / f"{n}.png", right)
    return root / "L", root / "R"


def cache_env(cache: Path) -> dict:
    """The environment of a ``stereojax`` subprocess that compiles into the cache folder ``cache``."""
    return {**os.environ, "PYTHONPATH": str(ROOT), "STEREOJAX_CACHE_DIR": str(cache)}


def training_samples(n=2, h=40, w=96, d=5):
    """StereoSamples of textured images shifted by d, with GT d everywhere."""
    from stereojax.data.datasets import StereoSample

    out = []
    for i in range(n):
        left = textured(h, w, seed=10 + i)
        right = np.roll(left, -d, axis=1)       # left(x) == right(x - d)
        gt = np.full((h, w), float(d), np.float32)
        out.append(StereoSample(name=f"s{i}", left=left, right=right, gt=gt,
                                gt_valid=np.ones((h, w), bool)))
    return out


def tiny_sampler():
    """Patch offsets that fit the small training samples."""
    from stereojax.learning.sampling import SamplerConfig

    return SamplerConfig(v_pos=1.0, z_low=3.0, z_high=8.0)


def tiny_train_config(**kw):
    """The tiny training preset with :func:`tiny_sampler`."""
    from stereojax.learning.train import train_preset

    return train_preset("tiny", sampler=tiny_sampler(), **kw)


def fake_kitti(root, n=2, with_gt=True):
    """A KITTI 2015 training/ tree of n small shifted pairs (d = 3) with GT on a rectangle."""
    import cv2

    for sub in ("image_2", "image_3", "disp_noc_0"):
        (root / sub).mkdir(parents=True)
    for i in range(n):
        left, right = shifted_pair(3, h=48, w=80, seed=i)
        cv2.imwrite(str(root / "image_2" / f"{i:06d}_10.png"), left)
        cv2.imwrite(str(root / "image_3" / f"{i:06d}_10.png"), right)
        if with_gt:
            gt = np.zeros(left.shape, np.uint16)
            gt[10:40, 20:70] = 3 * 256
            cv2.imwrite(str(root / "disp_noc_0" / f"{i:06d}_10.png"), gt)


def run_cli(argv, capsys):
    """``stereojax`` in-process: (exit code, stdout, stderr) of ``main(argv)``."""
    from stereojax.app.cli import main

    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def random_pair(shape=(9, 14), seed: int = 0):
    """A small pair of random grey images (float32, 0..255): the kernels' reference tests."""
    rng = np.random.default_rng(seed)
    return (rng.integers(0, 256, shape).astype(np.float32), rng.integers(0, 256, shape).astype(np.float32))


def require_native():
    """Fail the calling test unless the native kernels (stereojax/_native*.so) loaded, so that a
    native-vs-JAX test never passes by comparing the JAX kernels with themselves; with
    ``STEREOJAX_NATIVE_SKIP=1`` in the environment (the build was skipped on purpose) it skips."""
    import pytest

    from stereojax import kernels

    st = kernels.status()
    if st.loaded:
        import jax

        if jax.default_backend() != "cpu":   # platform_dependent picks the JAX kernels there
            pytest.skip(f"the native kernels run on the CPU only; the backend is {jax.default_backend()}")
        return
    if os.environ.get("STEREOJAX_NATIVE_SKIP") == "1":
        pytest.skip(f"native kernels not loaded, STEREOJAX_NATIVE_SKIP=1 ({st.reason})")
    pytest.fail(f"the native kernels did not load: {st.reason} (set STEREOJAX_NATIVE_SKIP=1 to skip "
                "the native tests where the extension is not built on purpose)", pytrace=False)
