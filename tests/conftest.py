"""Shared fixtures."""

from pathlib import Path

import pytest

#: ../shared/data from the project root (see /work/shared/data/README.md); never copied into the repo.
DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def _own_compile_cache(tmp_path_factory):
    """The suite's own persistent compile cache (STEREOJAX_CACHE_DIR, inherited by the CLI
    subprocesses and shared by the workers of ``pytest -n``): the tests never read or write the user's cache, nor one that another process
    (a training, a Ray worker) writes at the same time."""
    import os

    if "STEREOJAX_CACHE_DIR" in os.environ:       # set by the caller: keep it
        yield
        return
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):    # pytest -n N: the workers share one cache (writes
        base = base.parent                       # are atomic: stereojax.inference.compile_cache)
    folder = base / "compile-cache"
    folder.mkdir(exist_ok=True)
    os.environ["STEREOJAX_CACHE_DIR"] = str(folder)
    try:
        yield
    finally:
        os.environ.pop("STEREOJAX_CACHE_DIR", None)


@pytest.fixture(scope="module", autouse=True)
def _free_compiled_programs():
    """After each test module, the programs it compiled are dropped. Every XLA:CPU executable
    holds hundreds of memory maps of machine code (about 480 for a census chain), and JAX keeps
    them all; one process running the whole suite reached the kernel's vm.max_map_count (65 530)
    and segfaulted inside XLA, late in the run (twice, CI's run included)."""
    yield
    import gc

    import jax

    from stereojax.inference import predictor as pipeline

    pipeline._COMPILED.clear()
    jax.clear_caches()
    gc.collect()


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
