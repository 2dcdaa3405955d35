"""stereojax.inference.predictor end to end: the composed chain's invariants, bad input, real data; per-pixel
limits (``pixel_range=(MIN, MAX)``, two ``[H, W]`` maps, MIN <= d < MAX at each pixel, intersected with the
range and with the bands), the confidence map, and the cached-volume path (volume -> from_volume)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import stereojax
from stereojax import ConfigError, StereoConfig, StereoInputError
from stereojax.config import RefineConfig

from ..helpers import (banded_census as _banded, shifted_pair, shifted_pair as _shifted_pair, textured,
                       training_samples)


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


def _pair(d, h=48, w=128, seed=3, image=None):
    """left(x) == right(x - d)."""
    big = textured(h, w + 2 * abs(d) + 2, seed) if image is None else image
    c = abs(d) + 1
    return big[:, c: c + w], big[:, c + d: c + d + w]


def _maps(shape, lo, hi):
    return np.full(shape, lo, np.int32), np.full(shape, hi, np.int32)


@pytest.mark.parametrize("banded", [False, True])
def test_limits_of_the_whole_range_change_nothing(banded):
    left, right = _pair(9)
    cfg = _banded() if banded else stereojax.preset("census", 64)
    free = stereojax.disparity(left, right, cfg)
    whole = stereojax.disparity(left, right, cfg, pixel_range=_maps(left.shape, 0, 64))
    np.testing.assert_array_equal(free, whole)


@pytest.mark.parametrize("banded", [False, True])
def test_every_pixel_stays_inside_its_own_limits(banded):
    left, right = _pair(9)
    cfg = _banded() if banded else stereojax.preset("census", 64)
    rng = np.random.default_rng(2)
    block = lambda a: np.kron(a, np.ones((16, 16), np.int32))       # limits constant in 16x16 blocks
    lo = block(rng.integers(0, 16, (3, 8))).astype(np.int32)
    hi = lo + block(rng.integers(1, 12, (3, 8))).astype(np.int32)
    lo[::7, ::5] = 30                                                # and single pixels that differ
    hi[::7, ::5] = 31
    disp = stereojax.disparity(left, right, cfg, pixel_range=(lo, hi))
    assert np.all(disp >= lo) and np.all(disp <= hi - 1)
    # where the true disparity 9 is allowed in a whole block, the chain finds it (away from the
    # block's edges and the single pixels)
    inner = np.zeros(left.shape, bool)
    inner[6:-6, 24:-12] = True
    inner &= (np.arange(48)[:, None] % 16 >= 3) & (np.arange(48)[:, None] % 16 <= 12)
    inner &= (np.arange(128)[None, :] % 16 >= 3) & (np.arange(128)[None, :] % 16 <= 12)
    allowed = inner & (lo <= 8) & (hi >= 11)
    assert allowed.sum() > 200
    assert (np.abs(disp[allowed] - 9) < 1).mean() > 0.9


@pytest.mark.parametrize("banded", [False, True])
def test_limits_choose_among_repeated_matches(banded):
    """Vertical stripes of period 8: disparities 2, 10, 18 ... match equally well. Limits
    8 <= d < 13 must pick 10 by the costs, not by cutting a wrong answer to the nearest limit."""
    h, w = 48, 160
    rng = np.random.default_rng(4)
    stripes = np.tile((np.arange(w + 40) % 8 < 4) * 200.0 + 20.0, (h, 1))
    left, right = (np.clip(v + rng.normal(0, 6.0, v.shape), 0, 255).astype(np.uint8)   # noise of its own
                   for v in _pair(10, h=h, w=w, image=stripes))
    cfg = _banded(64, 16) if banded else stereojax.preset("census", 64)
    free = stereojax.disparity(left, right, cfg)[6:-6, 32:-12]
    assert (np.abs(free - 10) < 1).mean() < 0.8          # unlimited, other periods win often
    disp = stereojax.disparity(left, right, cfg, pixel_range=_maps(left.shape, 8, 13))
    inner = disp[6:-6, 32:-12]
    assert (np.abs(inner - 10) < 1).mean() > 0.95, np.unique(np.round(inner), return_counts=True)


def test_limits_with_a_negative_range():
    left, right = _pair(-6)
    cfg = stereojax.preset("census", 16)
    lo, hi = _maps(left.shape, -8, -3)
    disp = stereojax.disparity(left, right, cfg, disp_range=(-16, 8), pixel_range=(lo, hi))
    assert disp.min() >= -8 and disp.max() <= -4
    assert np.median(disp[6:-6, 24:-24]) == pytest.approx(-6, abs=0.25)


def test_limits_in_horizontal_bands_stay_inside():
    """The tiled path cuts the maps into the same bands as the images."""
    left, right = _pair(9, h=64)
    pred = stereojax.Predictor(stereojax.preset("census", 64))
    lo, hi = _maps(left.shape, 5, 12)
    lo[:32] = 0
    hi[:32] = 4
    limits = pred.limits((lo, hi), left.shape)
    out = pred.in_strips(left, right, rows=40, overlap=8, limits=limits)
    assert np.all(out >= lo) and np.all(out <= hi - 1)
    assert (np.abs(out[40:-6, 24:-12] - 9) < 1).mean() > 0.9


@pytest.mark.parametrize("maps,msg", [
    ("nothing", "two \\[H, W\\] maps"),
    ((np.zeros((48, 127)), np.ones((48, 127))), "maps are 127x48, the image is 128x48"),
    ((np.zeros((48, 128)) + 0.5, np.full((48, 128), 9.0)), "must hold integers"),
    ((np.full((48, 128), 5), np.full((48, 128), 5)), "leaves 6144 pixels no disparity"),
    ((np.full((48, 128), 70), np.full((48, 128), 90)), "within the range 0..64"),
])
def test_bad_maps_are_refused_in_one_line(maps, msg):
    left, right = _pair(2)
    with pytest.raises(StereoInputError, match=msg) as exc:
        stereojax.disparity(left, right, stereojax.preset("census", 64), pixel_range=maps)
    assert "\n" not in str(exc.value)


@pytest.mark.slow
@pytest.mark.parametrize("name,dense", [("kitti2015", False), ("kitti2015_compact", True)])
def test_the_learned_chains_keep_a_real_frame_inside_its_limits(data_root, name, dense):
    """The learned chains (a card's two programs: bands, census candidates, head; and the head
    at every disparity of a 24-wide band, one program) with limits from the ground truth: inside
    them everywhere, and closer to the truth than without them."""
    from stereojax.models import registry as models
    from stereojax.data.datasets import load_kitti2015

    sample = load_kitti2015(data_root / "kitti2015" / "training", "000001")
    left, right = sample.left[150:246, 400:656], sample.right[150:246, 400:656]
    gt = sample.gt[150:246, 400:656]
    known = sample.gt_valid[150:246, 400:656]
    weights = models.shipped_weights(name)
    model = stereojax.load_model(weights)
    cfg = models.learned_config(weights, 96)
    if dense:
        cfg = dataclasses.replace(cfg, cost=dataclasses.replace(cfg.cost, candidates=0),
                                  band=dataclasses.replace(cfg.band, width=24))
    assert cfg.banded and stereojax.chain.two_programs(cfg, model.net) == (not dense)
    lo = np.where(known, np.floor(gt) - 3, 0).astype(np.int32)
    hi = np.where(known, np.ceil(gt) + 4, 96).astype(np.int32)
    free = stereojax.disparity(left, right, cfg, params=model)
    disp = stereojax.disparity(left, right, cfg, params=model, pixel_range=(lo, hi))
    assert np.all(disp >= lo) and np.all(disp <= hi - 1)
    err = lambda d: (np.abs(d - gt)[known] > 3).mean()
    assert err(disp) <= err(free) and err(disp) < 0.01


def test_the_chains_own_answer_as_its_limits_moves_nothing(data_root):
    """Limits of the chain's own disparity +- 5 px (a prior that agrees with it): the bands stay
    where the coarse pass put them, so SGM aggregates the same costs, and nearly every pixel and
    the error stay (they moved when every band was started at MIN)."""
    from stereojax.data.datasets import load_kitti2015

    sample = load_kitti2015(data_root / "kitti2015" / "training", "000021")
    rows, cols = slice(150, 246), slice(380, 700)
    left, right, gt, known = (a[rows, cols] for a in (sample.left, sample.right, sample.gt, sample.gt_valid))
    cfg = _banded(96, 24)
    assert cfg.banded
    free = stereojax.disparity(left, right, cfg)
    lo = np.clip(np.floor(free) - 5, 0, 95).astype(np.int32)
    hi = np.clip(np.ceil(free) + 6, 1, 96).astype(np.int32)
    own = stereojax.disparity(left, right, cfg, pixel_range=(lo, hi))
    assert np.all(own >= lo) and np.all(own <= hi - 1)
    # measured on this crop: 94.5 % of the pixels unchanged (79.7 % when every band started at
    # MIN); the rest differ where the limits change the WTA of pixels that the left-right check
    # then labels otherwise, and the filters carry that to their neighbours
    same = np.abs(own - free) < 1e-4
    assert same.mean() > 0.9, same.mean()
    err = lambda d: 100 * (np.abs(d - gt)[known] > 3).mean()      # noqa: E731
    assert abs(err(own) - err(free)) <= 0.3, (err(own), err(free))           # 0.23 measured (30 pixels)


def test_predictor_confidence_is_low_where_the_match_is_wrong():
    left, right = shifted_pair(5, h=64, w=128, seed=3)
    rng = np.random.default_rng(9)
    right = right.copy()
    right[16:48, 40:80] = rng.integers(0, 256, (32, 40))        # no true match for left x 45..84
    cfg = stereojax.preset("census", 24)
    disp, conf = stereojax.Predictor(cfg, confidence=True)(left, right)
    np.testing.assert_array_equal(disp, stereojax.Predictor(cfg)(left, right))
    assert conf.shape == disp.shape and conf.dtype == np.float32
    assert 0.0 <= conf.min() and conf.max() <= 1.0
    good = np.zeros(disp.shape, bool)
    good[8:56, 30:40] = good[8:56, 95:120] = True
    bad = np.zeros(disp.shape, bool)
    bad[20:44, 50:80] = True
    assert conf[good].mean() > 2 * conf[bad].mean()
    # the most confident half is more often right than all pixels (a sparsification step)
    wrong = np.abs(disp - 5) > 1
    top = conf >= np.median(conf)
    assert wrong[top].mean() < 0.5 * wrong.mean()
    d2, c2 = stereojax.disparity(left, right, cfg, confidence=True)
    np.testing.assert_array_equal(c2, conf)


def test_volume_then_from_volume_equals_the_whole_chain():
    """What the chain search scores (cached volume, then the rest) is what the chain computes,
    for a classical and a learned cost and for changed back-end settings."""
    from stereojax.models.nets import init_params, net_preset
    from stereojax.matching_cost.learned import LearnedModel
    import jax

    left, right = training_samples(1, h=40, w=72, d=4)[0].left, training_samples(1, h=40, w=72, d=4)[0].right
    net = net_preset("downsize", 4)
    net = dataclasses.replace(net, widths=(8, 4)).validate()
    model = LearnedModel(net, init_params(net, jax.random.PRNGKey(1)))
    learned = stereojax.preset("learned", 12)
    learned = dataclasses.replace(learned, cost=dataclasses.replace(learned.cost, candidates=4, unsure_share=0.0,
                                                                     unsure_candidates=0)).validate()
    for cfg, m in ((stereojax.preset("census", 12), None), (learned, model)):
        predictor = stereojax.Predictor(cfg, m)
        vol = predictor.volume(left, right)
        np.testing.assert_allclose(predictor.from_volume(vol), predictor(left, right), atol=1e-5)
        other = dataclasses.replace(cfg, sgm=dataclasses.replace(cfg.sgm, p2=cfg.sgm.p2 * 3)).validate()
        np.testing.assert_allclose(stereojax.Predictor(other, m).from_volume(vol),
                                   stereojax.Predictor(other, m)(left, right), atol=1e-5)
