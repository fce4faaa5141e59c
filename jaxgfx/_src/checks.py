"""Argument checks and dataclass helpers shared by every layer.

Bad input must fail before tracing with a ``TypeError``/``ValueError`` that names the
argument; these helpers keep those messages in one form.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

__all__ = ["static_field", "check_int", "check_float"]

_MISSING: Any = dataclasses.MISSING


def static_field(default: Any = _MISSING) -> Any:
    """A dataclass field that ``jax.tree_util.register_dataclass`` treats as static.

    Static fields are part of the pytree's structure (they set shapes or choose code
    paths), so changing one retraces a jitted function instead of being traced.
    """
    return dataclasses.field(default=default, metadata=dict(static=True))


def check_int(name: str, value: Any, *, low: int | None = None, high: int | None = None) -> int:
    """``value`` as a Python int in ``[low, high]``; raises naming ``name`` otherwise.

    Booleans are refused (``True`` is an int to Python, never a size to us).

    Raises:
        TypeError: ``value`` is not an integer.
        ValueError: ``value`` is outside ``[low, high]``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    value = int(value)
    if low is not None and value < low:
        raise ValueError(f"{name} must be >= {low}, got {value}")
    if high is not None and value > high:
        raise ValueError(f"{name} must be <= {high}, got {value}")
    return value


def check_float(
    name: str, value: Any, *, low: float | None = None, high: float | None = None
) -> float:
    """``value`` as a finite Python float in ``[low, high]``; raises naming ``name`` otherwise.

    Raises:
        TypeError: ``value`` is not a real number.
        ValueError: ``value`` is not finite or outside ``[low, high]``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    if low is not None and value < low:
        raise ValueError(f"{name} must be >= {low}, got {value}")
    if high is not None and value > high:
        raise ValueError(f"{name} must be <= {high}, got {value}")
    return value
