"""stereojax.app.outputs: the pictures a person looks at (colour depth, its reliability mask, the error
map's legend), the output folder's bookkeeping, and one writer per output folder."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from stereojax.app.outputs import (RELIABLE_MIN_CONFIDENCE, RELIABLE_MIN_DISP, depth_color, depth_reliable,
                                   write_prediction)
from stereojax.data import io
from stereojax.data.calibration import Calibration

from ..helpers import cache_env as _env, pair_folders as _folders

FAST = ["--max-disp", "16", "--method", "census"]


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
    assert (rgb[0, 3:] == 128).all()                            # at half brightness
    assert 2.0 <= scale["near"] < scale["far"] <= 20.0 and scale["unit"] == "m"
    assert scale["reliable_to_m"] == 20.0 and 70 < scale["reliable_share_pct"] < 80


def test_far_unreliable_depth_is_half_bright_grey_not_the_black_of_no_depth():
    """Issue 55: the grey followed the colour's brightness, so the far end (Turbo's dark blue) came out
    near black, the colour of "no depth"."""
    z = np.tile(np.linspace(2.0, 20.0, 100, dtype=np.float32), (4, 1))
    z[:, -10:] = 300.0                                          # far past the reliable depths (sky)
    z[:, :3] = 0.0                                              # no depth
    reliable = np.ones_like(z, bool)
    reliable[:, -10:] = False
    reliable[:, 3:6] = False                                    # near and unreliable too
    rgb, scale = depth_color(z, reliable)
    assert (rgb[:, -10:] == 128).all() and (rgb[:, 3:6] == 128).all()
    assert (rgb[:, :3] == 0).all()
    assert scale["unreliable"] == [128, 128, 128] and scale["no_depth"] == [0, 0, 0]

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


def test_a_second_batch_on_a_held_folder_is_refused(tmp_path):
    left_dir, right_dir = _folders(tmp_path, ["a"])
    out = tmp_path / "o"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from pathlib import Path;"
                               "from stereojax.app.outputs import folder_lock\n"
                               f"with folder_lock(Path({str(out)!r})):\n    print('held', flush=True); time.sleep(60)"],
                              env=_env(tmp_path / "c"), stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        r = subprocess.run([sys.executable, "-m", "stereojax.app.cli", "predict", str(left_dir), str(right_dir),
                            "--out", str(out), *FAST], env=_env(tmp_path / "c"), capture_output=True, text=True,
                           timeout=300)
    finally:
        holder.kill()
        holder.wait()
    assert r.returncode == 8, r.stderr
    assert r.stderr.strip().splitlines()[-1] == (f"stereojax predict: error: output folder {out} is in use by PID "
                                                 f"{holder.pid} (another stereojax predict); wait for it to finish "
                                                 "or choose another --out")
    assert not (out / "a").exists()
    assert r.stdout == "", r.stdout               # refused before it says what it would run


def test_the_lock_is_reentrant_and_its_file_goes_when_the_run_ends(tmp_path):
    from stereojax.app.outputs import LOCK_NAME, folder_lock
    from stereojax.errors import OutputBusyError

    with folder_lock(tmp_path) as path:
        with folder_lock(tmp_path):                   # the CLI's block, then the batch's
            assert path.read_text().strip() == str(os.getpid())
        assert path.exists()                          # the outer block still holds it
        other = subprocess.run([sys.executable, "-c", "from pathlib import Path; from stereojax.app.outputs import "
                                f"folder_lock\nwith folder_lock(Path({str(tmp_path)!r})): pass"],
                               capture_output=True, text=True)
        assert other.returncode != 0 and OutputBusyError.__name__ in other.stderr
    assert not (tmp_path / LOCK_NAME).exists()
    with pytest.raises(RuntimeError):                 # a failed block removes it too
        with folder_lock(tmp_path):
            raise RuntimeError
    assert list(tmp_path.iterdir()) == []
    (tmp_path / LOCK_NAME).write_text("12345\n")    # a killed run's file: taken over
    with folder_lock(tmp_path) as path:
        assert path.read_text().strip() == str(os.getpid())
    assert list(tmp_path.iterdir()) == []


def test_a_failed_single_pair_leaves_no_empty_output_folder(tmp_path, capsys):
    from stereojax.app.cli import main

    left, right = _folders(tmp_path, ["a"])
    out = tmp_path / "new" / "o"
    code = main(["predict", str(left / "a.png"), str(tmp_path / "missing.png"), "--out", str(out), *FAST])
    assert code == 2 and "missing.png" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "new").exists()
    kept = tmp_path / "kept"
    kept.mkdir()                                      # a folder the user made stays
    assert main(["predict", str(left / "a.png"), str(tmp_path / "missing.png"), "--out", str(kept), *FAST]) == 2
    assert kept.is_dir()


@pytest.mark.slow
def test_two_identical_batches_started_together(tmp_path):
    """Two processes on one --out: one computes, the other refuses (exit 8) or, if it starts
    after the first finished, finds every frame complete; no frame fails or is lost."""
    left_dir, right_dir = _folders(tmp_path, ["a", "b", "c"])
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "stereojax.app.cli", "predict", str(left_dir), str(right_dir), "--out", str(out), *FAST]
    procs = [subprocess.Popen(cmd, env=_env(tmp_path / "c"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    results = [(p.wait(timeout=600), p.stderr.read()) for p in procs]
    codes = sorted(c for c, _ in results)
    assert codes in ([0, 0], [0, 8]), results
    if codes == [0, 8]:
        assert any("is in use by PID" in e for c, e in results if c == 8)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == [] and summary["ok"] == 3
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".") and p.name != ".stereojax.lock") == []
    for n in "abc":
        assert (out / n / "frame.json").is_file()


def test_ctrl_c_on_a_single_pair_ends_the_progress_line_and_leaves_no_empty_folder(tmp_path):
    """Issue 55: Ctrl-C while one pair compiles printed "interrupted" on the open progress line
    ("stereojax: compiling ... stereojax predict: interrupted") and left the empty --out folder."""
    import select
    import signal
    import time

    left, right = _folders(tmp_path, ["a"])
    # The signal must land while the pair compiles (about 2 s). Under a loaded machine the reader
    # can see "compiling" only after the child has finished; such a lost race is run again with a
    # fresh cache (at most three times), never judged.
    for attempt in range(3):
        out = tmp_path / "new" / "o"
        proc = subprocess.Popen([sys.executable, "-m", "stereojax.app.cli", "predict", str(left / "a.png"),
                                 str(right / "a.png"), "--out", str(out), *FAST],
                                env=_env(tmp_path / f"c{attempt}"), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        seen, deadline = b"", time.monotonic() + 240
        try:
            while b"compiling" not in seen and time.monotonic() < deadline:   # a fresh cache: it compiles
                if select.select([proc.stdout], [], [], 1.0)[0]:
                    chunk = os.read(proc.stdout.fileno(), 4096)
                    if not chunk:
                        break
                    seen += chunk
            assert b"compiling" in seen, seen.decode()
            proc.send_signal(signal.SIGINT)
            rest, _ = proc.communicate(timeout=240)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        if proc.returncode == 0 and b"computing" in seen + rest:     # finished before the signal
            shutil.rmtree(tmp_path / "new", ignore_errors=True)
            continue
        break
    text = (seen + rest).decode()
    assert proc.returncode == 130, text
    assert "\nstereojax predict: interrupted" in text, text      # on its own line
    assert "Traceback" not in text
    assert not out.exists() and not (tmp_path / "new").exists()


def _ply_z(path):
    head, body = path.read_bytes().split(b"end_header\n", 1)
    n = int([ln for ln in head.decode().splitlines() if ln.startswith("element vertex")][0].split()[-1])
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")],
                        count=n)
    return rec["z"]


def test_the_point_cloud_leaves_out_depths_it_cannot_measure(tmp_path):
    """points.ply keeps a point only where d + doffs >= 2 px (1 px of disparity error at most doubles
    its depth): on KITTI's calibration no point beyond B f / 2 = 195 m, not the 780 m of d = 0.5 px.
    --max-depth replaces that limit, farther as well as nearer; the depth files keep the far pixels."""
    calib = Calibration(0.54, 721.5)                               # B f = 389.6 m px
    disp = np.array([[0.6, 1.0, 1.5, 1.99, 2.0, 4.0, 10.0, 40.0, np.inf]], np.float32)
    image = np.full(disp.shape + (3,), 200, np.uint8)
    write_prediction(tmp_path / "d", "", disp, calib, image, ply=True)
    z = _ply_z(tmp_path / "d" / "points.ply")
    np.testing.assert_allclose(np.sort(z), 389.61 / np.array([40.0, 10.0, 4.0, 2.0]), rtol=1e-4)
    assert (np.load(tmp_path / "d" / "depth.npy") > 0).sum() == 8          # the depth map keeps them all
    write_prediction(tmp_path / "far", "", disp, calib, image, ply=True, max_depth=1000)
    assert _ply_z(tmp_path / "far" / "points.ply").max() == pytest.approx(389.61 / 0.6, rel=1e-4)
    write_prediction(tmp_path / "near", "", disp, calib, image, ply=True, max_depth=50)
    np.testing.assert_allclose(np.sort(_ply_z(tmp_path / "near" / "points.ply")), 389.61 / np.array([40.0, 10.0]),
                               rtol=1e-4)
    mid = Calibration(0.16, 3740.0, doffs=200.0)                   # Middlebury: d + doffs is never small
    write_prediction(tmp_path / "m", "", disp, mid, image, ply=True)
    assert len(_ply_z(tmp_path / "m" / "points.ply")) == 8


def test_a_ctrl_c_inside_a_c_callback_counts_as_an_interrupt():
    """A KeyboardInterrupt raised inside a C callback (numpy's dtype lookup while JAX traces) comes
    out as a SystemError caused by it; predict treats it as the Ctrl-C it is (exit 130)."""
    from stereojax.app.batch import _caused_by_interrupt

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ki:
            raise SystemError("returned a result with an exception set") from ki
    except SystemError as exc:
        assert _caused_by_interrupt(exc)
    assert not _caused_by_interrupt(ValueError("bad input"))
    try:
        try:
            raise ValueError("first")
        except ValueError:
            raise RuntimeError("second")
    except RuntimeError as exc:
        assert not _caused_by_interrupt(exc)
