"""Freed memory kept for reuse: glibc's ``malloc`` hands a block of more than 32 MB straight back to the system
when it is freed, so the next one of that size is mapped again and zeroed page by page by the kernel. At the
paper's sizes every stage-1 iteration and every FisherRF probe pass allocates a fresh 42 MB gradient of the hash
table (2^19 rows x 16 levels x 2 features x 4 bytes): without reuse its zeroing costs about 25 ms, with reuse about
4 ms. ``keep_freed_memory`` raises glibc's thresholds (``mallopt``) so that such blocks come from the heap and stay
there once freed. Values are unchanged: only where the bytes live changes."""

import ctypes
import sys

MMAP_THRESHOLD = 1 << 30  # bytes: blocks below this come from the heap (glibc's M_MMAP_THRESHOLD)
TRIM_THRESHOLD = 1 << 31  # bytes: free memory at the heap's top kept up to this (glibc's M_TRIM_THRESHOLD)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (malloc.h)


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds for this process; False where there is no glibc (another C library
    or system), which then allocates as it always does."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
