"""Shared fixtures. Keep this small: helpers that only one test file needs live in that file."""

import os
import shutil
import tempfile
import textwrap

import numpy as np
import pytest

import assurjax  # importing it starts no JAX backend
from assurjax._jit import COMPILER_OPTIONS, add_xla_flag
from assurjax.cli import STALL_FREE_FLAG

# XLA's CPU runtime can stall inside a large compiled call on this 2-core machine (all
# threads waiting; reproduced standalone with reactions() of 4001 states of the shaper in
# test_outputs.py, 0 of 4 runs finished); with the concurrency-optimized scheduler off it
# finished 5 of 5. Set before JAX starts its backend; the package itself sets no process-wide
# flag (docs/design-notes.md, "Known issues").
add_xla_flag(STALL_FREE_FLAG, "xla_cpu_enable_concurrency_optimized_scheduler")

# The tests' own jitted checks (derivatives, vmapped references) compile with the options the
# package compiles its programs with (assurjax._jit.COMPILER_OPTIONS): XLA's legacy loop
# emitters and no library fusions, which compile these programs faster and run them as fast (outputs
# the same to ~1e-12, benchmarks/bench_compile_options.py). Their files ran in 104 -> 77 s (test_sensitivities.py,
# test_synthesis_optimize.py, test_dyads.py).
for _setting, _value in COMPILER_OPTIONS.items():
    add_xla_flag(f"--{_setting}={str(_value).lower() if isinstance(_value, bool) else _value}", _setting)

# The command line keeps compiled programs on disk by default; tests leave no files behind.
os.environ.setdefault("ASSURJAX_NO_CACHE", "1")

SHARED_CACHE = "ASSURJAX_TEST_COMPILATION_CACHE"


def pytest_configure(config):
    """One compilation cache for the session, shared by its workers (they inherit the
    variable), so that a program several test files compile is compiled once; removed at the end."""
    if SHARED_CACHE not in os.environ:
        os.environ[SHARED_CACHE] = tempfile.mkdtemp(prefix="assurjax-tests-")
        config.stash[_CACHE_OWNER] = True
    assurjax.enable_compilation_cache(os.environ[SHARED_CACHE])


@pytest.fixture(scope="module", autouse=True)
def _free_compiled_programs():
    """Free a test file's compiled programs when it ends (``jax.clear_caches``): a file reuses
    its own, another file finds those it shares on disk (the session's compilation cache). Kept,
    they grew a worker of the default suite to 5.2 GB; freed, to 2.3 GB (docs/CONTRIBUTING.md).
    On a pytest-xdist worker this also frees the last file's before the worker reports its end:
    freed at exit, after the report, they could outlast the few seconds the controller waits, and
    its interrupt printed a KeyboardInterrupt warning."""
    yield
    import gc

    import jax

    jax.clear_caches()
    gc.collect()


def pytest_unconfigure(config):
    if config.stash.get(_CACHE_OWNER, False):
        shutil.rmtree(os.environ.pop(SHARED_CACHE), ignore_errors=True)


_CACHE_OWNER = pytest.StashKey[bool]()


@pytest.fixture
def rng():
    """A seeded generator: random inputs that are the same on every run."""
    return np.random.default_rng(20240501)


@pytest.fixture(scope="session")
def roberts_scene():
    return assurjax.load_scene("roberts")


@pytest.fixture
def write_scene(tmp_path):
    """Write a TOML scene given as a (dedented) string; returns its path."""

    def write(text: str, name: str = "scene.toml"):
        path = tmp_path / name
        path.write_text(textwrap.dedent(text))
        return path

    return write
