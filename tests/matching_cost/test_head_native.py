"""The native learned head (head.cc) against the JAX kernel (learned.head_at_xla): the shipped
networks' heads (the paper's 512-384-256-128 and the compact 64-32) on real tower features of a
KITTI and a Middlebury crop, at the candidates of real band offsets and at the image's left edge
(x - d < 0 reads column 0), to float rounding (issue 51, "Equality"); and a head whose widths are
not multiples of the kernel's 16-wide register blocks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stereojax.matching_cost import learned
from stereojax.models.nets import MatchNet, NetConfig, init_params
from stereojax.models.registry import load_model, shipped_weights
from tests import native_cases as nc
from tests.helpers import require_native


def _both(model, fl, fr, cand):
    native = jax.jit(lambda a, b, c: learned.head_at(MatchNet(model.net), model.variables, a, b, c, 8, "native"))
    xla = jax.jit(lambda a, b, c: learned.head_at(MatchNet(model.net), model.variables, a, b, c, 8, "xla"))
    return np.asarray(native(fl, fr, cand)), np.asarray(xla(fl, fr, cand))


def _check(got, want, what):
    assert got.shape == want.shape
    assert np.all(np.isfinite(got)), what
    # cost = 1 - sigmoid: compare the costs to 1e-5 absolute (they lie in [0, 1]; the logits'
    # rounding differs with the order of the sums)
    err = float(np.abs(got - want).max())
    print(f"max abs diff {what}: {err:.3g}")
    assert err <= 1e-5, (what, err)


@pytest.mark.parametrize("name", ["kitti2015_compact", pytest.param("kitti2015", marks=pytest.mark.slow)])
def test_head_native_equals_jax_on_real_features(data_root, name):
    require_native()
    model = load_model(shipped_weights(name))
    rng = np.random.default_rng(0)
    for crop, left, right in nc.real_pairs(data_root, padded=False):
        fl, fr = learned.tower_features(model.net, model.variables, jnp.asarray(left), jnp.asarray(right))
        h, w = left.shape
        off = rng.integers(0, nc.D - nc.K, (h, w))
        cand = (off[..., None] + rng.integers(0, nc.K, (h, w, 6))).astype(np.int32)
        cand[:, :5] = np.arange(6, dtype=np.int32)[None, None] + 3   # x - d < 0: column 0
        got, want = _both(model, fl, fr, jnp.asarray(cand))
        _check(got, want, f"{name} {crop}")


def test_head_native_handles_widths_off_the_register_blocks():
    require_native()
    net = NetConfig(features=5, layers=1, widths=(20, 7)).validate()
    variables = init_params(net, jax.random.PRNGKey(3))
    model = learned.LearnedModel(net, variables)
    rng = np.random.default_rng(1)
    h, w = 3, 11                     # w not a multiple of 4
    fl = jnp.asarray(rng.normal(size=(h, w, 5)).astype(np.float32))
    fr = jnp.asarray(rng.normal(size=(h, w, 5)).astype(np.float32))
    cand = jnp.asarray(rng.integers(0, 8, (h, w, 3)).astype(np.int32))
    got, want = _both(model, fl, fr, cand)
    _check(got, want, "widths 20-7")


def test_learned_chain_calls_the_native_head_only_with_native_kernels(data_root):
    import dataclasses
    import re

    from stereojax import chain
    from stereojax.models.registry import learned_config

    require_native()
    model = load_model(shipped_weights("kitti2015_compact"))
    _, left, right = nc.real_pairs(data_root, padded=False)[0]
    calls = {}
    for kernels in ("native", "xla"):
        cfg = dataclasses.replace(learned_config("kitti2015_compact", 64), kernels=kernels).validate()
        fn = jax.jit(lambda a, b: chain.front(a, b, cfg, model.variables, model.net).vol.cost)
        text = fn.lower(jnp.asarray(left), jnp.asarray(right)).as_text()
        calls[kernels] = set(re.findall(r"custom_call @(stereojax_\w+)", text))
    assert "stereojax_head_band" in calls["native"], calls["native"]
    assert not calls["xla"], calls["xla"]


def test_head_band_native_fills_the_same_band_volume(data_root):
    """The native head that also writes the band volume (ranked_dense_cost's scatter): the same
    costs, the same volume (the costs at cand - offset, the fill elsewhere), banded and full range."""
    require_native()
    model = load_model(shipped_weights("kitti2015_compact"))
    _, left, right = nc.real_pairs(data_root, padded=False)[1]
    fl, fr = learned.tower_features(model.net, model.variables, jnp.asarray(left), jnp.asarray(right))
    h, w = left.shape
    rng = np.random.default_rng(2)
    for size, off in ((nc.K, rng.integers(0, nc.D - nc.K, (h, w))), (nc.D, np.zeros((h, w), int))):
        # distinct candidates in each pixel's band, as the ranking gives them
        pick = np.argsort(rng.random((h, w, size)), axis=-1)[..., :5]
        cand = jnp.asarray((off[..., None] + pick).astype(np.int32))
        off = jnp.asarray(off.astype(np.int32))
        out = {}
        for kernels in ("native", "xla"):
            fn = jax.jit(lambda a, b, c, o, k=kernels: learned.head_band(MatchNet(model.net), model.variables, a, b, c, o,
                                                                         size, 0.75, 8, k))
            out[kernels] = [np.asarray(x) for x in fn(fl, fr, cand, off)]
        _check(out["native"][0], out["xla"][0], f"head_band cost size={size}")
        _check(out["native"][1], out["xla"][1], f"head_band volume size={size}")
        assert (out["native"][1] == 0.75).sum() == h * w * (size - 5)
