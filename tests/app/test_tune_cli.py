"""Fine-tuned models say and keep their settings (issue 55, item 2): `train --init MODEL` takes
MODEL's network and carries its card (marked inherited), predict's first line says where a
checkpoint's chain settings come from, and `stereojax tune` searches them and writes its card."""

from __future__ import annotations

import json

import pytest

from stereojax.errors import ConfigError
from stereojax.models.registry import chain_settings, learned_config, shipped_weights

from ..helpers import fake_kitti, run_cli
from ..robustness_helpers import _cli, _one_line


def _train(root, out, capsys, *extra):
    return run_cli(["train", "--data", root, "--dataset", "kitti2015", "--frames", "0-1", "--preset", "tiny",
                    *extra, "--out", out], capsys)


def _predict_first_line(root, weights, out, capsys):
    code, stdout, err = run_cli(["predict", root / "image_2" / "000000_10.png", root / "image_3" / "000000_10.png",
                                 "--out", out, "--max-disp", 16, "--check-rectified", "off", "--weights", weights],
                                capsys)
    assert code == 0, err
    return stdout.splitlines()[0]


def test_train_init_takes_the_network_and_the_card_of_the_model(tmp_path, capsys):
    root = tmp_path / "kitti" / "training"
    fake_kitti(root, n=2)
    out = tmp_path / "ft"
    code, stdout, err = _train(root, out, capsys, "--init", "kitti2015_compact")
    assert code == 0, err
    net = json.loads((out / "config.json").read_text())["net"]
    assert net["features"] == 16 and net["widths"] == [64, 32]
    card = json.loads((out / "checkpoint.json").read_text())
    assert card["chain"] == chain_settings(shipped_weights("kitti2015_compact"))
    assert "inherited from kitti2015_compact" in card["chain_from"]
    line = _predict_first_line(root, out / "checkpoint.msgpack", tmp_path / "p", capsys)
    assert "weights checkpoint.msgpack" in line and "inherited from kitti2015_compact" in line
    ran = json.loads((tmp_path / "p" / "config.json").read_text())
    want = json.loads(learned_config("kitti2015_compact", ran["max_disp"]).to_json())
    for section in ("cost", "cbca", "sgm", "refine", "band"):
        assert ran[section] == want[section], section


def test_train_init_with_a_network_that_does_not_fit_names_the_flags(tmp_path, capsys):
    root = tmp_path / "kitti" / "training"
    fake_kitti(root, n=2)
    code, _, err = _cli(["train", "--data", root, "--dataset", "kitti2015", "--frames", "0-1", "--preset", "tiny",
                         "--init", "kitti2015_compact", "--features", "32", "--out", tmp_path / "x"], capsys)
    line = _one_line(err)
    assert code == ConfigError.exit_code and "--features 32 do not fit" in line and "16 maps" in line and "64,32" in line
    assert not (tmp_path / "x").exists()


def test_weights_without_a_card_say_they_run_settings_never_searched_for_them(tmp_path, capsys):
    root = tmp_path / "kitti" / "training"
    fake_kitti(root, n=2)
    code, _, err = _train(root, tmp_path / "fresh", capsys)
    assert code == 0, err
    assert not (tmp_path / "fresh" / "checkpoint.json").exists()
    line = _predict_first_line(root, tmp_path / "fresh" / "checkpoint.msgpack", tmp_path / "p", capsys)
    assert "default chain settings, never searched for these weights" in line and "stereojax tune" in line


def test_shipped_models_keep_their_first_line(tmp_path, capsys):
    root = tmp_path / "kitti" / "training"
    fake_kitti(root, n=1)
    line = _predict_first_line(root, "kitti2015_compact", tmp_path / "p", capsys)
    assert "shipped model kitti2015_compact" in line and "never searched" not in line and "inherited" not in line


def test_tune_refuses_a_shipped_model(capsys):
    code, _, err = _cli(["tune", "--weights", "kitti2015", "--data", "x", "--dataset", "kitti2015", "--frames", "1"],
                        capsys)
    assert code == ConfigError.exit_code and "shipped model" in _one_line(err)


@pytest.mark.slow
def test_tune_searches_a_checkpoint_and_writes_its_card(tmp_path, capsys, monkeypatch, data_root):
    """On a real Middlebury scene, with a two-value space (P1) to keep it short."""
    from stereojax.app import tune as tune_mod

    monkeypatch.setitem(tune_mod.SPACES, "small", [("sgm", "p1", [0.5, 1.5])])
    root = tmp_path / "kitti" / "training"
    fake_kitti(root, n=2)
    out = tmp_path / "ft"
    assert _train(root, out, capsys, "--init", "kitti2015_compact")[0] == 0
    code, stdout, err = _cli(["tune", "--weights", out / "checkpoint.msgpack", "--data", data_root / "middlebury",
                              "--dataset", "middlebury", "--frames", "Tsukuba_2001"], capsys)
    assert code == 0, err
    assert "-> " + str(out / "checkpoint.json") in stdout
    card = json.loads((out / "checkpoint.json").read_text())
    assert card["chain_from"].startswith("searched by stereojax tune on 1 frames (Tsukuba_2001)")
    assert card["tuned"]["frames"] == ["Tsukuba_2001"] and len(card["tuned"]) >= 5
    assert card["chain"]["sgm"]["p1"] in (0.5, 1.5, chain_settings(shipped_weights("kitti2015_compact"))["sgm"]["p1"])
    line = _predict_first_line(root, out / "checkpoint.msgpack", tmp_path / "p", capsys)
    assert "searched by stereojax tune" in line
