"""Shared fixtures: the data folder and jitted functions compiled once per test run."""

from __future__ import annotations

import functools
import os
import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest

# Compiling is most of this suite's time, and LLVM's optimizer about a fifth of compiling, so
# tests (and the CLI and experiment runs they start) compile at XLA:CPU's lowest backend
# optimization level: what they check (values, shapes, errors, gradients) does not depend on
# it.  A claim that two programs give bit-identical results is a claim about the user's code
# generation: such tests compile both programs at XLA's default level (``USER_CODEGEN``; the
# sweep tests' subprocesses set their own flags).  JAXGFX_TEST_CODEGEN=default runs every
# test at the default level.
# XLA reads its flags when the backend starts (the first array), after these imports.
if os.environ.get("JAXGFX_TEST_CODEGEN") != "default":
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0"
    ).strip()
USER_CODEGEN = {"xla_backend_optimization_level": 3}
"""``jax.jit(..., compiler_options=USER_CODEGEN)``: XLA:CPU's default code generation."""

DATA = Path(
    os.environ.get("JAXGFX_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
)


# CLI runs in subprocesses (the sweep tests) keep their compilation cache out of $HOME.
os.environ.setdefault("JAXGFX_CACHE_DIR", tempfile.mkdtemp(prefix="jaxgfx-test-cache-"))


# Modules whose tests run for tens of seconds each (subprocesses, the experiments' --quick runs),
# scheduled first.  xdist gives each worker whole modules (--dist loadfile), so a module's
# shared jitted functions compile once, not once per worker; a long module started last would
# leave the other worker idle at the end of the run.
SLOW_FIRST = ("test_experiments.py", "test_sweep.py", "test_showcase.py", "test_cli.py")


def pytest_collection_modifyitems(items):
    def rank(item):
        name = item.path.name
        return SLOW_FIRST.index(name) if name in SLOW_FIRST else len(SLOW_FIRST)

    items.sort(key=rank)  # stable: collection order within each rank


@pytest.fixture(autouse=True)
def cache_calls(tmp_path, monkeypatch):
    """Keeps in-process ``jaxgfx.cli.main`` away from the real cache and JAX's global settings.

    main() calls ``enable_compilation_cache(cache_dir())``; here it only records the
    directory (``$JAXGFX_CACHE_DIR`` points into the test's tmp dir).  Its
    ``keep_freed_memory()`` is a no-op here (see ``test_hostmem``).
    """
    import jaxgfx.cli

    calls: list = []
    monkeypatch.setenv("JAXGFX_CACHE_DIR", str(tmp_path / "jax-cache"))
    monkeypatch.setattr(jaxgfx.cli, "enable_compilation_cache", calls.append)
    # The test process's malloc stays as it is (main() would set it process-wide).
    monkeypatch.setattr(jaxgfx.cli, "keep_freed_memory", lambda: True)
    return calls


@pytest.fixture(scope="package")
def data_dir() -> Path:
    """``../shared/data`` beside the checkout; tests needing it skip when absent."""
    if not DATA.is_dir():
        pytest.skip(f"real data folder {DATA} is absent (clone of the project alone)")
    return DATA


@pytest.fixture(scope="package")
def raster_jit():
    from jaxgfx.raster import rasterize

    return jax.jit(rasterize, static_argnames=("cull_backfaces", "block", "chunk"))


@pytest.fixture(scope="package")
def user_jit():
    """``jax.jit`` at XLA's default code generation, for claims about the user's programs."""
    return functools.partial(jax.jit, compiler_options=USER_CODEGEN)


class CompileCounter:
    """Counts XLA backend compilations while active (JAX's public monitoring events)."""

    EVENT = "/jax/core/compile/backend_compile_duration"

    def __init__(self) -> None:
        self.count = 0

    def _listener(self, event: str, duration: float, **kwargs) -> None:
        if event == self.EVENT:
            self.count += 1

    def __enter__(self) -> CompileCounter:
        jax.monitoring.register_event_duration_secs_listener(self._listener)
        return self

    def __exit__(self, *exc) -> None:
        jax.monitoring.unregister_event_duration_listener(self._listener)


@pytest.fixture
def compile_counter() -> type[CompileCounter]:
    """``with compile_counter() as c: ...; assert c.count == 0`` checks nothing recompiled."""
    return CompileCounter


@pytest.fixture
def hill(tmp_path) -> tuple[np.ndarray, Path]:
    """A 20 x 24 Gaussian hill (grey levels 10..40) and the .npy file holding it."""
    z, x = np.mgrid[0:20, 0:24]
    h = 10 + 30 * np.exp(-((x - 14.0) ** 2 + (z - 8.0) ** 2) / 40.0)
    path = tmp_path / "hill.npy"
    np.save(path, h)
    return h, path
