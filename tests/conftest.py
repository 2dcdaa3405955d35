"""Shared fixtures, and the XLA flag the suite compiles with."""

import os
from pathlib import Path

import pytest

#: The suite is bound by compilation (each chain it runs is compiled once, 2-15 s on the CPU).
#: It compiles with XLA:CPU's elemental emitters instead of the newer fusion emitters: about a
#: third less compile time, and the same disparities bit for bit (tests/system/test_golden.py compares
#: with maps made by the default compiler). Users' runs keep the default, whose programs run
#: faster once compiled. Set here, before jax starts, so that every test process inherits it,
#: the CLI subprocesses included; STEREOJAX_TEST_DEFAULT_XLA=1 runs the suite as users compile.
TEST_XLA_FLAGS = "--xla_cpu_use_fusion_emitters=false"
if not os.environ.get("STEREOJAX_TEST_DEFAULT_XLA") and TEST_XLA_FLAGS not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {TEST_XLA_FLAGS}".strip()


def pytest_sessionstart(session):
    """The suite fails at once on a CPU where the native kernels (stereojax.kernels) did not load:
    it would otherwise test the JAX kernels only, and say nothing. ``STEREOJAX_NATIVE_SKIP=1`` runs
    it anyway (the build was skipped on purpose). Checked once, in the process that starts the run
    (not in pytest -n's workers), and not for ``--collect-only``."""
    if (session.config.option.collectonly or os.environ.get("PYTEST_XDIST_WORKER")
            or os.environ.get("STEREOJAX_NATIVE_SKIP") == "1"):
        return
    from stereojax import kernels

    st = kernels.status()
    if st.loaded or _backend() != "cpu":
        return
    pytest.exit(f"the native kernels did not load ({st.reason}); build them (make install, or pip install -e .) "
                "or set STEREOJAX_NATIVE_SKIP=1 to test the JAX kernels only", returncode=1)


def _backend() -> str:
    """JAX's default backend, asked in a child process: this process starts no backend (on a GPU it
    would hold memory that the test workers need)."""
    import subprocess
    import sys

    try:
        out = subprocess.run([sys.executable, "-c", "import jax; print(jax.default_backend())"],
                             capture_output=True, text=True, timeout=120, check=True)
    except (subprocess.SubprocessError, OSError):
        return "cpu"
    return out.stdout.strip().splitlines()[-1] if out.stdout.strip() else "cpu"


#: ../shared/data from the project root (see /work/shared/data/README.md); never copied into the repo.
DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def _own_compile_cache(tmp_path_factory):
    """The suite's own persistent compile cache (STEREOJAX_CACHE_DIR, inherited by the CLI
    subprocesses and shared by the workers of ``pytest -n``): the tests never read or write the user's cache, nor one that another process
    (a training, a Ray worker) writes at the same time."""
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

    from stereojax.inference import programs

    programs._COMPILED.clear()
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


def pytest_collection_modifyitems(config, items):
    """A test module with ``FAST_CASES`` (a set of test names with their parameters) runs those in
    ``make test-fast`` and marks its other cases slow (they still run in ``make test``): the
    native-vs-JAX equality grids (issue 51) cover every combination only in the whole suite."""
    for item in items:
        fast = getattr(getattr(item, "module", None), "FAST_CASES", None)
        if fast is not None and item.name not in fast and item.originalname != item.name:
            item.add_marker(pytest.mark.slow)
