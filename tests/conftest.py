"""Shared fixtures."""

from pathlib import Path

import pytest

#: ../shared/data from the project root (see /work/shared/data/README.md); never copied into the repo.
DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def _own_compile_cache(tmp_path_factory):
    """The suite's own persistent compile cache (STEREOJAX_CACHE_DIR), for the subprocesses
    only: the tests never read or write the user's cache, nor one that another process (a
    training, a Ray worker) writes at the same time.

    The pytest process itself compiles without a persistent cache. It compiles hundreds of
    programs over 15 minutes, and jaxlib 0.10.2 (CPU) twice segfaulted inside
    ``executable.serialize()`` when writing a cache entry late in such a run (the same test,
    test_train.py::test_fit_from_init..., passes alone and in its file); the cache itself is
    tested in subprocesses, as users run it (tests/test_integrity.py, tests/test_speed.py)."""
    import os

    from stereojax import compile_cache

    compile_cache._enabled["tried"] = True           # ensure_enabled(): nothing in this process
    enable = compile_cache.enable
    compile_cache.enable = lambda path=None: None    # the CLI run in-process: no cache either
    mine = "STEREOJAX_CACHE_DIR" not in os.environ   # set by the caller: keep it
    if mine:
        os.environ["STEREOJAX_CACHE_DIR"] = str(tmp_path_factory.mktemp("compile-cache"))
    try:
        yield
    finally:
        compile_cache.enable = enable
        compile_cache._enabled.pop("tried", None)
        if mine:
            os.environ.pop("STEREOJAX_CACHE_DIR", None)


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
