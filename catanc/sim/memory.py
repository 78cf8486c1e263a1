"""Keeping the memory a simulation frees, so the next arrays do not fault their pages in again.

A compiled run allocates tens of megabytes a simulated minute and frees most
of it: record arrays that double as they fill, draw rings, and the sorted
copies that become the results.  glibc serves blocks above a (dynamic)
threshold with fresh ``mmap``s and hands them back to the kernel when they
are freed, and trims the heap's free top the same way, so each new block is
zero pages that fault in one by one on first touch: ~3 us a 4 KiB page on
this VM, 4-10% of a warm 2-core nav2d run's wall time (benchmarks/RESULTS.md,
thirteenth pass).  Raising both thresholds keeps freed blocks in the heap
for reuse, for 4-9% more peak memory in a whole ``catanc simulate`` process.
Transparent huge pages were no help: fewer faults, but more time zeroing
and compacting.
"""

from __future__ import annotations

import ctypes
import functools
import sys

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 256 << 20
"""Blocks up to this size come from the heap (glibc's own default grows up to 32 MiB only as blocks are
freed): a 250 s nav2d run's largest arrays are ~16 MiB, an hour's a few hundred."""
TRIM_THRESHOLD_BYTES = 1 << 30
"""Free memory at the heap's top is given back to the kernel only beyond this."""


@functools.cache
def keep_freed_memory() -> bool:
    """Make this process's glibc ``malloc`` keep freed memory for reuse; whether it could (glibc on Linux only).

    Process-wide and once: the process's memory use stays near its peak until it exits, as a
    simulation's already does while it runs.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library Python itself runs on
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )
