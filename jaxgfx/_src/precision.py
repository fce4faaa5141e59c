"""32-bit kernels under ``jax_enable_x64``.

The renderers compare float bit patterns (the z-buffer's 1/z as int32), pack run-length
elements into int32 words and carry int32 loop counters, so they are defined in 32 bits.
With ``jax_enable_x64`` a user's float64 inputs and JAX's 64-bit defaults (``jnp.arange``,
Python scalars) would change those types mid-kernel.  :func:`in_32bit` gives a public kernel
32-bit inputs and traces its body with x64 off, so it computes and returns exactly what it
does without x64; the caller's own code around it keeps 64 bits.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["to_32bit", "in_32bit"]

_NARROW = {
    np.dtype(np.float64): np.float32,
    np.dtype(np.int64): np.int32,
    np.dtype(np.uint64): np.uint32,
    np.dtype(np.complex128): np.complex64,
}

F = TypeVar("F", bound=Callable[..., Any])


def to_32bit(tree):
    """``tree`` with every 64-bit array leaf cast to its 32-bit type; other leaves unchanged."""

    def narrow(x):
        dtype = getattr(x, "dtype", None)
        if dtype is None or np.dtype(dtype) not in _NARROW:
            return x
        target = _NARROW[np.dtype(dtype)]
        return x.astype(target) if isinstance(x, np.ndarray) else jnp.asarray(x, target)

    return jax.tree_util.tree_map(narrow, tree)


def in_32bit(fn: F) -> F:
    """``fn`` with 32-bit array arguments, traced with ``jax_enable_x64`` off.

    Without x64 it is ``fn`` unchanged (the cast and the context are no-ops).
    """

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        if not jax.config.jax_enable_x64:
            return fn(*args, **kwargs)
        args, kwargs = to_32bit((args, kwargs))
        with jax.enable_x64(False):
            return fn(*args, **kwargs)

    return wrapped  # type: ignore[return-value]
