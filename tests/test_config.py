import json

import pytest

from stereojax import ConfigError, StereoConfig, preset
from stereojax.config import AggregationConfig, CostConfig, RefineConfig, SGMConfig


def test_json_round_trip_and_hashable():
    cfg = preset("sad", max_disp=96)
    again = StereoConfig.from_json(cfg.to_json())
    assert again == cfg
    assert hash(again) == hash(cfg)
    assert isinstance(again.cost.census_radius, tuple)


@pytest.mark.parametrize("text, match", [
    ('{"max_dsp": 10}', "did you mean 'max_disp'"),
    ('{"sgm": {"p22": 1.0}}', "did you mean 'sgm.p2'"),
    ('{"sgm": {"directions": 6}}', "directions"),
    ('{"sgm": {"p1": 0.5, "p2": 0.1}}', "p2 must be >= sgm.p1"),
    ('{"max_disp": 2.5}', "integer"),
    ('{"refine": {"median_size": 4}}', "odd"),
    ('{"cost": {"method": "ssd"}}', "census"),
    ('[1, 2]', "object"),
    ('{"max_disp": ', "not valid JSON"),
    ('{"refine": {"lr_check": "yes"}}', "true or false"),
])
def test_bad_configs_raise_config_error(text, match):
    with pytest.raises(ConfigError, match=match):
        StereoConfig.from_json(text)


@pytest.mark.parametrize("sub", [
    CostConfig(census_radius=(0, 3)), AggregationConfig(tau=0), AggregationConfig(arm_length=0),
    SGMConfig(q1=0.5), RefineConfig(lr_tolerance=-1), RefineConfig(bilateral_sigma_space=0),
])
def test_sub_config_validation(sub):
    with pytest.raises(ConfigError):
        sub.validate()


def test_unknown_preset():
    with pytest.raises(ConfigError, match="unknown preset"):
        preset("magic")


def test_to_dict_is_json_serialisable():
    json.dumps(StereoConfig().to_dict())


def test_numpy_integer_max_disp_is_accepted():
    import numpy as np

    from stereojax import StereoConfig, preset

    cfg = preset("census", np.int64(16))
    assert cfg.max_disp == 16 and type(cfg.max_disp) is int
    assert StereoConfig().with_max_disp(np.int32(32)).max_disp == 32
    with pytest.raises(ConfigError):
        preset("census", 16.0)


def test_kernels_setting_is_checked():
    assert StereoConfig().kernels == "auto"
    for bad in ({"kernels": "bogus"}, {"kernels": "XLA"}):
        with pytest.raises(ConfigError, match="kernels must be"):
            StereoConfig.from_dict(bad)
    with pytest.raises(ConfigError, match="kernels must be"):
        StereoConfig(kernels="bogus").validate()
    # the Predictor's kernels= replaces the config's; each setting is its own compiled program
    from stereojax.inference.predictor import Predictor

    with pytest.raises(ConfigError, match="kernels must be"):
        Predictor(preset("census", 16), kernels="bogus")
    xla = Predictor(preset("census", 16), kernels="xla")
    assert xla.config.kernels == "xla" and Predictor(xla.config).config.kernels == "xla"
    assert xla._key(48, 80) != Predictor(preset("census", 16))._key(48, 80)
