"""stereojax.data.datasets: layouts on tiny synthetic trees, then the real data when present."""

import numpy as np
import pytest

from stereojax.data import datasets as ds
from stereojax.data import io
from stereojax.errors import StereoInputError

# real KITTI calibration rows (KITTI 2015 calib_cam_to_cam/000000.txt, KITTI 2012 calib/000000.txt)
P_RECT_02 = "7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03"
P_RECT_03 = "7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03"
K12 = {
    "P0": "7.070912e+02 0.000000e+00 6.018873e+02 0.000000e+00 0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00",
    "P1": "7.070912e+02 0.000000e+00 6.018873e+02 -3.798145e+02 0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00",
    "P2": "7.070912e+02 0.000000e+00 6.018873e+02 4.688783e+01 0.000000e+00 7.070912e+02 1.831104e+02 1.178601e-01 0.000000e+00 0.000000e+00 1.000000e+00 6.203223e-03",
    "P3": "7.070912e+02 0.000000e+00 6.018873e+02 -3.334597e+02 0.000000e+00 7.070912e+02 1.831104e+02 1.930130e+00 0.000000e+00 0.000000e+00 1.000000e+00 3.318498e-03",
}

H, W = 6, 8


def _img(seed, shape=(H, W, 3)):
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def _gt(seed):
    rng = np.random.default_rng(seed)
    d = rng.uniform(1, 20, (H, W)).astype(np.float32)
    valid = rng.random((H, W)) < 0.5
    return np.where(valid, d, 0).astype(np.float32), valid


def _kitti2015(root, frames=("000003", "000007"), occ=("000003",), calib=True):
    for f in frames:
        io.write_png(root / "image_2" / f"{f}_10.png", _img(1))
        io.write_png(root / "image_3" / f"{f}_10.png", _img(2))
        io.write_kitti_disparity(root / "disp_noc_0" / f"{f}_10.png", *_gt(3))
    for f in occ:
        io.write_kitti_disparity(root / "disp_occ_0" / f"{f}_10.png", *_gt(4))
    if calib:
        (root / "calib_cam_to_cam").mkdir()
        (root / "calib_cam_to_cam" / "000003.txt").write_text(
            f"calib_time: 09-Jan-2012 13:57:47\nP_rect_02: {P_RECT_02}\nP_rect_03: {P_RECT_03}\n")
    return root


# ---- load_pair ---------------------------------------------------------------------------------

def test_load_pair(tmp_path):
    io.write_png(tmp_path / "l.png", _img(0))
    io.write_png(tmp_path / "r.png", _img(1))
    s = ds.load_pair(tmp_path / "l.png", tmp_path / "r.png")
    assert s.name == "l" and s.left.shape == (H, W, 3) and s.gt is None and s.calib is None


def test_load_pair_size_mismatch(tmp_path):
    io.write_png(tmp_path / "l.png", _img(0, (375, 1242)))
    io.write_png(tmp_path / "r.png", _img(1, (370, 1226)))
    with pytest.raises(StereoInputError, match="left is 1242x375 but right is 1226x370"):
        ds.load_pair(tmp_path / "l.png", tmp_path / "r.png")
    with pytest.raises(StereoInputError, match="no such file"):
        ds.load_pair(tmp_path / "l.png", tmp_path / "missing.png")


# ---- KITTI 2015 --------------------------------------------------------------------------------

def test_kitti2015_synthetic(tmp_path):
    root = _kitti2015(tmp_path)
    (root / "image_2" / "000009_10.png").write_bytes(b"only a left view")  # not a pair: ignored
    assert ds.list_kitti2015(root) == ["000003", "000007"]
    s = ds.load_kitti2015(root, "000003")
    gt, valid = _gt(3)
    assert s.name == "000003" and s.left.dtype == np.uint8 and s.left.shape == (H, W, 3)
    np.testing.assert_array_equal(s.gt_valid, valid)
    np.testing.assert_allclose(s.gt, gt, atol=1 / 512)
    np.testing.assert_array_equal(s.gt_noc_valid, valid)
    assert s.calib.baseline == pytest.approx((44.85728 + 339.5242) / 721.5377)
    assert 0.5 < s.calib.baseline < 0.56 and s.calib.focal == pytest.approx(721.5377)
    assert s.calib.doffs == 0 and s.calib.cx == pytest.approx(609.5593)

    occ = ds.load_kitti2015(root, "000003", gt="occ")
    np.testing.assert_array_equal(occ.gt_valid, _gt(4)[1])
    np.testing.assert_array_equal(occ.gt_noc_valid, valid)
    s7 = ds.load_kitti2015(root, 7, gt="occ")  # int ids are zero-padded; no occ GT -> None
    assert s7.gt is None and s7.gt_valid is None and s7.gt_noc_valid is not None and s7.calib is None


def test_kitti2015_errors(tmp_path):
    root = _kitti2015(tmp_path)
    with pytest.raises(StereoInputError, match=r"unknown frame '000042'.*000003, 000007"):
        ds.load_kitti2015(root, "000042")
    with pytest.raises(StereoInputError, match="gt must be"):
        ds.load_kitti2015(root, "000003", gt="all")
    (root / "calib_cam_to_cam" / "000003.txt").write_text("P_rect_02: 1 2 3\n")
    with pytest.raises(StereoInputError, match="P_rect_02 with 12 values"):
        ds.load_kitti2015(root, "000003")
    io.write_png(root / "image_3" / "000007_10.png", _img(2, (H, W + 1, 3)))
    with pytest.raises(StereoInputError, match=f"left is {W}x{H} but right is {W + 1}x{H}"):
        ds.load_kitti2015(root, "000007")


def test_kitti_loaders_on_a_missing_or_empty_folder_say_so(tmp_path):
    """Issue 55: a missing folder was "unknown frame ...; available: none"."""
    for load in (ds.load_kitti2015, ds.load_kitti2012):
        with pytest.raises(StereoInputError, match=r"^no such folder: \S*nope \(expected a KITTI 201[25] training/") as e:
            load(tmp_path / "nope", "000000")
        assert "available" not in str(e.value) and "\n" not in str(e.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(StereoInputError, match=r"^no KITTI 2015 pairs in \S*empty: expected image_2/ and image_3/"):
        ds.load_kitti2015(tmp_path / "empty", "000000")
    with pytest.raises(StereoInputError, match=r"^no KITTI 2012 pairs in \S*empty: expected image_0/ and image_1/"):
        ds.load_kitti2012(tmp_path / "empty", "000000")


# ---- KITTI 2012 --------------------------------------------------------------------------------

def test_kitti2012_prefers_grey_falls_back_to_colour(tmp_path):
    for d in ("colored_0", "colored_1"):
        io.write_png(tmp_path / d / "000000_10.png", _img(5))
        io.write_png(tmp_path / d / "000001_10.png", _img(5))
    for d in ("image_0", "image_1"):
        io.write_png(tmp_path / d / "000001_10.png", _img(6, (H, W)))
    io.write_kitti_disparity(tmp_path / "disp_occ" / "000000_10.png", *_gt(7))
    (tmp_path / "calib").mkdir()
    for f in ("000000", "000001"):
        (tmp_path / "calib" / f"{f}.txt").write_text("".join(f"{k}: {v}\n" for k, v in K12.items()))
    assert ds.list_kitti2012(tmp_path) == ["000000", "000001"]

    colour = ds.load_kitti2012(tmp_path, "000000", gt="occ")
    assert colour.left.shape == (H, W, 3) and colour.gt is not None
    assert colour.calib.baseline == pytest.approx((46.88783 + 333.4597) / 707.0912)  # P2/P3
    assert ds.load_kitti2012(tmp_path, "000000").gt is None  # no disp_noc

    grey = ds.load_kitti2012(tmp_path, "000001")
    assert grey.left.shape == (H, W)
    assert grey.calib.baseline == pytest.approx(379.8145 / 707.0912)  # P0/P1
    with pytest.raises(StereoInputError, match="available: 000000, 000001"):
        ds.load_kitti2012(tmp_path, "000002")


# ---- Middlebury --------------------------------------------------------------------------------

def _middlebury(scene, calib=True, mask=True):
    io.write_png(scene / "im0.png", _img(8))
    io.write_png(scene / "im1.png", _img(9))
    gt = np.full((H, W), 30.5, np.float32)
    gt[0, :3] = np.inf
    io.write_pfm(scene / "disp0GT.pfm", gt)
    if mask:
        m = np.full((H, W), 255, np.uint8)
        m[1, :] = 128
        io.write_png(scene / "mask0nocc.png", m)
    if calib:
        (scene / "calib.txt").write_text(
            "cam0=[999.421 0 294.182; 0 999.421 252.932; 0 0 1]\n"
            "cam1=[999.421 0 326.96; 0 999.421 252.932; 0 0 1]\n"
            "doffs=32.778\nbaseline=193.001\nwidth=8\nheight=6\nndisp=70\nisint=0\n")
    return scene


def test_middlebury_synthetic(tmp_path):
    s = ds.load_middlebury(_middlebury(tmp_path / "Scene"))
    assert s.name == "Scene" and s.max_disp_hint == 70
    assert s.calib == ds.Calibration(baseline=0.193001, focal=999.421, doffs=32.778, cx=294.182, cy=252.932)
    assert s.gt_valid.sum() == H * W - 3 and (s.gt[~s.gt_valid] == 0).all() and np.isfinite(s.gt).all()
    assert s.gt_noc_valid.sum() == H * W - 3 - W  # row 1 occluded (128), row 0 has 3 inf pixels
    noc = ds.load_middlebury(tmp_path / "Scene", gt="noc")
    np.testing.assert_array_equal(noc.gt_valid, s.gt_noc_valid)

    bare = ds.load_middlebury(_middlebury(tmp_path / "Bare", calib=False, mask=False))
    assert bare.calib is None and bare.max_disp_hint is None and bare.gt_noc_valid is None
    assert ds.load_middlebury(tmp_path / "Bare", gt="noc").gt is None
    assert ds.list_middlebury(tmp_path) == ["Bare", "Scene"]

    (tmp_path / "Scene" / "calib.txt").write_text("cam0=[1 2 3]\nbaseline=100\n")
    with pytest.raises(StereoInputError, match="cam0 as a 3x3 matrix"):
        ds.load_middlebury(tmp_path / "Scene")
    with pytest.raises(StereoInputError, match="im0.png and im1.png"):
        ds.load_middlebury(tmp_path)


# ---- load_dataset ------------------------------------------------------------------------------

def test_load_dataset_resolves_roots_and_checks_frames(tmp_path):
    _kitti2015(tmp_path / "kitti2015" / "training")
    for root in (tmp_path, tmp_path / "kitti2015", tmp_path / "kitti2015" / "training"):
        items = ds.load_dataset(root, "kitti2015")
        assert [f for f, _ in items] == ["000003", "000007"]
    items = ds.load_dataset(tmp_path, "kitti2015", frames=["000007"])
    assert items[0][1]().name == "000007"
    with pytest.raises(StereoInputError, match=r"unknown kitti2015 frame\(s\) 000021.*available: 000003, 000007"):
        ds.load_dataset(tmp_path, "kitti2015", frames=["000021"])
    with pytest.raises(StereoInputError, match="image_0/ and image_1/"):
        ds.load_dataset(tmp_path, "kitti2012")
    with pytest.raises(StereoInputError, match="im0.png"):
        ds.load_dataset(tmp_path / "kitti2015", "middlebury")
    with pytest.raises(StereoInputError, match="unknown dataset"):
        ds.load_dataset(tmp_path, "sintel")
    with pytest.raises(StereoInputError, match="does not exist"):
        ds.load_dataset(tmp_path / "nope", "kitti2015")


def test_load_dataset_auto_reads_each_frame_with_the_ground_truth_its_files_give(tmp_path):
    root = _kitti2015(tmp_path / "k15", frames=("000003", "000007"), occ=("000003", "000009"), calib=False)
    io.write_png(root / "image_2" / "000009_10.png", _img(1))        # all-pixel GT only
    io.write_png(root / "image_3" / "000009_10.png", _img(2))
    io.write_png(root / "image_2" / "000011_10.png", _img(1))        # no GT at all
    io.write_png(root / "image_3" / "000011_10.png", _img(2))
    items = ds.load_dataset(root, "kitti2015", gt="auto")
    assert items.gt_of == {"000003": "noc", "000007": "noc", "000009": "occ", "000011": None}
    loaded = {f: load() for f, load in items}
    np.testing.assert_array_equal(loaded["000003"].gt_valid, _gt(3)[1])         # noc, not occ
    np.testing.assert_array_equal(loaded["000009"].gt_valid, _gt(4)[1])         # occ, the only one
    assert loaded["000009"].gt_noc_valid is None and loaded["000011"].gt is None
    assert ds.load_dataset(root, "kitti2015", gt="noc").gt_of is None
    with pytest.raises(StereoInputError, match="gt must be 'noc', 'occ' or 'auto'"):
        ds.load_dataset(root, "kitti2015", gt="all")

def test_calibration_rejects_bad_values():
    with pytest.raises(StereoInputError, match="baseline"):
        ds.Calibration(baseline=0.0, focal=700.0)
    with pytest.raises(StereoInputError, match="focal"):
        ds.Calibration(baseline=0.5, focal=float("nan"))


# ---- built-in and real data --------------------------------------------------------------------

def test_builtin_sample():
    s = ds.load_builtin_sample()
    assert s.name == "motorcycle"
    assert s.left.shape == s.right.shape == (500, 741, 3) and s.left.dtype == np.uint8
    assert s.gt.dtype == np.float32 and s.gt_valid.dtype == bool and np.isfinite(s.gt).all()
    assert 0.9 < s.gt_valid.mean() < 0.95  # its inf pixels are invalid
    assert 7 < s.gt[s.gt_valid].min() and s.gt[s.gt_valid].max() < 60
    assert s.max_disp_hint == 64 and s.max_disp_hint > s.gt.max()
    assert s.calib.focal == pytest.approx(994.978) and s.calib.baseline == pytest.approx(0.193001)


def _need(path):
    if not path.is_dir():
        pytest.skip(f"{path} not present")
    return path


def test_real_kitti2015_000021(data_root):
    root = _need(data_root / "kitti2015" / "training")
    assert "000021" in ds.list_kitti2015(root)
    s = ds.load_kitti2015(root, "000021")
    assert s.left.shape == s.right.shape == (375, 1242, 3) and s.left.dtype == np.uint8
    assert s.gt.shape == (375, 1242) and s.gt.dtype == np.float32
    assert 0.10 < s.gt_valid.mean() < 0.30  # sparse LiDAR GT
    assert s.gt[s.gt_valid].min() > 0 and s.gt[s.gt_valid].max() < 256
    assert (s.gt[~s.gt_valid] == 0).all()
    np.testing.assert_array_equal(s.gt_noc_valid, s.gt_valid)
    assert ds.load_kitti2015(root, "000021", gt="occ").gt is None  # disp_occ_0 only has 000001
    occ = ds.load_kitti2015(root, "000001", gt="occ")
    assert occ.gt_valid.sum() >= (occ.gt_noc_valid.sum())


def test_real_kitti2012_000000_colour_fallback(data_root):
    root = _need(data_root / "kitti2012" / "training")
    s = ds.load_kitti2012(root, "000000", gt="occ")
    assert s.left.shape == (370, 1226, 3) and s.left.dtype == np.uint8  # from colored_0
    assert s.gt.shape == (370, 1226) and 0.1 < s.gt_valid.mean() < 0.6
    assert 0 < s.gt[s.gt_valid].max() < 256
    assert s.gt_noc_valid is None  # no disp_noc in the shared copy
    assert ds.load_kitti2012(root, "000000").gt is None


def test_real_middlebury_motorcycle(data_root):
    scene = _need(data_root / "middlebury" / "Motorcycle_MiddEval3Q")
    s = ds.load_middlebury(scene)
    assert s.left.shape == s.right.shape == (497, 741, 3)
    assert s.calib.focal == pytest.approx(999.421) and s.calib.doffs == pytest.approx(32.778)
    assert s.calib.baseline == pytest.approx(0.193001) and s.calib.cx == pytest.approx(294.182)
    assert s.max_disp_hint == 70
    assert 0.95 < s.gt_valid.mean() < 1.0
    assert 0.8 < s.gt_noc_valid.mean() < s.gt_valid.mean()
    assert 5 < s.gt[s.gt_valid].min() and s.gt[s.gt_valid].max() < 70


def test_real_load_dataset_from_shared_root(data_root):
    k15 = ds.load_dataset(data_root, "kitti2015", frames=["000021", "000030"])
    assert [f for f, _ in k15] == ["000021", "000030"]
    assert len(ds.load_dataset(data_root, "kitti2015")) == 30
    assert [f for f, _ in ds.load_dataset(data_root, "kitti2012")] == ["000000"]
    mb = dict(ds.load_dataset(data_root / "middlebury", "middlebury", gt="occ"))
    assert "Motorcycle_MiddEval3Q" in mb and "Tsukuba_2001" in mb
    t = mb["Tsukuba_2001"]()
    assert t.left.shape == (288, 384, 3) and t.gt[t.gt_valid].max() <= 16
    with pytest.raises(StereoInputError, match="available: (.*, )?Aloe_opencv"):
        ds.load_dataset(data_root, "middlebury", frames=["Art"])
