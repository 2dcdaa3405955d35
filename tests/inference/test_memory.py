"""The memory guard (stereojax.inference.memory): calibrated estimate, refusal before allocating, the
limit read from the argument, the environment or the available memory."""

from __future__ import annotations

import os

import numpy as np
import pytest

import stereojax
from stereojax import ConfigError, MemoryBudgetError, StereoError
from stereojax.inference import memory
from stereojax.data import io

from ..robustness_helpers import _cli, _one_line, _record


# ---- memory guard ------------------------------------------------------------------------------

def _full_range(cfg):
    """The full-range chain of a preset (band.width 0), which the calibration below is of."""
    import dataclasses

    from stereojax.config import BandConfig

    return dataclasses.replace(cfg, band=BandConfig()).validate()


def test_memory_estimate_is_calibrated_on_the_kitti_frame():
    # full-range census chain, 1242x375, 228 disparities: measured peak ~2.7 GiB
    est = memory.chain_peak_bytes(375, 1242, _full_range(stereojax.preset("census", 228))) / memory.GIB
    assert 2.4 < est < 3.0, est


def test_memory_estimate_of_a_banded_chain_counts_the_band():
    """H*W*K, not H*W*D: the banded estimate grows with the band width, not with the range (the
    coarse pass's small volumes aside), and a 6 MP pair with 282 disparities fits whole in the
    default budget of a 24 GiB machine like this project's (measured peak 11.5 GiB, tiling.md)."""
    import dataclasses

    cfg = stereojax.preset("census", 228)
    assert cfg.banded
    band = memory.chain_peak_bytes(375, 1242, cfg)
    assert band < 0.5 * memory.chain_peak_bytes(375, 1242, _full_range(cfg))
    wide = memory.chain_peak_bytes(375, 1242, dataclasses.replace(cfg, max_disp=456))
    per_disp_full = memory.VOLUMES * 375 * 1242 * 4
    assert wide - band < 0.2 * per_disp_full * 228      # doubling D adds only the coarse pass
    six_mp = memory.chain_peak_bytes(2012, 2982, stereojax.preset("census", 282))
    assert 11.5 * memory.GIB < six_mp < memory.DEFAULT_SHARE * 22 * memory.GIB


def test_memory_guard_refuses_a_4k_pair_before_allocating(monkeypatch):
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    monkeypatch.setattr(memory, "available_bytes", lambda: 16 * memory.GIB)
    from stereojax.inference import predictor as pipeline

    def never(*a, **k):
        raise AssertionError("the jitted chain must not run")

    monkeypatch.setattr(pipeline, "compiled_chain", never)      # disparity() and the CLI compile through it
    monkeypatch.setattr(pipeline, "disparity_grey", never)      # disparity(bucket=False)
    monkeypatch.setattr(pipeline, "stages_grey", never)        # stages()
    left = np.zeros((2160, 3840), np.uint8)
    cfg = _full_range(stereojax.preset("census", 228))
    with pytest.raises(MemoryBudgetError) as exc:
        stereojax.disparity(left, left, cfg)
    msg = str(exc.value)
    _record("4K pair (3840x2160, 228 disparities), Python API", "MemoryBudgetError", msg)
    assert "a 3840x2160 frame with 228 disparities needs about 39.2 GiB" in msg
    assert "more than the limit of 11.2 GiB (70% of the 16.0 GiB available)" in msg
    assert "at most 62 fits" in msg and "downscale the pair by 2" in msg and memory.ENV_VAR in msg
    assert isinstance(exc.value, StereoError) and exc.value.exit_code == 6
    # the limit is read at call time: argument, then environment, then available memory
    with pytest.raises(MemoryBudgetError, match=r"limit of 8\.0 GiB \(memory_limit_gb=8\)"):
        stereojax.disparity(left, left, cfg, memory_limit_gb=8)
    monkeypatch.setenv(memory.ENV_VAR, "20")
    with pytest.raises(MemoryBudgetError, match=r"limit of 20\.0 GiB \(STEREOJAX_MEMORY_LIMIT_GB=20\)"):
        stereojax.stages(left, left, cfg)
    monkeypatch.setenv(memory.ENV_VAR, "lots")
    with pytest.raises(ConfigError, match="STEREOJAX_MEMORY_LIMIT_GB must be a positive number of GiB or 'off', got 'lots'"):
        stereojax.disparity(left, left, cfg)
    monkeypatch.setenv(memory.ENV_VAR, "off")
    with pytest.raises(AssertionError, match="must not run"):        # guard off: it would run
        stereojax.disparity(left, left, cfg)
    monkeypatch.delenv(memory.ENV_VAR)
    monkeypatch.setattr(memory, "available_bytes", lambda: 128 * memory.GIB)
    with pytest.raises(AssertionError, match="must not run"):        # a bigger machine: it fits
        stereojax.disparity(left, left, cfg)
    # stages() keeps every volume: its estimate is larger
    assert (memory.chain_peak_bytes(2160, 3840, cfg, keep=True) > memory.chain_peak_bytes(2160, 3840, cfg))


def test_memory_guard_cli_exit_6(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    monkeypatch.setattr(memory, "available_bytes", lambda: 16 * memory.GIB)
    from stereojax.inference import predictor as pipeline

    # the CLI compiles its chain through compiled_chain: refused before that, nothing compiles or runs
    monkeypatch.setattr(pipeline, "compiled_chain", lambda *a, **k: pytest.fail("chain compiled"))
    img = np.zeros((2160, 3840), np.uint8)
    img[::7, ::5] = 255
    io.write_png(tmp_path / "l.png", img)
    io.write_png(tmp_path / "r.png", img)
    out = tmp_path / "out"
    code, _, err = _cli(["predict", tmp_path / "l.png", tmp_path / "r.png", "--out", out, "--method", "census",
                         "--max-disp", "228", "--tile", "off"], capsys, "4K pair (3840x2160, 228 disparities), CLI")
    line = _one_line(err)
    assert code == 6 and line.startswith("stereojax predict: error: a 3840x2160 frame with 228 disparities")
    assert not out.exists()


def test_available_memory_is_read(monkeypatch):
    """The default limit is the stated share of the memory available now (read from the
    system, at most the machine's total); the environment variable and the argument override it."""
    avail = memory.available_bytes()
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert avail is not None and 0 < avail <= total
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    limit, source = memory.memory_limit()
    assert limit == pytest.approx(memory.DEFAULT_SHARE * memory.available_bytes(), rel=0.05)
    assert source.endswith("GiB available") and f"{memory.DEFAULT_SHARE:.0%}" in source
    monkeypatch.setenv(memory.ENV_VAR, "1.5")
    assert memory.memory_limit() == (1.5 * memory.GIB, f"{memory.ENV_VAR}=1.5")
    assert memory.memory_limit(0.25) == (0.25 * memory.GIB, "memory_limit_gb=0.25")
