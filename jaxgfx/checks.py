"""Value checks that also hold under ``jax.jit``.

Every kernel checks shapes and types while tracing, and values where they are concrete
(eager calls).  :func:`checked` wraps a function so that the kernels it calls check the
values of traced arguments too while the program runs (each check a host callback, as
``equinox.error_if`` does), raising ``ValueError`` naming the argument; without it no
check is compiled.
"""

from __future__ import annotations

from jaxgfx._src.checks import checked as checked

__all__ = ["checked"]
