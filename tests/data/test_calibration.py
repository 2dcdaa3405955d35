"""stereojax.data.calibration: calibration files (KITTI, Middlebury, OpenCV YAML, JSON) give depth in metres
that matches a hand computation, and implausible scales are flagged."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereojax.data.calibration import plausibility_warnings, read_calibration
from stereojax.data.datasets import Calibration
from stereojax.errors import StereoInputError

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
MOTORCYCLE = DATA / "middlebury" / "Motorcycle_MiddEval3Q"
needs_data = pytest.mark.skipif(not MOTORCYCLE.is_dir(), reason=f"real data not found at {DATA}")
# a KITTI 2012 calib/<frame>.txt in the KITTI format (values of KITTI 2012 training frame 000000)
KITTI2012 = """P0: 7.070912e+02 0.000000e+00 6.018873e+02 0.000000e+00 0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
P1: 7.070912e+02 0.000000e+00 6.018873e+02 -3.798145e+02 0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
P2: 7.070912e+02 0.000000e+00 6.018873e+02 4.688783e+01 0.000000e+00 7.070912e+02 1.831104e+02 1.178601e-01 0.000000e+00 0.000000e+00 1.000000e+00 6.203223e-03
P3: 7.070912e+02 0.000000e+00 6.018873e+02 -3.334597e+02 0.000000e+00 7.070912e+02 1.831104e+02 1.930130e+00 0.000000e+00 0.000000e+00 1.000000e+00 3.318498e-03
"""
CAM_TO_CAM = """calib_time: 09-Jan-2012 14:00:15
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
"""


def _depth_at(calib: Calibration, d: float) -> float:
    from stereojax.data.depth import disparity_to_depth

    return float(disparity_to_depth(np.full((2, 2), d, np.float32), calib.baseline, calib.focal, calib.doffs)[0, 0])


@needs_data
def test_middlebury_calib_txt_gives_metres():
    calib, kind = read_calibration(MOTORCYCLE / "calib.txt")
    assert "Middlebury" in kind
    assert calib.baseline == pytest.approx(0.193001) and calib.focal == pytest.approx(999.421)
    assert calib.doffs == pytest.approx(32.778)
    # by hand: Z = 0.193001 m * 999.421 px / (40 px + 32.778 px)
    assert _depth_at(calib, 40.0) == pytest.approx(0.193001 * 999.421 / 72.778, rel=1e-5)


@pytest.mark.parametrize("text, name, focal, baseline", [
    (KITTI2012, "000000.txt", 707.0912, (46.88783 + 333.4597) / 707.0912),
    (CAM_TO_CAM, "calib_cam_to_cam.txt", 721.5377, (44.85728 + 339.5242) / 721.5377)])
def test_kitti_calibrations_give_the_baseline_of_the_projection_matrices(tmp_path, text, name, focal, baseline):
    path = tmp_path / name
    path.write_text(text)
    calib, kind = read_calibration(path)
    assert "KITTI" in kind and calib.focal == pytest.approx(focal) and calib.baseline == pytest.approx(baseline)
    assert 0.5 < calib.baseline < 0.56                                   # KITTI's ~0.54 m
    assert _depth_at(calib, 30.0) == pytest.approx(baseline * focal / (30.0 + calib.doffs), rel=1e-5)


def test_opencv_yaml_and_json(tmp_path):
    k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    fs = cv2.FileStorage(str(tmp_path / "cam.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("K", k)
    fs.write("baseline", 0.12)
    fs.release()
    (tmp_path / "cam.json").write_text(json.dumps({"K": k.tolist(), "baseline": 0.12}))
    for name in ("cam.yaml", "cam.json"):
        calib, _ = read_calibration(tmp_path / name)
        assert (calib.focal, calib.baseline, calib.doffs, calib.cx) == (800.0, 0.12, 0.0, 320.0)
        assert _depth_at(calib, 16.0) == pytest.approx(0.12 * 800 / 16)
    (tmp_path / "bad.json").write_text(json.dumps({"K": [[1, 2], [3, 4]], "baseline": 0.1}))
    with pytest.raises(StereoInputError, match="3x3"):
        read_calibration(tmp_path / "bad.json")
    (tmp_path / "other.txt").write_text("hello\n")
    with pytest.raises(StereoInputError, match="not a format"):
        read_calibration(tmp_path / "other.txt")


def test_implausible_scales_are_flagged():
    mm = Calibration(baseline=193.0, focal=999.4)
    assert any("millimetres" in w for w in plausibility_warnings(mm))
    ok = Calibration(baseline=0.54, focal=721.5)
    assert plausibility_warnings(ok, np.full((4, 4), 12.0)) == []
    assert any("median depth" in w for w in plausibility_warnings(depth=np.full((4, 4), 5000.0)))
