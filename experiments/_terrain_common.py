"""Helpers shared by the terrain experiments (thesis ch. 3): machine line, atomic table output."""

from __future__ import annotations

import json
import os
import platform

import jax

__all__ = ["machine", "write_table"]


def machine() -> str:
    """One line naming the CPU, core count, load and JAX devices."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    devs = ", ".join(sorted({d.device_kind for d in jax.devices()}))
    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores "
        f"(load {load:.1f}); jax {jax.__version__} on {devs}"
    )


def write_table(out_dir, name: str, markdown: str, data: dict) -> None:
    """Writes ``table.md`` and ``table.json`` atomically under ``out_dir``."""
    from jaxgfx.io import atomic_write

    os.makedirs(out_dir, exist_ok=True)
    with atomic_write(os.path.join(out_dir, "table.md")) as tmp:
        tmp.write_text(f"# {name}\n\n{markdown}\n")
    with atomic_write(os.path.join(out_dir, "table.json")) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
