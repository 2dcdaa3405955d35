"""End-to-end tests of the composed chain: invariants, bad input, real data."""

import dataclasses

import numpy as np
import pytest

import stereojax
from stereojax import ConfigError, StereoConfig, StereoInputError
from stereojax.config import RefineConfig

from .helpers import shifted_pair as _shifted_pair


@pytest.mark.parametrize("method", ["census", "sad"])
@pytest.mark.parametrize("d", [0, 3, 7])
def test_constant_shift_is_recovered_exactly(method, d):
    left, right = _shifted_pair(d)
    cfg = dataclasses.replace(stereojax.preset(method, max_disp=12), refine=RefineConfig(subpixel=False))
    disp = stereojax.disparity(left, right, cfg)
    assert disp.shape == left.shape and disp.dtype == np.float32
    # Exact wherever the match's window lies inside the right image. In the band x < d + 12
    # the right window reaches the image border (edge replication makes the windows differ),
    # so there we ask only for the right answer after rounding on most pixels.
    np.testing.assert_array_equal(disp[:, d + 12:], float(d))
    assert np.mean(np.round(disp[:, : d + 12]) == d) > 0.8


def test_constant_shift_with_subpixel_rounds_to_the_shift():
    left, right = _shifted_pair(5)
    disp = stereojax.disparity(left, right, stereojax.preset("census", max_disp=12))
    assert np.all(np.abs(disp[:, 5 + 12:] - 5) < 0.5)


def test_stages_are_consistent():
    left, right = _shifted_pair(4)
    st = stereojax.stages(left, right, stereojax.preset("census", max_disp=10))
    assert st["cost"].shape == (40, 64, 10)
    assert set(np.unique(st["labels"])) <= {0, 1, 2}
    np.testing.assert_array_equal(st["disp_wta"], np.argmin(st["cost_final"], -1))
    cfg = stereojax.preset("census", 10)
    np.testing.assert_allclose(st["disparity"], stereojax.disparity(left, right, cfg, bucket=False))


def test_inputs_are_not_mutated_and_colour_is_accepted():
    left, right = _shifted_pair(2)
    lc, rc = np.repeat(left[..., None], 3, -1), np.repeat(right[..., None], 3, -1)
    before = lc.copy()
    d1 = stereojax.disparity(lc, rc, stereojax.preset("census", 8))
    np.testing.assert_array_equal(lc, before)
    d2 = stereojax.disparity(left, right, stereojax.preset("census", 8))
    np.testing.assert_allclose(d1, d2, atol=1e-4)


@pytest.mark.parametrize("bad, match", [
    (lambda l, r: (l, r[:, :-1]), "right is"),
    (lambda l, r: (l[:3, :3], r[:3, :3]), "smaller than"),
    (lambda l, r: (l.astype(np.float32) * np.nan, r), "NaN"),
    (lambda l, r: (l[..., None, None], r), "grey or HxWx3"),
])
def test_bad_pairs_raise_typed_errors(bad, match):
    left, right = _shifted_pair(2)
    with pytest.raises(StereoInputError, match=match):
        stereojax.disparity(*bad(left, right), stereojax.preset("census", 8))


@pytest.mark.parametrize("max_disp", [0, -3, 64, 100])
def test_bad_max_disp(max_disp):
    left, right = _shifted_pair(2)
    with pytest.raises((StereoInputError, ConfigError), match="max_disp"):
        stereojax.disparity(left, right, StereoConfig(max_disp=max_disp))


def test_params_with_classical_cost_is_rejected():
    left, right = _shifted_pair(2)
    with pytest.raises(ConfigError, match="classical"):
        stereojax.disparity(left, right, stereojax.preset("census", 8), params={"w": 1})
