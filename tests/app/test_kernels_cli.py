"""--kernels (issue 51): which kernels ran, said on the first lines of the command and recorded in
timings.json and frame.json; --kernels native without the library is a one-line error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stereojax import kernels
from stereojax.data import io

from ..helpers import run_cli, shifted_pair

FAST = ["--method", "census", "--check-rectified", "off"]


def _folders(root, d=4):
    left, right = shifted_pair(d, h=48, w=80)
    io.write_png(root / "L" / "f0.png", left)
    io.write_png(root / "R" / "f0.png", right)
    return root / "L", root / "R"


def _not_loaded(monkeypatch):
    monkeypatch.setattr(kernels, "_STATUS", kernels.Status(False, None, "reason"))


@pytest.mark.parametrize("setting", ["xla", "native"])
def test_kernels_option_is_said_and_recorded(tmp_path, capsys, setting):
    if setting == "native" and not kernels.status().loaded:
        pytest.skip(f"the native kernels did not load: {kernels.status().reason}")
    lf, rf = _folders(tmp_path / "in")
    code, out, err = run_cli(["predict", lf, rf, "--out", tmp_path / "o", "--max-disp", 16, "--kernels", setting,
                              *FAST], capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == "stereojax: method: census cost (--method census)"       # the first line kept
    assert lines[1] == f"stereojax: kernels: {kernels.describe(setting)}"        # the kernels right after
    assert ("native C++" in lines[1]) == (setting == "native")
    frame = tmp_path / "o" / "f0"
    want = {"kernels": setting, "setting": setting, "reason": None}
    assert json.loads((frame / "timings.json").read_text())["kernels"] == want
    assert json.loads((frame / "frame.json").read_text())["kernels"] == want
    assert json.loads((frame / "config.json").read_text())["kernels"] == setting
    np.testing.assert_allclose(np.median(io.read_pfm(frame / "disparity.pfm")[:, 20:]), 4, atol=0.5)


def test_first_line_says_jax_kernels_when_the_library_did_not_load(tmp_path, capsys, monkeypatch):
    _not_loaded(monkeypatch)
    left, right = shifted_pair(4, h=48, w=80)
    io.write_png(tmp_path / "l.png", left)
    io.write_png(tmp_path / "r.png", right)
    # 12 disparities: no chain of this module's other tests (compiled with the library loaded) is reused
    code, out, err = run_cli(["predict", tmp_path / "l.png", tmp_path / "r.png", "--out", tmp_path / "o",
                              "--max-disp", 12, *FAST], capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == "stereojax: kernels: JAX (XLA) kernels: the native kernels did not load (reason)"
    assert lines[1] == "stereojax: method: census cost (--method census)"
    assert not any("kernels" in ln for ln in lines[1:])                          # said once
    timings = json.loads((tmp_path / "o" / "timings.json").read_text())
    assert timings["kernels"] == {"kernels": "xla", "setting": "auto", "reason": "reason"}


def test_kernels_native_without_the_library_is_one_line_error(tmp_path, capsys, monkeypatch):
    _not_loaded(monkeypatch)
    left, right = shifted_pair(4, h=48, w=80)
    io.write_png(tmp_path / "l.png", left)
    io.write_png(tmp_path / "r.png", right)
    for argv in (["predict", tmp_path / "l.png", tmp_path / "r.png", "--out", tmp_path / "o"],
                 ["demo", "--out", tmp_path / "o"]):
        code, out, err = run_cli([*argv, "--kernels", "native", *FAST[:2]], capsys)
        assert code == 3 and out == ""
        assert err.strip().splitlines() == [f"stereojax {argv[0]}: error: --kernels native: the native kernels did "
                                            "not load (reason)"]
        assert not (tmp_path / "o").exists()


def test_a_bad_kernels_value_is_one_line(tmp_path, capsys):
    code, _, err = run_cli(["predict", "l.png", "r.png", "--out", tmp_path / "o", "--kernels", "gpu"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--kernels: invalid choice: 'gpu'" in err
