"""Host memory: let XLA:CPU's next call reuse what its last call freed.

XLA:CPU takes each call's buffers (temporaries and outputs) from ``malloc`` and frees
them when the call and its outputs are done.  glibc serves a large block (32 MB and up,
or a new heap of a thread's arena) with fresh ``mmap`` pages and hands them back to the
OS on ``free``, so every call touches its whole working set anew, one page fault per
4 KiB.  Kept for reuse, the next call's buffers come from pages already touched (see the
design notes, docs/design/engine.md).
"""

from __future__ import annotations

import ctypes
import sys

__all__ = ["keep_freed_memory"]

# mallopt parameters (glibc malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8
_KEEP = 2**31 - 1  # the largest trim threshold mallopt takes: never give memory back


def keep_freed_memory() -> bool:
    """Makes this process's ``malloc`` keep freed memory for reuse (glibc only).

    Sets glibc's ``M_MMAP_MAX`` to 0 (no block gets its own ``mmap``), ``M_TRIM_THRESHOLD``
    to its maximum (freed memory is not returned to the OS) and ``M_ARENA_MAX`` to 1 (one
    heap for every thread: a thread arena's heaps are ``mmap``-ed and trimmed however
    the other two are set).  XLA:CPU's buffers then come from memory already touched by
    an earlier call instead of fresh, page-faulting pages; see the module docstring for
    what it saves.  The ``jaxgfx`` command and the benchmarks in ``experiments/`` call it
    first thing.  The same from the environment, before Python starts:
    ``GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=2147483647:glibc.malloc.arena_max=1``.

    It is process-wide and lasts until the process ends; the process keeps the most
    memory it ever used.  Calling it again changes nothing.

    Returns:
        True if glibc took all three settings; False where there is no glibc ``mallopt``
        (other C libraries, other systems), in which case nothing changed.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:  # the C library this process already runs on (no search for it)
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    settings = ((_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, _KEEP), (_M_ARENA_MAX, 1))
    return all(mallopt(param, value) == 1 for param, value in settings)
