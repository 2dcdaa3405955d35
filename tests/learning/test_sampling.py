"""stereojax.learning.sampling: patch offsets and sub-pixel interpolation of the sampler, and the near-miss
patches of distillation."""

import jax
import jax.numpy as jnp
import numpy as np

from stereojax.learning.sampling import PatchData, SamplerConfig, _cut, sample_batch, sample_distill_batch

P = 9


def _ramp_data():
    # right image = left shifted by 3 px: a patch at (y, x) matches the right one at x - 3
    h, w = 30, 60
    left = np.tile(np.arange(w, dtype=np.float32), (h, 1)) + np.arange(h)[:, None] * 0.5
    right = np.pad(left[:, 3:], ((0, 0), (0, 3)), mode="edge")
    ys, xs = np.mgrid[10:20, 30:40]
    return PatchData(left=jnp.asarray(left[None]), right=jnp.asarray(right[None]),
                     index=jnp.zeros(ys.size, jnp.int32), y=jnp.asarray(ys.ravel(), jnp.int32),
                     x=jnp.asarray(xs.ravel(), jnp.int32), d=jnp.full(ys.size, 3.0, jnp.float32))


def test_sampler_offsets_and_interpolation():
    data = _ramp_data()
    cfg = SamplerConfig(v_pos=1.0, z_low=4.0, z_high=8.0)
    ref, pos, neg = sample_batch(jax.random.PRNGKey(0), data, 200, 9, cfg)
    assert ref.shape == pos.shape == neg.shape == (200, 9, 9, 1)
    # on the ramp, intensity = x (+ row term): the centre difference is the offset itself
    o_pos = np.asarray(pos[:, 4, 4, 0] - ref[:, 4, 4, 0])
    o_neg = np.asarray(neg[:, 4, 4, 0] - ref[:, 4, 4, 0])
    assert np.all(np.abs(o_pos) <= 1.0 + 1e-4)
    assert np.all((np.abs(o_neg) >= 4.0 - 1e-4) & (np.abs(o_neg) <= 8.0 + 1e-4))
    assert 0.3 < np.mean(o_neg > 0) < 0.7                      # both signs drawn
    # same key, same batch
    again = sample_batch(jax.random.PRNGKey(0), data, 200, 9, cfg)
    np.testing.assert_array_equal(np.asarray(ref), np.asarray(again[0]))
    # sub-pixel cut is linear interpolation
    p = _cut(data.left, jnp.zeros(1, jnp.int32), jnp.array([15]), jnp.array([20.25]), 3)
    np.testing.assert_allclose(np.asarray(p[0, 1, :, 0]), [19.25 + 7.5, 20.25 + 7.5, 21.25 + 7.5], atol=1e-5)


def _ramp():
    """One pair whose right image's value is its column index: a patch's centre tells where it
    was cut."""
    h, w = 40, 120
    right = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))[None]
    ys, xs = np.mgrid[10:30, 40:100]
    n = ys.size
    return PatchData(left=jnp.asarray(right), right=jnp.asarray(right), index=jnp.zeros(n, jnp.int32),
                     y=jnp.asarray(ys.ravel(), jnp.int32), x=jnp.asarray(xs.ravel(), jnp.int32),
                     d=jnp.full(n, 12.0, jnp.float32))


def test_near_miss_patches_lie_within_their_range_of_the_true_match():
    data, cfg = _ramp(), SamplerConfig(v_pos=1.0, z_low=4.0, z_high=18.0)
    key = jax.random.PRNGKey(3)
    ref, pos, neg, soft = sample_distill_batch(key, data, 400, P, cfg, soft_range=6.0)
    for a, b in zip((ref, pos, neg), sample_batch(key, data, 400, P, cfg)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))    # the labelled batch is unchanged
    offset = np.asarray(soft[:, P // 2, P // 2, 0]) - (np.asarray(ref[:, P // 2, P // 2, 0]) - 12.0)
    assert np.abs(offset).max() <= 6.0 + 1e-4
    assert offset.min() < -4.0 and offset.max() > 4.0                 # the whole range is drawn
    assert 0.3 < (offset > 0).mean() < 0.7
