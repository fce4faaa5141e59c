"""Timing, machine description and tables, shared by the CLI and the experiments.

Compile time is always reported apart from steady-state time (the first call of a
jitted function traces, compiles and runs it).
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax

from jaxgfx._src.io import atomic_write

__all__ = ["machine", "time_jitted", "markdown_table", "write_table"]


def machine() -> str:
    """One line: CPU model, core count, current load, JAX version, devices (count x kind)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    kinds = [d.device_kind for d in jax.devices()]
    devs = ", ".join(f"{kinds.count(k)} x {k}" for k in sorted(set(kinds)))
    return f"{cpu}, {os.cpu_count()} cores (load {load:.1f}); jax {jax.__version__} on {devs}"


def time_jitted(fn: Callable[..., Any], *args: Any, repeats: int = 3) -> tuple[float, float, Any]:
    """Times a jitted function.

    Returns:
        (seconds of the first call, including trace and compile; median seconds of
        ``repeats`` later calls; the output), every call blocked until ready.
    """
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    ts.sort()
    return first, ts[len(ts) // 2], out


def markdown_table(rows: Sequence[dict], columns: Sequence[str]) -> str:
    """Rows of dicts as a Markdown table (floats with 4 significant digits, None blank)."""

    def fmt(v: Any) -> str:
        if v is None:
            return ""
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def write_table(
    out_dir: str | os.PathLike, name: str, markdown: str, data: dict, *, stem: str = "table"
) -> None:
    """Writes ``<stem>.md`` (titled ``name``) and ``<stem>.json`` atomically under ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / f"{stem}.md") as tmp:
        tmp.write_text(f"# {name}\n\n{markdown}\n")
    with atomic_write(out / f"{stem}.json") as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
