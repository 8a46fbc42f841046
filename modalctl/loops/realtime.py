"""A process set up for real-time loops: memory, once taken, kept (the PREEMPT_RT recipe).

The first write to a page the process has not touched yet costs a page fault (about 4 us per
4 KiB page on this project's machines, 1 ms a megabyte). glibc hands out every allocation
above 128 KiB as fresh pages from the system (mmap) and gives them back when freed, so each
shot that makes its records, the truth's answer and their temporaries anew faults on every page
of them again: a third of a 10 kHz HIL shot's wall time. :func:`keep_memory` does what the
real-time Linux recipe does before a loop starts (``mallopt(M_MMAP_MAX, 0)``,
``mallopt(M_TRIM_THRESHOLD, -1)``): large allocations come from the heap, and the heap is
never given back, so after the first shot the pages are the process's own and are reused.
The price: the process keeps its peak memory until it ends. Locking it in RAM (``mlockall``)
needs privileges a user seldom has and is left to the system.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

__all__ = ["keep_memory"]

M_TRIM_THRESHOLD = -1  # glibc's malloc.h
M_MMAP_MAX = -4


def keep_memory() -> bool:
    """Make the C allocator keep freed memory for reuse (process-wide, for the rest of its life).

    Returns
    -------
    bool
        True when it was set; False where the C library is not glibc (nothing is changed).
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    return bool(libc.mallopt(M_MMAP_MAX, 0)) and bool(libc.mallopt(M_TRIM_THRESHOLD, -1))
