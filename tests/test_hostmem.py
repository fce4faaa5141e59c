"""keep_freed_memory: a freed large block is reused, not page-faulted in again."""

from __future__ import annotations

import subprocess
import sys

import pytest

# mallocs and touches a 64 MB block, frees it, does it again, and prints the page faults of
# the second; with ``keep`` it first calls jaxgfx.keep_freed_memory().
_PROBE = """
import ctypes, resource, sys
if sys.argv[1] == "keep":
    import jaxgfx
    assert jaxgfx.keep_freed_memory() is True
    assert jaxgfx.keep_freed_memory() is True  # again: no change, still True
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
n = 1 << 26  # 64 MB: over glibc's largest mmap threshold, as XLA:CPU's frame buffers
p = libc.malloc(n); ctypes.memset(p, 1, n); libc.free(p)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
p = libc.malloc(n); ctypes.memset(p, 1, n)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc settings: Linux")
def test_keep_freed_memory_reuses_a_freed_block():
    def faults(mode):
        out = subprocess.run(
            [sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True
        )
        return int(out.stdout.split()[-1])

    pages = (1 << 26) // 4096  # 16,384 pages of 4 KiB
    assert faults("default") > pages // 2  # fresh mmap pages: ~one fault per page
    assert faults("keep") < pages // 20  # the freed block again: (almost) none
