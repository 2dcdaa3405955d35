"""Synthetic inputs shared by the test modules:
textured images, pairs shifted by a known disparity, training samples, a tiny KITTI tree."""

from __future__ import annotations

import numpy as np


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
