"""Eager calls of the public kernels run as one compiled program.

Called outside ``jit``, a JAX function runs op by op, and every operation is compiled for
its shapes the first time it meets them: a kernel of a hundred operations costs a hundred
small compiles (tens of milliseconds each) at every new mesh, map or image size, where one
program of the whole kernel compiles in a fraction of that and runs faster.
:func:`compiled_when_eager` gives a kernel that behaviour: an eager call runs the kernel
compiled (``jax.jit``, once per shapes and static arguments); a call with any traced argument
(under the caller's ``jit``, ``grad`` or ``vmap``) runs the kernel itself, so the caller's
program is the same as without the wrapper.  Argument checks that need concrete values stay
outside the wrapped kernel (in the public function that calls it), so eager calls keep their
errors.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, TypeVar, cast

import jax

F = TypeVar("F", bound=Callable[..., Any])

__all__ = ["compiled_when_eager"]


def compiled_when_eager(fn: F, static_argnames: Sequence[str] = ()) -> F:
    """``fn``, run as one ``jax.jit``-compiled program when no argument is traced.

    Args:
        fn: a pure function of arrays (pytrees allowed).
        static_argnames: its arguments that set shapes or choose code (Python ints, strings,
            settings); they must be hashable and are passed by keyword or position.

    Returns:
        A function with ``fn``'s signature, results and docstring (a decorator:
        ``@functools.partial(compiled_when_eager, static_argnames=(...))``).
    """
    jitted = jax.jit(fn, static_argnames=tuple(static_argnames))

    @functools.wraps(fn)
    def call(*args, **kwargs):
        leaves = jax.tree_util.tree_leaves((args, kwargs))
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return fn(*args, **kwargs)
        return jitted(*args, **kwargs)

    return cast(F, call)
