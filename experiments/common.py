"""Helpers shared by every experiment: machine line, timing, atomic Markdown/JSON tables."""

from __future__ import annotations

import json
import os
import platform
import time

import jax

from jaxgfx.io import atomic_write

__all__ = ["machine", "time_jitted", "markdown_table", "write_table"]


def machine() -> str:
    """One line naming the CPU model, core count, current load, JAX version and devices."""
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
    devs = ", ".join(sorted({d.device_kind for d in jax.devices()}))
    return f"{cpu}, {os.cpu_count()} cores (load {load:.1f}); jax {jax.__version__} on {devs}"


def time_jitted(fn, *args, repeats: int = 3):
    """(first call incl. trace + compile, median steady seconds, output), all blocked."""
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


def markdown_table(rows: list[dict], columns: list[str]) -> str:
    """Rows of dicts as a Markdown table (floats with 4 significant digits)."""

    def fmt(v):
        if v is None:
            return ""
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def write_table(out_dir, name: str, markdown: str, data: dict) -> None:
    """Writes ``table.md`` and ``table.json`` atomically under ``out_dir``."""
    os.makedirs(out_dir, exist_ok=True)
    with atomic_write(os.path.join(out_dir, "table.md")) as tmp:
        tmp.write_text(f"# {name}\n\n{markdown}\n")
    with atomic_write(os.path.join(out_dir, "table.json")) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
