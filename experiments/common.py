"""Helpers shared by the experiments: timing, machine description, table output."""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import jax

from jaxgfx.io import atomic_write


def machine() -> str:
    """One line naming the processor, core count, JAX version and devices."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    devs = ", ".join(sorted({d.device_kind for d in jax.devices()}))
    return f"{cpu}, {os.cpu_count()} cores; jax {jax.__version__}; devices: {devs}"


def time_jitted(fn, *args, repeats: int = 3):
    """(first call incl. compile, median steady seconds, output)."""
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
    head = "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n"
    return head + "".join(
        "| " + " | ".join(str(r.get(c, "")) for c in columns) + " |\n" for r in rows
    )


def write_table(out_dir, name: str, title: str, rows: list[dict], columns: list[str], meta: dict):
    """Prints the table and writes ``name.md`` and ``name.json`` atomically into ``out_dir``."""
    mach = meta.get("machine", machine())
    md = f"## {title}\n\n{markdown_table(rows, columns)}\nmachine: {mach}\n"
    print(md)
    if out_dir is None:
        return md
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / f"{name}.md") as tmp:
        tmp.write_text(md)
    with atomic_write(out / f"{name}.json") as tmp:
        tmp.write_text(json.dumps(dict(meta, rows=rows), indent=2, default=str) + "\n")
    return md
