"""The ``jaxgfx`` command line.

Each subcommand lives in its own module with ``register(subparsers)``; :data:`COMMANDS`
lists them in the order ``jaxgfx --help`` shows them.  Arguments are parsed by the
helpers in :mod:`jaxgfx.cli.args`; every usage error ends the same way: one
``jaxgfx CMD: error: ...`` line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from jaxgfx.cli import demo, info, render, skin, terrain, voxels
from jaxgfx.cli.args import CliError, join_negative_values

__all__ = ["main", "build_parser", "COMMANDS"]

COMMANDS = (demo, render, info, voxels, terrain, skin)


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser with every subcommand of :data:`COMMANDS` registered."""
    p = argparse.ArgumentParser(
        prog="jaxgfx",
        description="Game-engine visualization in JAX (terrain, voxels, skinning).",
    )
    sub = p.add_subparsers(dest="command")
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
        return int(args.func(args) or 0)
    except (CliError, ValueError, TypeError, FileNotFoundError) as exc:
        print(f"jaxgfx {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
