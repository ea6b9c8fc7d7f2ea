"""Thread policy for the numerical core."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")


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


#: Threads of the fit's repeated KD-tree queries (``cKDTree.query(workers=)``): one, as for BLAS.
#: scipy starts and joins threads on every query; the fit makes ~150-200 of 2-13 k points each.
#: Measured (``service.cli.run_fit``, markerless, same process, load ~7 on 2 cores): raw-0 CPU
#: 8.37/8.07 s with workers=-1 vs 6.98/7.46 s with 1, wall 13.7/12.9 vs 10.9/11.4 s; raw-31 CPU
#: 12.1/9.4 vs 8.9/9.5 s, wall 20.0/15.7 vs 13.8/14.2 s; identical results.
KD_WORKERS = 1
