"""Per-pixel disparity limits from the Python API: ``pixel_range=(MIN, MAX)``, two ``[H, W]``
maps, MIN <= d < MAX at each pixel, intersected with the range and with the bands."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax import StereoInputError, chain
from stereojax.volume import BIG, CostVolume

from .helpers import textured


def _pair(d, h=48, w=128, seed=3, image=None):
    """left(x) == right(x - d)."""
    big = textured(h, w + 2 * abs(d) + 2, seed) if image is None else image
    c = abs(d) + 1
    return big[:, c: c + w], big[:, c + d: c + d + w]


def _banded(max_disp=64, width=16):
    cfg = stereojax.preset("census", max_disp)
    return dataclasses.replace(cfg, band=dataclasses.replace(cfg.band, width=width))


def _maps(shape, lo, hi):
    return np.full(shape, lo, np.int32), np.full(shape, hi, np.int32)


def test_the_limits_stage_against_numpy():
    """Entries outside a pixel's limits cost BIG, the others are untouched (full range
    and bands)."""
    rng = np.random.default_rng(0)
    h, w, d, k = 5, 7, 12, 4
    lo = rng.integers(0, 8, (h, w)).astype(np.int32)
    hi = (lo + rng.integers(1, 5, (h, w))).astype(np.int32)
    lim = jnp.asarray(np.stack([lo, hi]))
    full = rng.random((h, w, d)).astype(np.float32)
    got = chain._limits(chain.State(None, None, limits=lim, vol=CostVolume.full(jnp.asarray(full))), None).vol.cost
    disp = np.arange(d)[None, None, :]
    want = np.where((disp >= lo[..., None]) & (disp < hi[..., None]), full, BIG)
    np.testing.assert_array_equal(np.asarray(got), want)
    off = rng.integers(0, d - k + 1, (h, w)).astype(np.int32)
    band = rng.random((h, w, k)).astype(np.float32)
    vol = CostVolume.band(jnp.asarray(band), jnp.asarray(off), d)
    got = chain._limits(chain.State(None, None, limits=lim, vol=vol), None).vol.cost
    disp = off[..., None] + np.arange(k)
    want = np.where((disp >= lo[..., None]) & (disp < hi[..., None]), band, BIG)
    np.testing.assert_array_equal(np.asarray(got), want)


def test_bands_move_inside_the_limits():
    """A band moves by as little as it takes: inside limits K wide or wider, around narrower
    ones (a band that already holds them stays); always inside 0 .. D - K."""
    cfg = _banded(64, 16)
    rng = np.random.default_rng(1)
    off = rng.integers(0, 49, (6, 9)).astype(np.int32)
    lo = rng.integers(0, 60, (6, 9)).astype(np.int32)
    hi = np.minimum(lo + rng.integers(1, 40, (6, 9)), 64).astype(np.int32)
    got = np.asarray(chain.limit_bands(jnp.asarray(off), jnp.asarray(np.stack([lo, hi])), cfg))
    want = off.copy()
    for i, j in np.ndindex(off.shape):                  # the nearest start whose band fits or holds
        starts = [s for s in range(0, 49) if (lo[i, j] <= s and s + 16 <= hi[i, j]) or
                  (s <= lo[i, j] and hi[i, j] <= s + 16)]
        if starts:
            want[i, j] = min(starts, key=lambda s: abs(s - off[i, j]))
        else:                                            # limits reach past 0 .. D - K: its nearest end
            want[i, j] = np.clip(off[i, j], 0, 48)
    np.testing.assert_array_equal(got, want)
    wide = hi - lo >= 16
    assert np.all(got[wide] >= lo[wide]) and np.all(got[wide] + 16 <= hi[wide])
    narrow = ~wide & (hi <= 64)
    assert np.all(got[narrow] <= lo[narrow]) and np.all(got[narrow] + 16 >= hi[narrow])
    holds = (off <= lo) & (hi <= off + 16)
    np.testing.assert_array_equal(got[holds], off[holds])        # already holding them: unmoved


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
