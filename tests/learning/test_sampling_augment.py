"""MC-CNN-style patch augmentation (stereojax.learning.sampling.AugmentConfig): the warped reader is exact on
linear images, the random maps stay in their ranges, the shared part is shared, and the option
is off unless asked for."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.errors import ConfigError
from stereojax.learning.sampling import (AUGMENT_MCCNN, AugmentConfig, PatchData, SamplerConfig, _cut,
                                         _cut_warped, sample_batch)

P = 9


def _ramp_data(h=60, w=120, gx=0.5, gy=0.25):
    """One image pair whose grey value is linear in (x, y): bilinear reading is exact there, so
    a warped patch is exactly the plane seen through its affine map."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = (gx * xx + gy * yy)[None]
    ys, xs = np.mgrid[15:h - 15, 30:w - 15]
    n = ys.size
    return PatchData(left=jnp.asarray(img), right=jnp.asarray(img), index=jnp.zeros(n, jnp.int32),
                     y=jnp.asarray(ys.ravel(), jnp.int32), x=jnp.asarray(xs.ravel(), jnp.int32),
                     d=jnp.full(n, 6.0, jnp.float32))


def _plane(patches):
    """Least-squares plane fit of every patch: (gradient along u, along v, max residual)."""
    off = np.arange(P) - P // 2
    v, u = np.meshgrid(off, off, indexing="ij")
    a = np.stack([u.ravel(), v.ravel(), np.ones(P * P)], 1).astype(np.float64)
    vals = np.asarray(patches, np.float64).reshape(len(patches), -1).T
    coef, *_ = np.linalg.lstsq(a, vals, rcond=None)
    resid = np.abs(a @ coef - vals).max()
    return coef[0], coef[1], coef[2], resid


def test_identity_warp_equals_the_plain_reader():
    rng = np.random.default_rng(0)
    imgs = jnp.asarray(rng.normal(size=(2, 30, 50)).astype(np.float32))
    idx = jnp.array([0, 1, 1]); y = jnp.array([10.0, 12.0, 20.0]); x = jnp.array([10.0, 20.5, 33.25])
    eye = jnp.broadcast_to(jnp.eye(2), (3, 2, 2))
    a = _cut(imgs, idx, y.astype(jnp.int32), x, P)
    b = _cut_warped(imgs, idx, y, x, P, eye, jnp.zeros(3), jnp.ones(3))
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)


def test_augmented_patches_are_the_plane_through_maps_within_their_ranges():
    data = _ramp_data()
    aug = AugmentConfig(rotate=7.0, scale=0.2, hscale=0.2, hshear=0.1)
    cfg = SamplerConfig(v_pos=1.0, z_low=4.0, z_high=8.0, augment=aug)
    ref, pos, neg = sample_batch(jax.random.PRNGKey(3), data, 256, P, cfg)
    gu, gv, _, resid = _plane(ref[..., 0])
    assert resid < 1e-3                                       # exactly an affine image of the plane
    # the plane's gradient (0.5, 0.25) seen through rotation(<=7 deg) @ zoom(0.64..1) @ shear(<=0.1)
    norm = np.hypot(gu, gv)
    lo = 0.64 * np.hypot(0.5, 0.25) * 0.8
    assert norm.min() > lo and norm.max() < np.hypot(0.5, 0.25) * 1.2, (norm.min(), norm.max())
    assert gu.std() > 1e-3                                     # the maps really vary
    # no difference drawn for the right patches: they share the reference's map exactly
    gu_p, gv_p, _, _ = _plane(pos[..., 0])
    np.testing.assert_allclose(gu_p, gu, atol=1e-4)
    np.testing.assert_allclose(gv_p, gv, atol=1e-4)


def test_photometric_change_is_per_triple_and_right_patches_get_their_own_difference():
    data = _ramp_data()
    plain_cfg = SamplerConfig(v_pos=1.0, z_low=4.0, z_high=8.0)
    key = jax.random.PRNGKey(5)
    r0, p0, n0 = sample_batch(key, data, 128, P, plain_cfg)
    cfg = dataclasses.replace(plain_cfg, augment=AugmentConfig(brightness=0.7, d_brightness=0.3))
    r1, p1, n1 = sample_batch(key, data, 128, P, cfg)
    shift_ref = np.asarray(r1 - r0)[..., 0]
    shift_pos = np.asarray(p1 - p0)[..., 0]
    shift_neg = np.asarray(n1 - n0)[..., 0]
    # the same offsets are drawn (same key), so only a constant per patch is added
    for s in (shift_ref, shift_pos, shift_neg):
        assert np.ptp(s.reshape(len(s), -1), axis=1).max() < 1e-4
    b_ref, b_pos, b_neg = (s[:, 0, 0] for s in (shift_ref, shift_pos, shift_neg))
    assert np.abs(b_ref).max() <= 0.7 + 1e-5 and np.abs(b_ref).std() > 0.1
    np.testing.assert_allclose(b_pos, b_neg, atol=1e-5)          # one right-image difference
    diff = b_pos - b_ref
    assert np.abs(diff).max() <= 0.3 + 1e-5 and diff.std() > 0.05


def test_augmentation_is_off_by_default_and_never_touches_validation():
    assert not SamplerConfig().augment.enabled and AUGMENT_MCCNN.enabled
    data = _ramp_data()
    key = jax.random.PRNGKey(1)
    cfg = SamplerConfig(v_pos=1.0, z_low=4.0, z_high=8.0, augment=AUGMENT_MCCNN)
    plain = sample_batch(key, data, 64, P, dataclasses.replace(cfg, augment=AugmentConfig()))
    val = sample_batch(key, data, 64, P, cfg, augment=False)
    aug = sample_batch(key, data, 64, P, cfg)
    for a, b in zip(plain, val):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not np.allclose(np.asarray(aug[0]), np.asarray(plain[0]))
    # deterministic in the key
    again = sample_batch(key, data, 64, P, cfg)
    np.testing.assert_array_equal(np.asarray(aug[1]), np.asarray(again[1]))


@pytest.mark.parametrize("bad", [dict(scale=1.0), dict(contrast=0.5), dict(rotate=-1.0), dict(d_hscale=-0.1)])
def test_bad_augmentation_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="sampler.augment"):
        SamplerConfig(augment=AugmentConfig(**bad)).validate()
