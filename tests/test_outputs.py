"""stereojax.app.outputs: the pictures a person looks at (colour depth, its reliability mask, the
error map's legend) and the output folder's bookkeeping."""

import json

import numpy as np

from stereojax.app.outputs import (RELIABLE_MIN_CONFIDENCE, RELIABLE_MIN_DISP, depth_color, depth_reliable,
                                   write_prediction)
from stereojax.data import io
from stereojax.data.calibration import Calibration


def test_depth_is_reliable_only_at_large_confident_disparities():
    disp = np.array([[np.inf, 2.0, RELIABLE_MIN_DISP - 0.01, RELIABLE_MIN_DISP, 40.0]], np.float32)
    assert depth_reliable(disp).tolist() == [[False, False, False, True, True]]
    conf = np.array([[1, 1, 1, 1, RELIABLE_MIN_CONFIDENCE - 0.01]], np.float32)
    assert depth_reliable(disp, conf).tolist() == [[False, False, False, True, False]]


def test_depth_colour_runs_near_red_to_far_blue_and_greys_the_unreliable():
    z = np.tile(np.linspace(2.0, 20.0, 100, dtype=np.float32), (4, 1))
    z[:, :3] = 0.0                                              # no depth
    reliable = np.ones_like(z, bool)
    reliable[0] = False                                         # a row we do not trust
    rgb, scale = depth_color(z, reliable)
    assert rgb.shape == z.shape + (3,) and rgb.dtype == np.uint8
    near, far = rgb[1, 3], rgb[1, -1]
    assert near[0] > near[2] and far[2] > far[0]                # red near, blue far
    assert (rgb[:, :3] == 0).all()                              # no depth: black
    assert (rgb[0, 3:, 0] == rgb[0, 3:, 1]).all() and (rgb[0, 3:, 1] == rgb[0, 3:, 2]).all()   # grey
    assert rgb[0, 3:].max() < 128                               # at half brightness
    assert 2.0 <= scale["near"] < scale["far"] <= 20.0 and scale["unit"] == "m"
    assert scale["reliable_to_m"] == 20.0 and 70 < scale["reliable_share_pct"] < 80


def test_write_prediction_writes_the_colour_depth_its_scale_and_mask(tmp_path):
    disp = np.full((20, 30), 25.0, np.float32)
    disp[:, :10] = 3.0                                           # far: 1 px moves its depth by a third
    conf = np.ones_like(disp)
    conf[15:] = 0.1
    names = write_prediction(tmp_path, "", disp, Calibration(0.5, 100.0), ply=False, confidence=conf)
    assert {"depth_color.png", "depth_color.json", "depth_reliable.png"} <= set(names)
    mask = io.read_image(tmp_path / "depth_reliable.png") > 0
    assert mask[:15, 10:].all() and not mask[:, :10].any() and not mask[15:].any()
    scale = json.loads((tmp_path / "depth_color.json").read_text())
    assert scale["reliable_to_m"] == 2.0                         # 0.5 m x 100 px / 25 px
    assert io.read_image(tmp_path / "depth_color.png").shape == (20, 30, 3)


def test_the_error_legend_shows_every_band_of_the_error_map():
    legend = io.error_legend()
    assert legend.ndim == 3 and legend.shape[1] >= 300
    colours = {tuple(c) for c in legend.reshape(-1, 3)}
    for _, _, colour in io.KITTI_ERROR_COLORS:
        assert tuple(colour) in colours
