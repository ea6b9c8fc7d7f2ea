"""The machine's speed, for CPU-time bounds that hold on a slower or busier machine."""

from __future__ import annotations

import time

import numpy as np


def reference_cpu(repeats: int = 5) -> float:
    """Least CPU seconds of ``repeats`` runs of a fixed workload of a fit's kind (a KD-tree over
    150 k points and its 4-nearest queries; dense normal equations, 400 unknowns).

    Timed tests bound their CPU time as a multiple of this instead of in seconds: on the same
    machine and code, a fit's CPU time varied ~2x between hours (2026-11-29) and this workload
    with it. Read 0.18-0.20 s on the 2-core development machine when idle, 0.37-0.52 s when slow.
    """
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    P = rng.random((150_000, 3))
    A = rng.random((2000, 400))
    best = float("inf")
    for _ in range(repeats):
        t = time.process_time()
        cKDTree(P, leafsize=32).query(P[::2], k=4)
        for _ in range(3):
            np.linalg.solve(A.T @ A + np.eye(400), A.T @ A[:, 0])
        best = min(best, time.process_time() - t)
    return best
