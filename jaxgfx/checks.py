"""Value checks that also hold under ``jax.jit``.

Every kernel checks shapes and types while tracing, and values where they are concrete
(eager calls).  :func:`checked` wraps a function so that the kernels it calls check the
values of traced arguments too while the program runs (``jax.experimental.checkify``),
raising ``ValueError`` naming the argument; without it no check is compiled.
Implementation: ``jaxgfx/_src/checks.py``.
"""

from __future__ import annotations

from jaxgfx._src.checks import checked as checked

__all__ = ["checked"]
