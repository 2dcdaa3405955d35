"""Networks, losses, sampler, training steps and the learned cost volume (tiny configs)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.learning import losses
from stereojax.matching_cost import learned as learned_cost
from stereojax.models.nets import MatchNet, init_params, net_preset
from stereojax.learning.sampling import PatchData, SamplerConfig, _cut, sample_batch

TINY = {h: dataclasses.replace(net_preset(h, 8), widths=tuple(6 for _ in net_preset(h, 8).widths))
        for h in ("downsize", "uniform", "cosine")}


def _variables(net, seed=0):
    v = init_params(net, jax.random.PRNGKey(seed))
    # non-trivial batch-norm statistics, so inference really uses them
    v = jax.tree_util.tree_map(lambda x: x, v)
    bs = jax.tree_util.tree_map(lambda x: x + 0.1, v["batch_stats"])
    return {"params": v["params"], "batch_stats": bs}


def test_downsize_head_widths():
    v = init_params(net_preset("downsize", 16), jax.random.PRNGKey(0))["params"]["head"]
    assert v["first_left"]["kernel"].shape == (16, 512)
    assert v["first_right"]["kernel"].shape == (16, 512)
    assert [v[f"dense{i}"]["kernel"].shape[1] for i in (1, 2, 3)] == [384, 256, 128]
    assert v["out"]["kernel"].shape == (128, 1)


@pytest.mark.parametrize("head", ["downsize", "uniform"])
def test_split_first_layer_equals_naive_head(head):
    net = TINY[head]
    v = _variables(net)
    rng = np.random.default_rng(0)
    fl = jnp.asarray(rng.normal(size=(5, 11, net.features)).astype(np.float32))
    fr = jnp.asarray(rng.normal(size=(5, 11, net.features)).astype(np.float32))
    fast = learned_cost.dense_cost(net, v, fl, fr, 4, rows_per_tile=2)
    naive = learned_cost.naive_dense_cost(net, v, fl, fr, 4)
    np.testing.assert_allclose(np.asarray(fast), np.asarray(naive), atol=1e-5)
    # and the naive head is the concatenation-based dense layer (a hand-built check)
    p = v["params"]["head"]
    cat = jnp.concatenate([fl[0, 3], fr[0, 3]])
    w1 = jnp.concatenate([p["first_left"]["kernel"], p["first_right"]["kernel"]])
    h = jax.nn.relu(cat @ w1 + p["first_left"]["bias"])
    for i in range(1, len(net.widths)):
        h = jax.nn.relu(h @ p[f"dense{i}"]["kernel"] + p[f"dense{i}"]["bias"])
    logit = (h @ p["out"]["kernel"] + p["out"]["bias"])[0]
    np.testing.assert_allclose(float(naive[0, 3, 0]), float(1 - jax.nn.sigmoid(logit)), atol=1e-5)


def test_whole_image_features_equal_patch_features():
    """tower_features (what the chain runs) on whole images: at every pixel the feature of the
    9x9 patch of the normalised image around it; with a pair padded to a size bucket, the real
    pixels get the unpadded features (statistics over the real region only)."""
    net = TINY["downsize"]
    v = _variables(net)
    rng = np.random.default_rng(1)
    left, right = (jnp.asarray(rng.uniform(0, 255, size=(20, 24)).astype(np.float32)) for _ in range(2))
    fl, fr = learned_cost.tower_features(net, v, left, right)
    assert fl.shape == fr.shape == (20, 24, net.features)
    for img, feats in ((left, fl), (right, fr)):
        norm = (img - img.mean()) / img.std()
        for y, x in [(10, 12), (4, 4), (15, 19)]:
            patch = norm[y - 4: y + 5, x - 4: x + 5][None, :, :, None]
            f_patch = MatchNet(net).apply(v, patch, False, method=MatchNet.features)[0, 0, 0]
            np.testing.assert_allclose(np.asarray(feats[y, x]), np.asarray(f_patch), atol=1e-4)
    from stereojax.inference.programs import pad_to

    pl, pr = (jnp.asarray(pad_to(np.asarray(a), (32, 40))) for a in (left, right))
    gl, gr = learned_cost.tower_features(net, v, pl, pr, valid=jnp.array([20, 24]))
    np.testing.assert_allclose(np.asarray(gl[:16, :20]), np.asarray(fl[:16, :20]), atol=1e-4)
    np.testing.assert_allclose(np.asarray(gr[:16, :20]), np.asarray(fr[:16, :20]), atol=1e-4)


def test_cosine_cost_matches_direct_formula():
    rng = np.random.default_rng(2)
    fl = rng.normal(size=(3, 9, 5)).astype(np.float32)
    fr = rng.normal(size=(3, 9, 5)).astype(np.float32)
    c = np.asarray(learned_cost.cosine_cost(jnp.asarray(fl), jnp.asarray(fr), 3))
    y, x, d = 1, 6, 2
    a, b = fl[y, x], fr[y, x - d]
    cos = a @ b / np.sqrt((a @ a + 1e-6) * (b @ b + 1e-6))
    assert abs(c[y, x, d] - (1 - cos) / 2) < 1e-4
    assert c.min() >= -1e-6 and c.max() <= 1 + 1e-6


def test_relaxed_loss_definition_and_stability():
    delta = 0.05
    logit = lambda s: jnp.log(s) - jnp.log1p(-s)
    one, zero = jnp.float32(1), jnp.float32(0)
    # positive inside [1 - 3 delta, 1 - delta]: -ln(delta + s)
    s = jnp.float32(0.9)
    assert abs(float(losses.relaxed(logit(s), one, delta)) + np.log(0.95)) < 1e-5
    # positive outside: plain BCE
    s = jnp.float32(0.5)
    assert abs(float(losses.relaxed(logit(s), one, delta)) - float(losses.bce(logit(s), one))) < 1e-6
    # negative inside [delta, 3 delta]: -ln(delta + 1 - s)
    s = jnp.float32(0.1)
    assert abs(float(losses.relaxed(logit(s), zero, delta)) + np.log(0.95)) < 1e-5
    # delta = 0 is BCE; extreme logits stay finite, and so do their gradients
    z = jnp.array([-80.0, -5.0, 0.0, 5.0, 80.0])
    np.testing.assert_allclose(losses.relaxed(z, jnp.ones(5), 0.0), losses.bce(z, jnp.ones(5)))
    for lab in (0.0, 1.0):
        g = jax.grad(lambda q: losses.relaxed(q, jnp.full(5, lab), delta).sum())(z)
        assert np.all(np.isfinite(np.asarray(g)))
        assert np.all(np.isfinite(np.asarray(losses.relaxed(z, jnp.full(5, lab), delta))))
    assert float(losses.hinge(jnp.float32(0.9), jnp.float32(0.1), 0.2)) == 0.0


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


@pytest.mark.parametrize("net", [TINY["downsize"], dataclasses.replace(TINY["downsize"], features=4, widths=(16, 8))],
                         ids=["narrow head", "narrow tower"])
def test_pruned_mode_with_all_candidates_equals_exact(net):
    """The head at the candidates (the chain's ranked_dense_cost) equals the exact head there,
    and every other entry is the worst cost."""
    from stereojax.config import CostConfig, StereoConfig

    v = _variables(net)
    rng = np.random.default_rng(3)
    fl = jnp.asarray(rng.normal(size=(6, 10, net.features)).astype(np.float32))
    fr = jnp.asarray(rng.normal(size=(6, 10, net.features)).astype(np.float32))
    exact = learned_cost.dense_cost(net, v, fl, fr, 5, rows_per_tile=4)
    every = jnp.broadcast_to(jnp.arange(5, dtype=jnp.int32)[::-1], (6, 10, 5))

    def pruned(k):
        cfg = StereoConfig(max_disp=5, cost=CostConfig(method="learned", candidates=k, rows_per_tile=4))
        return np.asarray(learned_cost.ranked_dense_cost(net, v, fl, fr, every[..., :k], cfg))

    np.testing.assert_allclose(pruned(5), np.asarray(exact), atol=1e-5)
    part = pruned(2)                                             # only d = 4, 3: the rest is fill
    np.testing.assert_allclose(part[..., 3:], np.asarray(exact)[..., 3:], atol=1e-5)
    assert np.all(part[..., :3] == 1.0)


def test_chain_settings_travel_with_the_model(tmp_path):
    import json
    import shutil

    from stereojax import preset
    from stereojax.errors import ConfigError
    from stereojax.models.registry import chain_settings, learned_config, shipped_weights

    src = shipped_weights("kitti2015")
    w = tmp_path / "m.msgpack"
    shutil.copy(src, w)
    assert chain_settings(w) == {} and learned_config(w, 64) == preset("learned", 64)
    (tmp_path / "m.json").write_text(json.dumps({"chain": {"sgm": {"p1": 0.7}, "refine": {"median_size": 3}}}))
    cfg = learned_config(w, 64)
    assert cfg.sgm.p1 == 0.7 and cfg.refine.median_size == 3 and cfg.max_disp == 64
    assert cfg.sgm.p2 == preset("learned").sgm.p2 and cfg.cost == preset("learned", 64).cost
    # the CLI's --method learned runs the model's settings
    from stereojax.models.registry import resolve

    assert resolve("learned", str(w), max_disp=64).config == cfg
    (tmp_path / "m.json").write_text(json.dumps({"chain": {"sgm": {"p7": 1}}}))
    with pytest.raises(ConfigError, match="sgm.p7"):
        learned_config(w, 64)
