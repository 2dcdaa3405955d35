"""The confidence's texture term (issue 55, item 3): where the census window has nothing for the
cost to work on (saturated sky), the chain's disparity is not confident."""

import dataclasses

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

import stereojax
from stereojax.validation.confidence_measure import texture_factor, texture_share


def test_texture_share_counts_the_window_pixels_that_differ_beyond_the_noise():
    flat = jnp.full((20, 30), 255.0)
    assert float(texture_share(flat, (3, 4), 2.0).max()) == 0.0
    img = np.full((20, 30), 100.0, np.float32)
    img[10, 15] = 110.0                                  # one bright pixel
    share = np.asarray(texture_share(jnp.asarray(img), (3, 4), 2.0))
    assert share[10, 15] == pytest.approx(1.0)           # every neighbour differs from it
    assert share[10, 16] == pytest.approx(1 / 62)        # its neighbours see one of 62
    assert share[0, 0] == 0.0
    assert share[10, 15 + 5] == 0.0                      # outside the 7x9 window
    factor = np.asarray(texture_factor(jnp.asarray(img), (3, 4), 2.0, 0.25))
    assert factor[10, 15] == 1.0 and factor[10, 16] == pytest.approx(4 / 62)
    assert np.all(np.asarray(texture_factor(jnp.asarray(img), (3, 4), 2.0, 0.0)) == 1.0)   # off


def test_saturated_sky_of_a_real_frame_is_not_confident(data_root):
    """KITTI 2015 000001's sky (grey >= 250 and a flat 7x7 window): with the texture term, almost
    none of it keeps confidence >= 0.3 (30 % without it); the rest of the crop keeps most of its."""
    from stereojax.data.datasets import load_kitti2015

    s = load_kitti2015(data_root / "kitti2015" / "training", "000001", "noc")
    crop = (slice(0, 160), slice(300, 700))
    left, right = s.left[crop], s.right[crop]
    g = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mean = cv2.blur(g, (7, 7))
    sky = (g >= 250) & (np.sqrt(np.maximum(cv2.blur(g * g, (7, 7)) - mean * mean, 0)) < 2)
    assert sky.sum() > 10000
    cfg = stereojax.preset("census", max_disp=64)
    off = dataclasses.replace(cfg, refine=dataclasses.replace(cfg.refine, texture_full=0.0))
    _, conf = stereojax.Predictor(cfg, confidence=True)(left, right)
    _, conf_off = stereojax.Predictor(off, confidence=True)(left, right)
    assert (conf_off[sky] >= 0.3).mean() > 0.2
    assert (conf[sky] >= 0.3).mean() < 0.01
    assert (conf[~sky] >= 0.3).mean() > 0.8
    assert np.all(conf <= conf_off + 1e-6)              # the term only ever lowers the confidence
