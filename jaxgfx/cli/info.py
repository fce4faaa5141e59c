"""``jaxgfx info``: versions, backend and devices as JSON."""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Adds ``info`` to the CLI's subparsers."""
    i = subparsers.add_parser("info", help="jax version and devices")
    i.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Prints one JSON object: versions, backend, devices, processes, machine."""
    import jax

    import jaxgfx
    from jaxgfx._src.report import machine

    info = dict(
        jaxgfx=jaxgfx.__version__,
        jax=jax.__version__,
        backend=jax.default_backend(),
        devices=[str(d) for d in jax.devices()],
        local_devices=jax.local_device_count(),
        processes=jax.process_count(),
        python=sys.version.split()[0],
        machine=machine(),
    )
    print(json.dumps(info, indent=2))
    return 0
