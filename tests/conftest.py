"""Shared fixtures: the data folder and jitted functions compiled once per session."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import pytest

DATA = Path(
    os.environ.get("JAXGFX_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """``../shared/data`` beside the checkout; tests needing it skip when absent."""
    if not DATA.is_dir():
        pytest.skip(f"real data folder {DATA} is absent (clone of the project alone)")
    return DATA


@pytest.fixture(scope="session")
def raster_jit():
    from jaxgfx.raster import rasterize

    return jax.jit(rasterize, static_argnames=("cull_backfaces", "block", "chunk"))
