"""How a vgr process's C allocator keeps the memory of large messages it has freed.

A stage that handles point clouds allocates and frees buffers of megabytes for every message (the
payload it builds, its encoding, the bytes copied out of a received sample). glibc's ``malloc``
(``man 3 mallopt``) serves a buffer above its *mmap threshold* with a fresh ``mmap`` and, for a
buffer from the heap, gives the top of the heap back to the kernel once more than its *trim
threshold* lies free there. Both thresholds move on their own: the mmap threshold rises to the
size of the largest mapped block freed so far, the trim threshold to twice that. With two 1.2 MB
buffers freed per message (a payload and its encoding), the freed top of the heap reaches the trim
threshold, the heap shrinks, and the next message touches ~600 new pages: measured across two vgr
processes on a 2-vCPU VM, one-way latency of 1.2 MB messages was 1400-1950 us in processes where
that happened and 480-660 us in the others, process by process at random
(benchmarks/engine_overhead.py, the 1.2 MB row).

:func:`keep_freed_memory` fixes both thresholds (:data:`MMAP_THRESHOLD`, :data:`TRIM_THRESHOLD`), so
buffers up to 32 MiB come from the heap and up to 128 MiB of freed heap is kept for the next
message. The cost is resident memory that a process with a past peak does not give back (at most
the trim threshold above what it uses). It is called once by engine.run.runner.Runner for a run that
owns its process (``vgr run``; ``freeze_gc``), never by a library user's process on its own. On a C
library without ``mallopt`` (musl, macOS) it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # glibc's <malloc.h>
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 * 1024 * 1024  # glibc's upper bound for this setting on 64-bit systems
TRIM_THRESHOLD = 128 * 1024 * 1024

_done: bool | None = None


def keep_freed_memory() -> bool:
    """Fix glibc's mmap and trim thresholds for this process (see the module docstring); True when
    the C library took both settings. Idempotent."""
    global _done
    if _done is None:
        _done = _set_thresholds()
    return _done


def _set_thresholds() -> bool:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
