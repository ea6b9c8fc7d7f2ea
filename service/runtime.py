"""Process-level tuning of an API process, applied once when the app starts (lifespan)."""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger("bodyspace.service")

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: Blocks up to this size come from the heap, not from a fresh mmap() each time.
MMAP_THRESHOLD = 16 * 1024 * 1024
#: Free memory at the top of the heap kept for reuse instead of returned to the OS.
TRIM_THRESHOLD = 128 * 1024 * 1024


def tune_malloc() -> bool:
    """Serve the large short-lived buffers of a request from the heap (glibc; else a no-op).

    A GLB synthesis allocates ~2 MB of arrays of 0.1–0.6 MB each. glibc gives blocks above its
    mmap threshold (128 kB at start; raised only after such a block has been freed) fresh
    ``mmap()`` pages, and every page then faults on first touch: measured 583 page faults and
    ~1.7 ms of CPU per request in this VM (half the request), or none, depending on the order
    of the process's first requests. Fixed thresholds make it deterministic: blocks up to
    :data:`MMAP_THRESHOLD` come from the heap, and up to :data:`TRIM_THRESHOLD` of free heap is
    kept. Returns whether the thresholds were set.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
    if not ok:
        log.info("malloc thresholds not set (not glibc?)")
    return ok
