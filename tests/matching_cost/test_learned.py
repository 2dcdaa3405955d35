"""stereojax.matching_cost.learned: the dense cost of the network's head (split first layer, whole-image
features, cosine cost, the pruned head at its candidates), on tiny configs."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.matching_cost import learned as learned_cost
from stereojax.models.nets import MatchNet, init_params, net_preset

TINY = {h: dataclasses.replace(net_preset(h, 8), widths=tuple(6 for _ in net_preset(h, 8).widths))
        for h in ("downsize", "uniform", "cosine")}


def _variables(net, seed=0):
    v = init_params(net, jax.random.PRNGKey(seed))
    # non-trivial batch-norm statistics, so inference really uses them
    v = jax.tree_util.tree_map(lambda x: x, v)
    bs = jax.tree_util.tree_map(lambda x: x + 0.1, v["batch_stats"])
    return {"params": v["params"], "batch_stats": bs}


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
