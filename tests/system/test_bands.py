"""Per-pixel disparity bands across the chain: the band stages against their numpy references, every stage
with a band covering the whole range against today's full-volume stage (and the whole chain), random
bands by hypothesis, and the band search on a real frame. (Each band kernel alone: the test file of its
module.)"""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stereojax.aggregation import cross_based as aggregation
from stereojax.config import BandConfig, SGMConfig
from stereojax.disparity import right_view, winner_takes_all
from stereojax.matching_cost import classical as cost
from stereojax.optimization.semi_global import sgm, sgm_volume
from stereojax.refinement import parabola
from stereojax.validation import confidence_measure
from stereojax.volume import CostVolume

from ..band_reference import (D, _arms, _band, _case, ref_cbca_band, ref_neutral_band, ref_right_wta,
                              ref_sgm_band, ref_subpixel_band)


def test_wta_right_view_subpixel_neutral_match_references():
    k = 4
    full, off, _, _ = _case(4, k)
    band = _band(full, off, k)
    off_r = np.clip(off[:, ::-1] + 1, 0, D - k).astype(np.int32)
    vol = CostVolume.band(jnp.asarray(band), jnp.asarray(off), D)
    np.testing.assert_array_equal(np.asarray(winner_takes_all.wta_volume(vol)), band.argmin(-1) + off)
    np.testing.assert_array_equal(np.asarray(right_view.right_wta(vol, jnp.asarray(off_r))),
                                  ref_right_wta(band, off, off_r))
    disp = (off + np.random.default_rng(5).integers(-1, k + 1, off.shape)).astype(np.float32)
    np.testing.assert_allclose(np.asarray(parabola.subpixel_volume(vol, jnp.asarray(disp))),
                               ref_subpixel_band(band, off, disp), atol=1e-5)
    np.testing.assert_allclose(np.asarray(cost.neutral_border_volume(vol).cost),
                               ref_neutral_band(band, off), atol=1e-6)


def _whole(full):
    return CostVolume.band(jnp.asarray(full), jnp.zeros(full.shape[:2], jnp.int32), full.shape[-1])


def test_whole_range_band_equals_full_stages():
    full, _, grey, right = _case(7, D)
    g, r, c = jnp.asarray(grey), jnp.asarray(right), jnp.asarray(full)
    whole = _whole(full)
    arms = _arms(grey)
    np.testing.assert_allclose(np.asarray(aggregation.cbca_volume(whole, arms, 2, 3).cost),
                               np.asarray(aggregation.cbca(c, arms, 2, 3)), rtol=1e-5, atol=1e-6)
    cfg = SGMConfig(directions=8, p1=0.1, p2=0.5, grad_threshold=60.0)
    np.testing.assert_allclose(np.asarray(sgm_volume(whole, g, r, cfg).cost), np.asarray(sgm(c, g, r, cfg)),
                               rtol=1e-5, atol=1e-5)
    zeros = jnp.zeros(full.shape[:2], jnp.int32)
    np.testing.assert_array_equal(np.asarray(right_view.right_wta(whole, zeros)),
                                  np.asarray(winner_takes_all.wta(right_view.right_cost_from_left(c))))
    disp = jnp.asarray(full.argmin(-1).astype(np.float32))
    np.testing.assert_allclose(np.asarray(parabola.subpixel_volume(whole, disp)),
                               np.asarray(parabola.subpixel(c, disp)), atol=1e-6)
    np.testing.assert_allclose(np.asarray(cost.neutral_border_volume(whole).cost),
                               np.asarray(cost.neutral_border(c)), atol=1e-6)
    dw = winner_takes_all.wta_volume(whole)
    dr = right_view.right_wta(whole, zeros)
    np.testing.assert_allclose(np.asarray(confidence_measure.confidence_volume(whole, dw, dr)),
                               np.asarray(confidence_measure.confidence(c, dw, dr)), atol=1e-6)


def test_whole_range_band_chain_equals_full_chain(kitti_pair_small):
    """The whole chain with bands of the full width (set by hand) gives the full-range chain."""
    import stereojax
    from stereojax import chain

    left, right = kitti_pair_small
    cfg = stereojax.preset("census", 24)
    full_vol = chain.run(("matching cost",), chain.State(left, right),
                         dataclasses.replace(cfg, band=BandConfig())).vol
    zeros = jnp.zeros(left.shape, jnp.int32)
    whole = CostVolume.band(full_vol.cost, zeros, 24)
    a = np.asarray(chain.run(chain.BACK, chain.State(left, right, vol=full_vol), cfg).disparity)
    b = np.asarray(chain.run(chain.BACK, chain.State(left, right, vol=whole, right_offset=zeros), cfg).disparity)
    # equal up to the order in which SGM's paths are summed (a float tie can then flip a WTA
    # choice: 6 of 10 240 pixels, all within 0.31 px, when written)
    diff = np.abs(a - b)
    assert (diff > 1e-3).mean() < 0.002 and diff.max() < 1.0, (diff > 1e-3).sum()


@pytest.fixture
def kitti_pair_small(data_root):
    """A 64x160 crop of a real KITTI 2015 frame, grey 0..255."""
    from stereojax.data import load_kitti2015
    from stereojax.data.images import as_grey

    s = load_kitti2015(data_root / "kitti2015" / "training", "000003")
    crop = (slice(200, 264), slice(500, 660))
    return jnp.asarray(as_grey(s.left, "left")[crop]), jnp.asarray(as_grey(s.right, "right")[crop])


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(3, D - 1))
def test_random_bands_every_kernel_matches_reference(seed, k):
    full, off, grey, right = _case(seed, k)
    band = _band(full, off, k)
    vol = CostVolume.band(jnp.asarray(band), jnp.asarray(off), D)
    arms = _arms(grey)
    np.testing.assert_allclose(np.asarray(aggregation.cbca_volume(vol, arms, 1, 3).cost),
                               ref_cbca_band(band, off, [np.asarray(a) for a in arms], 1), rtol=1e-5, atol=1e-5)
    cfg = SGMConfig(directions=8, p1=0.1, p2=0.5, adaptive=False)
    np.testing.assert_allclose(np.asarray(sgm_volume(vol, jnp.asarray(grey), jnp.asarray(right), cfg).cost),
                               ref_sgm_band(band, off, D, grey, right, 8, 0.1, 0.5), rtol=1e-5, atol=1e-4)
    off_r = np.roll(off, 2, axis=1)
    np.testing.assert_array_equal(np.asarray(right_view.right_wta(vol, jnp.asarray(off_r))),
                                  ref_right_wta(band, off, off_r))
    disp = band.argmin(-1) + off
    np.testing.assert_allclose(np.asarray(parabola.subpixel_volume(vol, jnp.asarray(disp.astype(np.float32)))),
                               ref_subpixel_band(band, off, disp), atol=1e-5)


@pytest.mark.slow
def test_band_search_measures_coverage_on_a_real_frame(data_root, tmp_path):
    """experiments/band_search.py on one training frame: a 48-wide band from the coarse pass
    covers nearly every GT pixel, and a 6-wide band clearly fewer (that the full range covers
    them all follows from the definition; test_whole_range_band_* check that case)."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "experiments" / "band_search.py"
    spec = importlib.util.spec_from_file_location("band_search", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "bands"
    mod.main(["--data", str(data_root), "--frames", "000003", "--bands", "48/2/1/3/3", "6/2/0/0/0",
              "--out", str(out)])
    rows = {r["band"]: r for r in json.loads(out.with_suffix(".json").read_text())["rows"]}
    assert 97.0 < rows["48/2/1/3/3"]["coverage_pct"] < 100.0
    assert rows["6/2/0/0/0"]["coverage_pct"] < rows["48/2/1/3/3"]["coverage_pct"] - 5
    assert rows["48/2/1/3/3"]["bad3_pct"] < 20
