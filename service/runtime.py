"""Process-level settings: malloc tuning of an API process (applied once when the app starts),
and helper processes that exit with their parent (:func:`die_with_parent`)."""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import threading
import time

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


#: ``prctl`` option: the signal a process receives when its parent dies (linux/prctl.h).
_PR_SET_PDEATHSIG = 1


def die_with_parent(
    parent_pid: int, sig: int = signal.SIGKILL, *, pdeathsig: bool = True, poll_s: float = 0.5
) -> bool:
    """Receive ``sig`` when the parent process ``parent_pid`` dies (a helper process of an API
    or worker process: a fit pool process, an API process of ``serve --workers N``).

    Linux's parent-death signal (``prctl(PR_SET_PDEATHSIG)``) acts at once, even in the middle
    of a C call, so a killed server's fit stops before it stores anything. Caveat: the kernel
    sends it when the *thread* that started this process exits, so the parent must start its
    helpers from a thread that lives as long as it does (``pdeathsig=False`` where it cannot
    promise that). A watchdog thread checking ``getppid()`` every ``poll_s`` seconds is the
    fallback (other systems; a parent that died before the signal was armed). Returns whether
    the parent-death signal is armed.
    """
    armed = False
    if pdeathsig and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os.kill(os.getpid(), sig)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        log.warning("parent process %d is gone: exiting", parent_pid)
        os.kill(os.getpid(), sig)

    threading.Thread(target=watch, daemon=True, name="parent-watchdog").start()
    return armed
