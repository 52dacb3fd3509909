"""Allocator settings for node processes: keep freed big buffers for the next message.

Every published message is encoded into a fresh payload buffer, and every received one lands in a
fresh buffer of libzmq's. By default glibc's malloc serves requests of 128 KiB or more with mmap, or
trims the top of the heap when they are freed, so the next 1 MB payload faults its 256 pages in
again: measured at about 4 us a page on the 2-core development VM, ~1 ms per megabyte, which halves
the bus throughput for 1 MB arrays (`palpate bench bus`, docs/benchmarks.md). Raising the mmap and
trim thresholds keeps freed buffers in the heap, where the next message reuses them. The price is
that a process keeps up to `trim_threshold_bytes` of freed memory instead of returning it at once.
"""

from __future__ import annotations

import ctypes
import ctypes.util

# glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: Buffers from this size on are still mapped (and returned) one by one.
DEFAULT_MMAP_THRESHOLD_BYTES = 32 << 20
DEFAULT_TRIM_THRESHOLD_BYTES = 128 << 20


def keep_freed_buffers(
    mmap_threshold_bytes: int = DEFAULT_MMAP_THRESHOLD_BYTES,
    trim_threshold_bytes: int = DEFAULT_TRIM_THRESHOLD_BYTES,
) -> bool:
    """Tune glibc's malloc for this process so that big message buffers are reused.

    Returns False (and changes nothing) where the C library is not glibc or refuses the values.
    """
    name = ctypes.util.find_library("c") or "libc.so.6"
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, mmap_threshold_bytes) == 1
    return mallopt(_M_TRIM_THRESHOLD, trim_threshold_bytes) == 1 and ok
