"""Thread policy for the numerical core."""

from __future__ import annotations

import functools
import itertools
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")
T = TypeVar("T")


def single_blas_thread(func: Callable[P, R]) -> Callable[P, R]:
    """Run ``func`` with one BLAS thread.

    The dense algebra of a fit is small (≤ 114² systems, 40k×60 products): multi-threaded BLAS
    gains little and spins idle on a busy machine (measured 7× slower at load 5 on 2 cores).
    A worker runs one fit per core instead.
    """

    @functools.wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return wrapper


def kd_workers() -> int:
    """Threads of a KD-tree query (``cKDTree.query(workers=)``): the fit's
    (:func:`fit_threads`), but one inside a trial running on :func:`map_in_threads` (its
    siblings hold the other CPUs). Where several fits share the CPUs (a worker's pool) that is one
    too: scipy starts and joins threads on every query, and at load ~7 on 2 cores
    ``workers=-1`` cost CPU (raw-0 8.37/8.07 s against 6.98/7.46 s with 1, raw-31 12.1/9.4
    against 8.9/9.5 s; identical results)."""
    return 1 if getattr(_trial, "running", False) else fit_threads()


_trial = threading.local()


#: Environment variable: how many threads a fit runs its independent trial fits on (the
#: markerless search's starts, the near-tied first fits, a round's two body-prior starts).
FIT_THREADS_ENV = "BODYSPACE_FIT_THREADS"


def share_cpus(processes: int | None) -> None:
    """Set :data:`FIT_THREADS_ENV` (unless it is set) for ``processes`` processes that each run
    fits at once (a Celery worker's pool, ``bench.realworld --jobs``): the CPUs shared out,
    at least one thread each; a setting already there is checked (:func:`fit_threads`). Call
    before the processes start (they inherit it)."""
    if os.environ.get(FIT_THREADS_ENV, "").strip():
        fit_threads()  # a wrong setting stops the start, not every fit
        return
    if processes:
        os.environ[FIT_THREADS_ENV] = str(max(1, available_cpus() // max(1, processes)))


def available_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover (not Linux)
        return os.cpu_count() or 1


def fit_threads() -> int:
    """Threads for a fit's independent trial fits: ``$BODYSPACE_FIT_THREADS``, else the CPUs
    this process may run on, at most 4 (a fit has a few trials at a time, up to ~12)."""
    raw = os.environ.get(FIT_THREADS_ENV, "").strip()
    if not raw:
        return max(1, min(4, available_cpus()))
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"{FIT_THREADS_ENV} must be a whole number of at least 1, got {raw!r}")
    return n


def map_in_threads(func: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """``[func(x) for x in items]``, run on :func:`fit_threads` threads (in order; the first
    exception is raised); in turn when called from such a thread. The trial fits' numpy, BLAS and
    KD-tree work releases the GIL."""
    n = min(fit_threads(), len(items))
    if n <= 1 or getattr(_trial, "running", False):  # no pools within a trial
        return [func(x) for x in items]

    def trial(x: T) -> R:
        _trial.running = True
        try:
            return func(x)
        finally:
            _trial.running = False

    with ThreadPoolExecutor(max_workers=n, thread_name_prefix="fit") as pool:
        return list(pool.map(trial, items))


#: Fewest rows per thread worth a block of their own (:func:`map_in_blocks`).
BLOCK_MIN_ROWS = 20_000


def map_in_blocks(func: Callable[[slice], R], n: int, max_rows: int | None = None) -> list[R]:
    """``func`` of consecutive slices covering ``range(n)`` (in order) on
    :func:`map_in_threads`: one per fit thread, none under :data:`BLOCK_MIN_ROWS` rows (one
    slice then), none over ``max_rows``. Per-row work of a large array side by side."""
    if n == 0:
        return []
    blocks = max(1, min(fit_threads(), n // BLOCK_MIN_ROWS))
    if max_rows:
        blocks = max(blocks, -(-n // max_rows))
    bounds = [n * i // blocks for i in range(blocks + 1)]
    return map_in_threads(func, [slice(a, b) for a, b in itertools.pairwise(bounds)])


def serialised(func: Callable[P, R] | None) -> Callable[P, R] | None:
    """``func`` behind a lock (None stays None): a progress callback that trial fits on
    :func:`map_in_threads` may call at once."""
    if func is None:
        return None
    lock = threading.Lock()
    inner = func

    @functools.wraps(inner)
    def locked(*args: P.args, **kwargs: P.kwargs) -> R:
        with lock:
            return inner(*args, **kwargs)

    return locked
