"""Argument parsing shared by every ``jaxgfx`` subcommand: sizes, cameras, numbers, errors.

Every parser here raises ``argparse.ArgumentTypeError`` with a message that names what was
expected, so argparse reports ``jaxgfx CMD: error: argument --X: ...`` and exits with 2.
Errors found after parsing (a missing file, an inconsistent combination) raise
:class:`CliError`; :func:`jaxgfx.cli.main` prints both the same way.

Every subcommand checks its output paths (:func:`check_out_file`, :func:`check_out_dir`)
and its memory estimate (:func:`check_memory`) before it imports JAX or does any work,
so a bad path or an impossible size fails in well under a second instead of after the
render.  The memory limit is half the machine's physical RAM (``os.sysconf``), 8 GiB
where that is unknown; the estimates are deliberately rough upper bounds per pixel or
per voxel, meant to refuse sizes that cannot work, not to budget exactly.

Output paths are checked by creating a file where the output will go (and removing it),
not by permission bits alone: root passes ``os.access`` everywhere, yet cannot write into
``/sys`` or a read-only mount.  Input files are checked the same way before they are read
(:func:`check_in_file`): a directory or an unreadable file is named as such.  Library
errors raised while reading or validating the user's inputs become :class:`CliError`
through :func:`input_errors`; a write that fails after the work (a full disk) becomes one
line through :func:`writing` (:class:`OutputError`, exit 1).  Every other exception is a
bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

__all__ = [
    "CliError",
    "OutputError",
    "Interrupted",
    "input_errors",
    "writing",
    "check_in_file",
    "parse_size",
    "parse_floats",
    "parse_ints",
    "positive_int",
    "parse_aa",
    "parse_fov",
    "bounded_float",
    "nonnegative_int",
    "join_negative_values",
    "add_up_argument",
    "check_out_file",
    "check_out_dir",
    "memory_limit",
    "check_memory",
    "check_image",
    "PIXEL_BYTES",
]

PIXEL_BYTES = 128
"""Rough upper bound of the bytes one rasterized pixel costs (z-buffer, colour, depth, face
id, the compositing copies and headroom); :func:`check_image` multiplies it by W*H."""


class CliError(Exception):
    """A usage error found after parsing; printed as ``jaxgfx CMD: error: ...``, exit 2."""

    exit_code = 2
    label = "error"


class OutputError(CliError):
    """An output could not be written after the work was done (exit 1, one line)."""

    exit_code = 1


class Interrupted(CliError):
    """Ctrl-C: printed as ``jaxgfx CMD: interrupted: ...`` with what is kept, exit 130."""

    exit_code = 130
    label = "interrupted"


@contextlib.contextmanager
def input_errors(what: str = "") -> Iterator[None]:
    """Turns a ``ValueError``, ``TypeError`` or ``OSError`` raised inside into :class:`CliError`.

    Wrap only the reading and validating of the user's inputs (a file, a camera): the
    library's message then reaches the user as one line naming the input.  Errors from
    anywhere else are bugs and must keep their traceback.

    Args:
        what: prefix naming the input (e.g. ``"--rig"``); empty when the library's message
            already names it.
    """
    try:
        yield
    except (ValueError, TypeError, OSError) as exc:
        text = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        if isinstance(exc, OSError) and exc.filename is not None:
            text = f"{exc.filename}: {text}"
        raise CliError(f"{what}: {text}" if what else text) from None


@contextlib.contextmanager
def writing(option: str, path: str | os.PathLike) -> Iterator[None]:
    """Turns an ``OSError`` while writing the output ``path`` into one line (exit 1).

    The paths were checked before the work (:func:`check_out_file`); this catches what
    can still go wrong after it: a full disk, a folder removed meanwhile.
    """
    try:
        yield
    except OSError as exc:
        why = exc.strerror or str(exc)
        raise OutputError(f"{option} {str(path)!r}: could not write it: {why}") from None


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


def _int_parser(low: int, rule: str) -> Callable[[str], int]:
    """A parser of one integer ``>= low``; ``rule`` words the bound in its error."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"must be {rule}, got {v}")
        return v

    return parse


positive_int = _int_parser(1, "> 0")
"""An integer > 0."""
nonnegative_int = _int_parser(0, ">= 0")
"""An integer >= 0."""


def bounded_float(lo: float, hi: float, *, open_interval: bool = False) -> Callable[[str], float]:
    """A parser of one finite float in ``[lo, hi]`` (``(lo, hi)`` when ``open_interval``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        inside = lo < v < hi if open_interval else lo <= v <= hi
        if not (math.isfinite(v) and inside):
            lb, rb = ("(", ")") if open_interval else ("[", "]")
            raise argparse.ArgumentTypeError(f"must be in {lb}{lo:g}, {hi:g}{rb}, got {text!r}")
        return v

    return parse


parse_fov = bounded_float(0.0, 180.0, open_interval=True)
"""A field of view in degrees, strictly between 0 and 180."""


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


def add_up_argument(parser: argparse.ArgumentParser) -> None:
    """Adds ``--up x|y|z`` (a mesh file's up axis, default y) for :func:`jaxgfx.io.load_mesh`."""
    parser.add_argument(
        "--up",
        choices=("x", "y", "z"),
        default="y",
        help="the mesh file's up axis, turned to y (z for most scans, e.g. Stanford Lucy)",
    )


def _try_create(option: str, what: str, folder: Path) -> None:
    """Creates and removes a file in ``folder``: the one test of writability that holds
    for root, read-only mounts and pseudo file systems alike."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".jaxgfx-check-", dir=folder)
    except OSError as exc:
        why = exc.strerror or str(exc)
        raise CliError(f"{option} {what}: cannot create a file in {str(folder)!r}: {why}") from None
    os.close(fd)
    os.remove(tmp)


def _check_parent(option: str, path: Path) -> None:
    parent = path.parent
    if not parent.exists():
        raise CliError(f"{option} {str(path)!r}: directory {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise CliError(f"{option} {str(path)!r}: {str(parent)!r} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CliError(f"{option} {str(path)!r}: directory {str(parent)!r} is not writable")
    _try_create(option, repr(str(path)), parent)


def check_out_file(option: str, path: str | os.PathLike, suffixes: Iterable[str]) -> Path:
    """Checks an output file before any work; returns it as a :class:`~pathlib.Path`.

    The suffix must be one of ``suffixes`` (lower case, with the dot: the file is written
    in that format and no other), the path must not be a directory, and a file must be
    creatable in its parent directory (tried, then removed); an existing file must be
    writable.  Raises :class:`CliError` naming ``option``.
    """
    p = Path(path)
    accepted = tuple(suffixes)
    if p.suffix.lower() not in accepted:
        got = repr(p.suffix) if p.suffix else "no suffix"
        raise CliError(
            f"{option} {str(p)!r}: {got} is not a format this writes; use {', '.join(accepted)}"
        )
    if p.is_dir():
        raise CliError(f"{option} {str(p)!r} is a directory, expected a file")
    _check_parent(option, p)
    if p.exists() and not os.access(p, os.W_OK):
        raise CliError(f"{option} {str(p)!r} is not writable")
    return p


def check_out_dir(option: str, path: str | os.PathLike) -> Path:
    """Checks an output directory before any work: an existing directory a file can be
    created in, or a new one whose parent exists and takes a new file.  Raises
    :class:`CliError` naming ``option``."""
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise CliError(f"{option} {str(p)!r} is a file, expected a directory")
        if not os.access(p, os.W_OK | os.X_OK):
            raise CliError(f"{option} {str(p)!r}: directory is not writable")
        _try_create(option, repr(str(p)), p)
        return p
    _check_parent(option, p)
    return p


def check_in_file(option: str, path: str | os.PathLike, kind: str) -> Path:
    """Checks an input file before any work: it exists, is a file and can be opened.

    Args:
        option: the argument's name in messages (``"mesh"``, ``"--rig"``).
        path: the path the user gave.
        kind: what was expected, e.g. ``"a mesh file (.ply, .obj, ...)"``.

    Raises:
        CliError: the path does not exist, is a directory or cannot be read; the message
            names ``option``, the path and ``kind``.
    """
    p = Path(path)
    if p.is_dir():
        raise CliError(f"{option} {str(p)!r} is a directory, expected {kind}")
    if not p.exists():
        raise CliError(f"{option} {str(p)!r} not found")
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:
        raise CliError(f"{option} {str(p)!r} cannot be read: {exc.strerror or exc}") from None
    return p


def memory_limit() -> int:
    """The most bytes a command may plan to use: half the physical RAM, else 8 GiB."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        total = 0
    return total // 2 if total > 0 else 8 << 30


def _gib(n: float) -> str:
    return f"{n / 2**30:,.1f} GiB"


def check_memory(option: str, value: str, nbytes: float) -> None:
    """Refuses ``option value`` when its estimate ``nbytes`` exceeds :func:`memory_limit`."""
    limit = memory_limit()
    if nbytes > limit:
        raise CliError(
            f"{option} {value}: needs about {_gib(nbytes)}, more than the limit of "
            f"{_gib(limit)} (half the physical memory); choose a smaller value"
        )


def check_image(size: tuple[int, int], bytes_per_pixel: float, option: str = "--size") -> None:
    """:func:`check_memory` for a ``W x H`` frame at ``bytes_per_pixel``."""
    w, h = size
    check_memory(option, f"{w}x{h}", float(w) * h * bytes_per_pixel)
