"""The ``jaxgfx`` command line.

Each subcommand lives in its own module with ``register(subparsers)``; :data:`COMMANDS`
lists them in the order ``jaxgfx --help`` shows them.  Arguments are parsed by the
helpers in :mod:`jaxgfx.cli.args`; every usage error ends the same way: one
``jaxgfx CMD: error: ...`` line on stderr and exit code 2.

Second runs are fast: before any JAX computation :func:`main` turns on JAX's persistent
compilation cache in :func:`cache_dir` (``$JAXGFX_CACHE_DIR``, else
``$XDG_CACHE_HOME/jaxgfx/jax``, else ``~/.cache/jaxgfx/jax``), caching every program however
small or quick to compile; ``jaxgfx --no-cache CMD ...`` skips it.

Every core: one XLA:CPU device uses other cores only inside large fused loops (the rest of
a program runs on one thread), so commands that shard a batch over
devices (``jaxgfx sweep``, marked by a ``--devices`` option) first give JAX one host device per
core by adding ``--xla_force_host_platform_device_count`` to ``XLA_FLAGS``
(:func:`host_device_flags`).  ``import jaxgfx`` imports JAX but does not start its backends, so
:func:`main` can still do this before the first JAX computation.

Fresh memory: :func:`main` also makes the process's ``malloc`` keep what it frees
(:func:`jaxgfx.keep_freed_memory`), so XLA:CPU's calls reuse touched pages instead of
page-faulting fresh ones every frame.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NoReturn

from jaxgfx._src.hostmem import keep_freed_memory
from jaxgfx.cli import demo, flythrough, info, render, skin, terrain, voxels
from jaxgfx.cli.args import CliError, join_negative_values

__all__ = [
    "main",
    "build_parser",
    "COMMANDS",
    "cache_dir",
    "enable_compilation_cache",
    "host_device_flags",
    "host_cores",
]

_COUNT_FLAG = "--xla_force_host_platform_device_count"

COMMANDS = (demo, render, info, voxels, terrain, flythrough, skin)


def cache_dir(environ: Mapping[str, str] | None = None) -> Path:
    """Where the CLI keeps compiled programs: ``$JAXGFX_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/jaxgfx/jax``, else ``~/.cache/jaxgfx/jax``."""
    env = os.environ if environ is None else environ
    if env.get("JAXGFX_CACHE_DIR"):
        return Path(env["JAXGFX_CACHE_DIR"]).expanduser()
    base = env.get("XDG_CACHE_HOME") or str(Path("~/.cache").expanduser())
    return Path(base) / "jaxgfx" / "jax"


def enable_compilation_cache(path: Path) -> bool:
    """Points JAX's persistent compilation cache at ``path`` for every program.

    Returns False (and leaves JAX alone) when the directory cannot be created: a cache
    that cannot be written must not stop a render.
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    if not os.access(path, os.W_OK | os.X_OK):
        return False
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    # JAX caches only programs that took >= 1 s to compile by default; ours are small.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return True


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
    )
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="do not use the persistent compilation cache (see JAXGFX_CACHE_DIR)",
    )
    sub = p.add_subparsers(dest="command", title="commands")
    for module in COMMANDS:
        module.register(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs one subcommand; returns its exit code (2 for any usage error)."""
    parser = build_parser()
    args_list = join_negative_values(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(args_list)
    except SystemExit as exc:  # argparse printed usage + "error:" (2) or --help (0)
        return exc.code if isinstance(exc.code, int) else 2
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        if getattr(args, "devices", False) is not False:  # a command that shards over devices
            _use_host_cores(args.devices)
        keep_freed_memory()  # XLA:CPU's next call reuses the last one's memory
        if not args.no_cache:
            enable_compilation_cache(cache_dir())
        return int(args.func(args) or 0)
    except (CliError, ValueError, TypeError, FileNotFoundError) as exc:
        print(f"jaxgfx {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
