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
