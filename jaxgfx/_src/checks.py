"""Argument checks, value checks under ``jit``, and dataclass helpers shared by every layer.

Bad input must fail before tracing with a ``TypeError``/``ValueError`` that names the
argument; these helpers keep those messages in one form.

Shapes and types are checked on abstract values, values (NaN, an index out of range) where
they are concrete.  Under ``jax.jit`` values are tracers: nothing can be raised while
tracing, and a kernel would turn a NaN camera into an empty frame or clamp a bad face index.
:func:`checked` checks those values too, as ``equinox.error_if`` does: the kernels' entry
points call :func:`require_finite`, :func:`require_indices` and :func:`require_values`, which
do nothing unless a function wrapped by :func:`checked` is being traced.  There a traced
value gets a run-time check (a host callback reporting a failed predicate) and a known one
is checked at once.  The flag is a ``jax.make_user_context``, part of ``jit``'s cache key,
so a jitted function traced inside :func:`checked` is traced again with the checks, and one
traced outside keeps its program: the default programs hold no check.

The callbacks are ``io_callback`` (unordered): a kept side effect, run once per item of a
``vmap`` batch by a rolled loop (``jax.debug.callback`` unrolls the batch into the program),
with ``stop_gradient`` arguments, so they also hold under ``grad``.  A transform such as
``jax.experimental.checkify`` cannot be used: it refuses the batched while loops of the
renderers' vectorized batch rule.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import threading
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import io_callback

__all__ = [
    "static_field",
    "check_int",
    "check_float",
    "check_pixels",
    "check_finite",
    "MAX_PIXELS",
    "checked",
    "checking",
    "require_finite",
    "require_indices",
    "require_values",
]

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


MAX_PIXELS = 2**31 - 1
"""The most pixels (``width * height``) a frame may have: the renderers index pixels with
int32 (2^31 - 1 is 46340 x 46340)."""


def check_pixels(width, height) -> tuple[int, int]:
    """``(width, height)`` as ints >= 1 whose product is at most :data:`MAX_PIXELS`.

    Raises:
        TypeError: not integers.
        ValueError: < 1, or too many pixels for the renderers' int32 pixel indices.
    """
    width = check_int("width", width, low=1)
    height = check_int("height", height, low=1)
    if width * height > MAX_PIXELS:
        raise ValueError(
            f"width x height = {width} x {height} = {width * height} pixels: at most "
            f"{MAX_PIXELS} (2^31 - 1, e.g. 46340 x 46340) fit the renderers' int32 pixel "
            "indices"
        )
    return width, height


# --------------------------------------------------------------------------------------
# value checks under jit (checked mode)
# --------------------------------------------------------------------------------------

# The mode while a checked function is traced: None (no checks), "record" (failures are
# recorded and raised by checked() after the run) or "raise" (the callback raises: checked()
# is itself traced, e.g. inside jax.jit, so nothing of it runs after the program).
_CHECKING = jax.make_user_context(default_value=None)
_SITES = itertools.count()  # one number per check traced: the program order of checks
_FAILED: list[tuple[int, str]] = []  # failed checks of the runs in progress: (site, text)
_FAILED_LOCK = threading.Lock()  # the callbacks run on the runtime's threads
_RUNS = threading.RLock()  # one checked run at a time (nested ones in the same thread)


def checking() -> bool:
    """True while a function wrapped by :func:`checked` is being traced."""
    return _CHECKING.value is not None


def checked(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` with jaxgfx's value checks on, also for values traced under ``jax.jit``.

    Eager calls check their arguments' values anyway; under ``jit`` (and ``vmap``, ``grad``)
    the values are unknown while tracing, so the kernels check only shapes and types, and a
    bad value becomes a wrong picture: NaN vertices or a NaN camera give an empty frame, an
    out-of-range face index is clamped.  Inside ``checked(fn)`` every kernel also checks the
    values it is given while the program runs, and the first failed check (in program
    order) raises ``ValueError`` naming the argument and the kernel, e.g.
    ``vertices: 3 of 3600 values are NaN or infinite (in rasterize)``.

    Wrap the jitted function, ``jaxgfx.checked(jax.jit(fn))``: it runs a checked program
    (compiled once per argument shapes, like any ``jit``), waits for it and raises the
    ``ValueError``.  ``jax.jit(jaxgfx.checked(fn))`` works too; there the check's host
    callback raises while the program runs, which reaches the caller as
    ``jax.errors.JaxRuntimeError`` whose message ends with the same ``ValueError`` line.
    Without ``checked`` nothing is checked or compiled: the default programs are unchanged.
    Checked runs take a lock, one at a time, and each check costs a host callback (per
    item of a ``vmap`` batch): a mode for finding bad inputs, not for production.  A
    ``vmap`` over a batch sharded along an explicit mesh axis
    (:func:`jaxgfx.sweep.shard_batch`) cannot be checked per item (``NotImplementedError``);
    :func:`jaxgfx.sweep.sharded_vmap` and :func:`~jaxgfx.sweep.sharded_renderer` can.

    Args:
        fn: any function that calls jaxgfx kernels (jitted or not).

    Returns:
        A function with ``fn``'s signature and results.

    Raises:
        ValueError: (from the returned function) a value check failed.

    Example:
        >>> import jax, jax.numpy as jnp, jaxgfx
        >>> cam = jaxgfx.look_at([0, 0, 3], [0, 0, 0], 50.0, 16, 12)
        >>> faces = jnp.array([[0, 1, 2]])
        >>> verts = jnp.array([[0.0, 0, 0], [1, 0, 0], [jnp.nan, 1, 0]])
        >>> render = jaxgfx.checked(jax.jit(jaxgfx.rasterize))
        >>> render(cam, verts, faces)
        Traceback (most recent call last):
        ValueError: vertices: 1 of 9 values are NaN or infinite (in rasterize)
    """

    @functools.wraps(fn)
    def run(*args, **kwargs):
        # A zero made here is a tracer only while a staging transform (jit, scan) traces.
        if isinstance(jnp.zeros(()), jax.core.Tracer):
            with _CHECKING("raise"):
                return fn(*args, **kwargs)
        with _RUNS:
            start = len(_FAILED)
            try:
                with _CHECKING("record"):
                    out = fn(*args, **kwargs)
                jax.effects_barrier()  # every check of the run has reported
            finally:
                with _FAILED_LOCK:
                    failed = sorted(_FAILED[start:])
                    del _FAILED[start:]
        if failed:
            raise ValueError(failed[0][1])
        return out

    return run


def _check(ok, rule: str, value) -> None:
    """Checked mode: a run-time check that the () bool ``ok`` holds.

    Otherwise ``rule.format(value)`` is the failure's text.
    """
    if not isinstance(ok, jax.core.Tracer) and not isinstance(value, jax.core.Tracer):
        if not bool(ok):  # known now (an eager call): no need to wait for a run
            raise ValueError(rule.format(_shown(value)))
        return
    site = next(_SITES)
    raise_now = _CHECKING.value == "raise"

    def report(ok, value):
        if ok:
            return
        text = rule.format(_shown(value))
        if raise_now:
            raise ValueError(text)
        with _FAILED_LOCK:
            _FAILED.append((site, text))

    try:
        io_callback(report, None, *jax.lax.stop_gradient((ok, value)), ordered=False)
    except ValueError as err:  # io_callback's vmap rule loops over the batch (lax.map)
        raise NotImplementedError(
            "jaxgfx.checked cannot check the items of a vmap over a batch sharded along an "
            "explicit mesh axis (jaxgfx.sweep.shard_batch): check it unsharded, or batch "
            f"with jaxgfx.sweep.sharded_vmap or sharded_renderer ({err})"
        ) from err


def require_values(name: str, ok, x, rule: str, where: str | None = None) -> None:
    """Checked mode: every element of ``ok`` must hold, else ``name: <rule with the value>``.

    Outside :func:`checked` it does nothing (callers compute ``ok`` under
    :func:`checking` only, so that the default programs hold no trace of it).

    Args:
        name: the argument, e.g. ``"cam.focal"``.
        ok: bool array, one per element of ``x`` (any shape).
        x: the values; the first one failing replaces ``{}`` in ``rule``.
        rule: what is wrong, e.g. ``"{} is outside (0, pi)"`` or
            ``"index {} out of range for 1200 vertices"``.
        where: the public function that checks, e.g. ``"rasterize"`` (named in the message).
    """
    if not checking():
        return
    ok = jnp.asarray(ok).reshape(-1)
    first = jnp.asarray(x).reshape(-1)[jnp.argmax(~ok)] if ok.size else jnp.zeros(())
    _check(jnp.all(ok), f"{name}: {rule}{_in(where)}", first)


def check_finite(name: str, x, where: str | None = None) -> None:
    """A concrete ``x`` must be finite, else ``name: k of n values are NaN or infinite``.

    Traced values pass (:func:`require_finite` checks them under :func:`checked`).
    """
    if isinstance(x, jax.core.Tracer):
        return
    a = np.asarray(x)
    if not np.issubdtype(a.dtype, np.floating):
        return
    bad = int(np.sum(~np.isfinite(a)))
    if bad:
        raise ValueError(f"{name}: {bad} of {a.size} values are NaN or infinite{_in(where)}")


def require_finite(name: str, x, where: str | None = None) -> None:
    """Checked mode: ``x`` must be finite, else ``name: k of n values are NaN or infinite``."""
    if not checking():
        return
    x = jnp.asarray(x)
    bad = jnp.sum(~jnp.isfinite(x), dtype=jnp.int32)
    _check(bad == 0, f"{name}: {{}} of {x.size} values are NaN or infinite{_in(where)}", bad)


def require_indices(
    name: str, idx, size: int, what: str, where: str | None = None, *, allow_minus_one=False
) -> None:
    """Checked mode: integer ``idx`` must lie in ``[0, size)`` (or be -1 where allowed).

    The message names the first index out of range, e.g.
    ``faces: index 1532 out of range for 1200 vertices``.
    """
    if not checking():
        return
    idx = jnp.asarray(idx)
    ok = (idx >= 0) & (idx < size)
    if allow_minus_one:
        ok = ok | (idx == -1)
    require_values(name, ok, idx, f"index {{}} out of range for {size} {what}", where)


def _shown(value) -> str:
    """A scalar as NumPy prints it: a float32 0.05 as ``0.05``, not its float64 digits."""
    return str(np.asarray(value)[()])


def _in(where: str | None) -> str:
    return "" if where is None else f" (in {where})"
