"""Argument parsing shared by every ``jaxgfx`` subcommand: sizes, cameras, numbers, errors.

Every parser here raises ``argparse.ArgumentTypeError`` with a message that names what was
expected, so argparse reports ``jaxgfx CMD: error: argument --X: ...`` and exits with 2.
Errors found after parsing (a missing file, an inconsistent combination) raise
:class:`CliError`; :func:`jaxgfx.cli.main` prints both the same way.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable, Sequence

__all__ = [
    "CliError",
    "parse_size",
    "parse_floats",
    "parse_ints",
    "positive_int",
    "parse_aa",
    "join_negative_values",
]


class CliError(Exception):
    """A usage error found after parsing; printed as ``jaxgfx CMD: error: ...``, exit 2."""


def parse_size(text: str) -> tuple[int, int]:
    """'WxH' -> (W, H), both positive."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 640x480, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def parse_floats(n: int, what: str = "") -> Callable[[str], list[float]]:
    """A parser of ``n`` finite comma-separated floats (``what`` names them in errors)."""

    def parse(text: str) -> list[float]:
        label = f" ({what})" if what else ""
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {n} comma-separated numbers{label}, got {text!r}"
            ) from None
        if len(vals) != n or not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(
                f"expected {n} finite comma-separated numbers{label}, got {text!r}"
            )
        return vals

    return parse


def parse_ints(n: int, what: str = "") -> Callable[[str], tuple[int, ...]]:
    """A parser of ``n`` comma-separated integers (``what`` names them in errors)."""

    def parse(text: str) -> tuple[int, ...]:
        label = f" ({what})" if what else ""
        try:
            vals = tuple(int(v) for v in text.split(","))
        except ValueError:
            vals = ()
        if len(vals) != n:
            raise argparse.ArgumentTypeError(
                f"expected {n} comma-separated integers{label}, got {text!r}"
            )
        return vals

    return parse


def positive_int(text: str) -> int:
    """An integer > 0."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {v}")
    return v


_AA = {"1x1": (1, 1), "2x1": (2, 1), "2x2": (2, 2)}


def parse_aa(text: str) -> tuple[int, int]:
    """Anti-aliasing factor: ``1x1`` (off), ``2x1`` (the thesis's) or ``2x2``."""
    if text not in _AA:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(_AA)}, got {text!r}")
    return _AA[text]


_NEGATIVE_VALUE = re.compile(r"^-(\d|\.\d)")


def join_negative_values(argv: Sequence[str]) -> list[str]:
    """``['--camera', '-120,45']`` -> ``['--camera=-120,45']``.

    argparse reads a token that starts with ``-`` as an option unless it is a single
    negative number, so comma-separated values such as a camera ``-120,45,...`` need the
    ``=`` form; this joins them for the user.  No option name starts with a digit.
    """
    out: list[str] = []
    for tok in argv:
        if (
            out
            and out[-1].startswith("--")
            and "=" not in out[-1]
            and _NEGATIVE_VALUE.match(tok)
            and "," in tok
        ):
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out
