"""The ``jaxgfx`` command line.

Each subcommand lives in its own module with ``register(subparsers)``; :data:`COMMANDS`
lists them in the order ``jaxgfx --help`` shows them.  Arguments are parsed by the
helpers in :mod:`jaxgfx.cli.args`.  Errors end in one line on stderr:

* a usage error or a bad input (``CliError``: an argument, a file that is not what it
  should be) prints ``jaxgfx CMD: error: ...`` and exits with 2;
* an output that cannot be written after the work (``OutputError``) exits with 1;
* Ctrl-C prints ``jaxgfx CMD: interrupted: ...`` (for a sweep: what is kept and how to
  resume) and exits with 130;
* any other exception is a bug in jaxgfx and shows its traceback (exit 1).

Second runs are fast: before any JAX computation :func:`main` turns on JAX's persistent
compilation cache in :func:`cache_dir` (``$JAXGFX_CACHE_DIR``, else
``$XDG_CACHE_HOME/jaxgfx/jax``, else ``~/.cache/jaxgfx/jax``), caching every program however
small or quick to compile; ``jaxgfx --no-cache CMD ...`` skips it.  The cache is bounded:
at start the least recently used entries are removed until it holds at most
``$JAXGFX_CACHE_MAX_MB`` megabytes (default :data:`CACHE_MAX_MB`; 0 turns the cache off),
see :func:`prune_cache`.

Every core: one XLA:CPU device uses other cores only inside large fused loops (the rest of
a program runs on one thread), so commands that shard a batch over
devices (``jaxgfx sweep``, marked by a ``--devices`` option) first give JAX one host device per
core by adding ``--xla_force_host_platform_device_count`` to ``XLA_FLAGS``
(:func:`host_device_flags`).  ``import jaxgfx`` imports JAX but does not start its backends, so
:func:`main` can still do this before the first JAX computation.

Fresh memory: when JAX will run on the CPU, :func:`main` also makes the process's ``malloc``
keep what it frees (:func:`jaxgfx.keep_freed_memory`), so XLA:CPU's calls reuse touched
pages instead of page-faulting fresh ones every frame.  Whether JAX will run on the CPU is
decided without starting a backend (:func:`runs_on_cpu`); on an accelerator the host's
``malloc`` is left as it is.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NoReturn

from jaxgfx._src.hostmem import keep_freed_memory
from jaxgfx.cli import demo, flythrough, info, render, skin, terrain, voxels
from jaxgfx.cli.args import CliError, Interrupted, join_negative_values

__all__ = [
    "main",
    "build_parser",
    "COMMANDS",
    "cache_dir",
    "cache_max_bytes",
    "prune_cache",
    "enable_compilation_cache",
    "runs_on_cpu",
    "host_device_flags",
    "host_cores",
]

_COUNT_FLAG = "--xla_force_host_platform_device_count"

COMMANDS = (demo, render, info, voxels, terrain, flythrough, skin)

CACHE_MAX_MB = 1024
"""Default bound of the compilation cache in megabytes (``$JAXGFX_CACHE_MAX_MB``)."""


def cache_dir(environ: Mapping[str, str] | None = None) -> Path:
    """Where the CLI keeps compiled programs: ``$JAXGFX_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/jaxgfx/jax``, else ``~/.cache/jaxgfx/jax``."""
    env = os.environ if environ is None else environ
    if env.get("JAXGFX_CACHE_DIR"):
        return Path(env["JAXGFX_CACHE_DIR"]).expanduser()
    base = env.get("XDG_CACHE_HOME") or str(Path("~/.cache").expanduser())
    return Path(base) / "jaxgfx" / "jax"


def cache_max_bytes(environ: Mapping[str, str] | None = None) -> int:
    """The compilation cache's bound in bytes: ``$JAXGFX_CACHE_MAX_MB`` megabytes, else
    :data:`CACHE_MAX_MB`; 0 means no cache.

    Raises:
        CliError: ``$JAXGFX_CACHE_MAX_MB`` is not a number >= 0.
    """
    env = os.environ if environ is None else environ
    text = env.get("JAXGFX_CACHE_MAX_MB", "").strip()
    if not text:
        return CACHE_MAX_MB << 20
    try:
        mb = float(text)
    except ValueError:
        mb = -1.0
    if not (mb >= 0 and mb < float("inf")):
        raise CliError(f"$JAXGFX_CACHE_MAX_MB must be a number of megabytes >= 0, got {text!r}")
    return int(mb * (1 << 20))


def prune_cache(path: Path, max_bytes: int) -> int:
    """Removes the least recently used files under ``path`` until at most ``max_bytes`` remain.

    A file's last use is the later of its access and modification times (JAX reads a
    cache entry to use it, and writes it once).  Files that vanish meanwhile (another
    process pruning) are skipped.

    Returns:
        The bytes removed.
    """
    entries = []
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            f = os.path.join(root, name)
            try:
                st = os.stat(f)
            except OSError:
                continue
            entries.append((max(st.st_atime, st.st_mtime), st.st_size, f))
            total += st.st_size
    removed = 0
    for _, size, f in sorted(entries):
        if total - removed <= max_bytes:
            break
        try:
            os.remove(f)
        except OSError:
            continue
        removed += size
    return removed


def enable_compilation_cache(path: Path, max_bytes: int | None = None) -> bool:
    """Points JAX's persistent compilation cache at ``path`` for every program.

    The cache is first pruned to ``max_bytes`` (default :func:`cache_max_bytes`) by
    :func:`prune_cache`.  Returns False (and leaves JAX alone) when the directory cannot be
    created or written, or when the bound is 0: a cache that cannot be written must not stop
    a render.
    """
    if max_bytes is None:
        max_bytes = cache_max_bytes()
    if max_bytes <= 0:
        return False
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    if not os.access(path, os.W_OK | os.X_OK):
        return False
    prune_cache(path, max_bytes)
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    # JAX caches only programs that took >= 1 s to compile by default; ours are small.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return True


def _accelerator_plugins() -> bool:
    """Whether a JAX plugin for a non-CPU backend is installed (CUDA, ROCm, TPU, Metal)."""
    if importlib.util.find_spec("libtpu") is not None:
        return True
    try:
        if importlib.util.find_spec("jax_plugins") is not None:
            return True
    except (ImportError, ValueError):
        pass
    return bool(importlib.metadata.entry_points(group="jax_plugins"))


def runs_on_cpu(environ: Mapping[str, str] | None = None) -> bool:
    """Whether JAX's default backend is (or will be) the CPU, decided without starting one.

    For this process (``environ`` None): started backends answer for themselves
    (``jax.default_backend()``).  Otherwise a platform list (``jax.config.jax_platforms``,
    else ``JAX_PLATFORMS`` or the older ``JAX_PLATFORM_NAME`` in ``environ``) decides by
    its first entry, and without one JAX takes the CPU exactly when no accelerator plugin
    is installed.

    Args:
        environ: the environment to judge (default: this process's, with its JAX state).
    """
    import jax

    env = os.environ if environ is None else environ
    configured = None
    if environ is None:
        from jax._src import xla_bridge

        if xla_bridge.backends_are_initialized():
            return jax.default_backend() == "cpu"
        configured = jax.config.values.get("jax_platforms")
    platforms = configured or env.get("JAX_PLATFORMS") or env.get("JAX_PLATFORM_NAME") or ""
    if platforms:
        return platforms.split(",")[0].strip().lower() == "cpu"
    return not _accelerator_plugins()


def host_cores() -> int:
    """Cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _cpu_first(environ: Mapping[str, str]) -> bool:
    """False when ``JAX_PLATFORMS`` (or the older ``JAX_PLATFORM_NAME``) puts another first."""
    platforms = environ.get("JAX_PLATFORMS") or environ.get("JAX_PLATFORM_NAME") or ""
    return not platforms or platforms.split(",")[0].strip().lower() == "cpu"


def host_device_flags(environ: Mapping[str, str], devices: int | None, cores: int) -> str | None:
    """The ``XLA_FLAGS`` value that gives JAX one host (CPU) device per core, or None.

    None (leave the environment alone) when the user's ``XLA_FLAGS`` already sets the host
    device count, when ``JAX_PLATFORMS`` picks a backend other than the CPU first, or when one
    device is all there is to ask for.  The flag only shapes the CPU backend.

    Args:
        environ: the environment (``os.environ``).
        devices: the ``--devices`` the user asked for, or None for one per core.
        cores: the number of host cores (:func:`host_cores`).
    """
    flags = environ.get("XLA_FLAGS", "")
    if _COUNT_FLAG in flags or not _cpu_first(environ):
        return None
    n = cores if devices is None else devices
    if n <= 1:
        return None
    return f"{flags} {_COUNT_FLAG}={n}".strip()


def _use_host_cores(devices: int | None) -> None:
    """Sets ``XLA_FLAGS`` for :func:`host_device_flags` if JAX's backends have not started.

    Raises:
        CliError: ``--devices`` asks for more devices than this process has cores.
    """
    from jax._src import xla_bridge

    cores = host_cores()
    if devices is not None and devices > cores and _cpu_first(os.environ):
        # More host devices than cores only queue on the same cores; thousands stall XLA.
        raise CliError(f"--devices {devices}: this process may use only {cores} core(s)")

    # Once a backend runs (main() called in a process that already used JAX) the flag would
    # change nothing but the environment of child processes.
    if xla_bridge.backends_are_initialized():
        return
    flags = host_device_flags(os.environ, devices, cores)
    if flags is not None:
        os.environ["XLA_FLAGS"] = flags


class _Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line: ``PROG: error: MESSAGE``."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser with every subcommand of :data:`COMMANDS` registered."""
    p = _Parser(
        prog="jaxgfx",
        description="Game-engine visualization in JAX (terrain, voxels, skinning).",
        epilog="Environment: JAXGFX_CACHE_DIR is where compiled programs are kept (default "
        "$XDG_CACHE_HOME/jaxgfx/jax or ~/.cache/jaxgfx/jax); JAXGFX_CACHE_MAX_MB bounds it "
        f"(default {CACHE_MAX_MB}; the least recently used programs are removed at start; "
        "0 turns the cache off); JAXGFX_DATA is the shared data folder 'jaxgfx demo' reads.",
    )
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="do not use the persistent compilation cache (see JAXGFX_CACHE_DIR and "
        "JAXGFX_CACHE_MAX_MB below)",
    )
    sub = p.add_subparsers(dest="command", title="commands")
    for module in COMMANDS:
        module.register(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs one subcommand; returns its exit code (2 for a usage error, 130 for Ctrl-C)."""
    parser = build_parser()
    args_list = join_negative_values(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(args_list)
    except SystemExit as exc:  # argparse printed usage + "error:" (2) or --help (0)
        return exc.code if isinstance(exc.code, int) else 2
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    # Every command turns its input errors into CliError itself (args.input_errors), so an
    # exception reaching main() otherwise is a bug and shows its traceback.
    usage_errors: tuple[type[BaseException], ...] = (CliError,)
    try:
        if getattr(args, "devices", False) is not False:  # a command that shards over devices
            _use_host_cores(args.devices)
        if runs_on_cpu():
            keep_freed_memory()  # XLA:CPU's next call reuses the last one's memory
        if not args.no_cache and cache_max_bytes() > 0:  # 0: the user turned the cache off
            enable_compilation_cache(cache_dir())
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"jaxgfx {args.command}: interrupted", file=sys.stderr)
        return Interrupted.exit_code
    except usage_errors as exc:
        label = exc.label if isinstance(exc, CliError) else "error"
        code = exc.exit_code if isinstance(exc, CliError) else 2
        print(f"jaxgfx {args.command}: {label}: {exc}", file=sys.stderr)
        return code


if __name__ == "__main__":
    sys.exit(main())
