"""Shared fixtures."""

from pathlib import Path

import pytest

#: ../shared/data from the project root (see /work/shared/data/README.md); never copied into the repo.
DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def data_root() -> Path:
    """The shared real-data folder; tests that use it are skipped when it is absent."""
    if not DATA_ROOT.is_dir():
        pytest.skip(f"real stereo data not found at {DATA_ROOT} (expected ../shared/data next to the project)")
    return DATA_ROOT


@pytest.fixture
def pair(tmp_path):
    """A small shifted pair written as left.png and right.png (the robustness tests' input)."""
    from .robustness_helpers import _write_pair

    return _write_pair(tmp_path / "in")
