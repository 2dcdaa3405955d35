"""stereojax.models.registry: which shipped model runs for an input and why, and the chain settings that
travel with a model."""

import pytest

from stereojax.errors import CheckpointError


def test_default_method_picks_the_shipped_model_for_the_input(tmp_path):
    from pathlib import Path

    from stereojax.models.registry import (BEST, SHIPPED, WEIGHTS_DIR, resolve as models_resolve,
                                           weights_for_input)

    kitti = WEIGHTS_DIR / f"{SHIPPED[BEST['kitti']]}.msgpack"          # what best runs on KITTI
    full = WEIGHTS_DIR / "kitti2015_downsize_relaxed.msgpack"          # the paper's network
    mb = WEIGHTS_DIR / "middlebury_downsize_relaxed.msgpack"
    assert kitti.is_file() and full.is_file()
    assert weights_for_input(1242, 375) == kitti                     # wide road frame
    assert weights_for_input(1224, 370) == kitti                     # another KITTI size
    assert weights_for_input(10, 10, "kitti2012") == kitti           # by data set
    assert weights_for_input(741, 500) == (mb if mb.is_file() else None)
    assert weights_for_input(1242, 375, "middlebury") == (mb if mb.is_file() else None)

    def resolve(config=None, **kw):
        from stereojax.config import StereoConfig

        cfg = StereoConfig.from_json(Path(config).read_text()) if config else None
        run = models_resolve(config=cfg, width=1242, height=375, **kw)
        return run.method, (str(run.weights) if run.weights else None)

    assert resolve() == ("learned", str(kitti))
    assert resolve(method="census") == ("census", None)
    assert resolve(weights="kitti2015") == ("learned", str(full))    # a shipped name
    for name, stem in SHIPPED.items():                               # every shipped name resolves
        assert resolve(weights=name) == ("learned", str(WEIGHTS_DIR / f"{stem}.msgpack"))
    with pytest.raises(CheckpointError, match="no shipped model named"):
        stereojax_models().shipped_weights("kitti2016")
    cfg = tmp_path / "sad.json"
    cfg.write_text(stereojax_preset_json("sad"))
    assert resolve(config=str(cfg)) == ("sad", None)                 # a classical chain from --config


def stereojax_models():
    import stereojax.models.registry
    return stereojax.models.registry


def test_best_runs_the_same_chain_on_every_backend_and_the_exact_head_on_request(monkeypatch):
    """`best` never switches to the exact head by backend; --exact-head asks for it."""
    import jax

    from stereojax.models.registry import learned_config, resolve, weights_for_input

    seen = []
    for backend in ("cpu", "gpu"):
        monkeypatch.setattr(jax, "default_backend", lambda b=backend: b)
        run = resolve("best", width=1242, height=375)
        seen.append((run.config, run.description))
    assert seen[0] == seen[1]
    assert seen[0][0] == learned_config(weights_for_input(1242, 375), 228)
    assert seen[0][0].cost.candidates > 0 and "exact" not in seen[0][1]
    assert "shipped model kitti2015" in seen[0][1]
    run = resolve("best", width=1242, height=375, exact_head=True)
    assert run.config.cost.candidates == 0 and "exact head" in run.description
    with pytest.raises(stereojax_config_error(), match="--weights needs --method learned"):
        resolve("census", weights="kitti2015")


def stereojax_config_error():
    from stereojax.errors import ConfigError
    return ConfigError


def stereojax_preset_json(name):
    from stereojax import preset

    return preset(name, 16).to_json()


def test_best_rule_and_scene_option():
    from stereojax.models.registry import BEST, SHIPPED, WEIGHTS_DIR, resolve

    if not all((WEIGHTS_DIR / f"{SHIPPED[BEST[k]]}.msgpack").is_file() for k in BEST):
        pytest.skip("the shipped models are not all there")
    crop = resolve("best", width=900, height=375)                  # a KITTI crop: not wide enough
    assert crop.weights.name.startswith("middlebury") and "less than 2.5 times as wide" in crop.reason
    road = resolve("best", width=900, height=375, scene="road")
    assert road.weights.name.startswith("kitti2015") and road.reason == "--method best: --scene road"
    assert "(--method best: --scene road)" in road.chosen_line
    wide = resolve("best", width=1242, height=375, scene="indoor")
    assert wide.weights.name.startswith("middlebury")
    kitti = resolve("best", width=1242, height=375)
    assert kitti.weights.name.startswith("kitti2015") and "road frame" in kitti.reason


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
