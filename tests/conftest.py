"""Shared fixtures: the data folder and jitted functions compiled once per test run."""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# One persistent compilation cache for the whole run, set before JAX starts: both xdist
# workers and every CLI and experiment run they start (the variables reach subprocesses)
# share it, so a program that several processes compile (an experiment's kernel a test
# compiled too, the report's run of another benchmark) compiles once.  Programs that
# compile in under 0.3 s (eager ops, thousands of them) are not written.  The controller
# makes it (its workers inherit the variables) and removes it at the end.
_OWN_CACHE = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _OWN_CACHE = tempfile.mkdtemp(prefix="jaxgfx-test-jit-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _OWN_CACHE
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.3"
    os.environ["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"] = "-1"

import jax  # noqa: E402
import jax_time  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax_time.install()  # JAXGFX_JAX_TIME=DIR: where the suite's time goes (tests/jax_time.py)

# Compiling is most of this suite's time, so tests (and the CLI and experiment runs they
# start: the variables reach subprocesses) compile at XLA:CPU's lowest backend optimization
# level and with its elemental emitters in place of the default fusion emitters, which
# together take about half of the compile time: what the tests check (values, shapes, errors,
# gradients) does not depend on either.  A claim that two programs give bit-identical results
# is a claim about the user's code generation (the two emitters round differently): such tests
# compile both programs with XLA's defaults (``USER_CODEGEN``; the sweep tests' subprocesses
# set their own flags).  JAXGFX_TEST_CODEGEN=default runs every test with the defaults.
# XLA reads its flags when the backend starts (the first array), after these imports; it
# aborts on a flag it does not know, so a jaxlib without the emitter flag keeps its default.
_LEVEL_0 = "--xla_backend_optimization_level=0"
_ELEMENTAL = "--xla_cpu_use_fusion_emitters=false"
USER_CODEGEN: dict = {"xla_backend_optimization_level": 3}
"""``jax.jit(..., compiler_options=USER_CODEGEN)``: XLA:CPU's default code generation."""
if os.environ.get("JAXGFX_TEST_CODEGEN") != "default":
    _flags = os.environ.get("XLA_FLAGS", "")
    if _LEVEL_0 not in _flags:
        _flags = f"{_flags} {_LEVEL_0}".strip()
    if _ELEMENTAL not in _flags:  # the controller: xdist's workers inherit its variables
        _with = f"{_flags} {_ELEMENTAL}"
        _probe = subprocess.run(
            [sys.executable, "-c", "import jax; jax.devices()"],
            env={**os.environ, "XLA_FLAGS": _with},
            capture_output=True,
        )
        _flags = _with if _probe.returncode == 0 else _flags
    os.environ["XLA_FLAGS"] = _flags
    if _ELEMENTAL in _flags:
        USER_CODEGEN["xla_cpu_use_fusion_emitters"] = True

DATA = Path(
    os.environ.get("JAXGFX_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
)


# CLI runs in subprocesses (the sweep tests) keep their compilation cache out of $HOME.
os.environ.setdefault("JAXGFX_CACHE_DIR", tempfile.mkdtemp(prefix="jaxgfx-test-cache-"))


# The longest modules (``pytest --durations=0``, summed per module), longest first, scheduled
# before the rest.  xdist gives each worker whole modules (--dist loadfile), so a module's
# shared jitted functions compile once, not once per worker; a long module started last would
# leave the other worker idle at the end of the run.  xdist's own order (by test count) is off
# (``--no-loadscope-reorder`` in pyproject.toml), so this one holds.
SLOW_FIRST = (
    "test_examples.py",
    "test_experiments.py",
    "test_raycast.py",
    "test_sweep.py",
    "test_terrain.py",
    "test_raster.py",
    "test_skin.py",
    "test_silhouette.py",
    "test_showcase.py",
    "test_fit_images.py",
    "test_inputs.py",
)


def pytest_unconfigure(config):
    if _OWN_CACHE is not None and not hasattr(config, "workerinput"):
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


def pytest_terminal_summary(terminalreporter):
    """Each experiment's seconds in the shared smoke process (``test_experiments.py``)."""
    rows = [
        (dict(r.user_properties)["shared_process_seconds"], r.nodeid)
        for r in terminalreporter.stats.get("passed", []) + terminalreporter.stats.get("failed", [])
        if r.when == "call" and "shared_process_seconds" in dict(r.user_properties)
    ]
    if rows:
        terminalreporter.section("experiments in the shared process (seconds each)")
        for seconds, nodeid in sorted(rows, key=lambda r: -(r[0] or 0)):
            terminalreporter.write_line(f"{seconds or 0:8.1f}s  {nodeid}")


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
def user_codegen() -> dict:
    """``USER_CODEGEN``, for programs compiled in a subprocess."""
    return dict(USER_CODEGEN)


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
