"""Solve the registration energy for fixed correspondences.

With correspondences fixed, E = α·E_d + β·E_s + γ·E_m is a sparse linear least-squares problem in
the affines, separable over the three output coordinates (one shared matrix, three right-hand
sides). The normal-equation matrix is factorised at the first iteration of a stage; later
iterations of the stage, whose matrices differ only in the data weights, are solved by conjugate
gradients preconditioned with that factorisation, warm-started from the previous affines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from core.registration.operators import ResolutionLevel

REGULARIZATION = 1e-8  # ε‖T − T₀‖², relative to the mean diagonal: keeps tiny cases well-posed


@dataclass
class SystemTerms:
    """The energy terms of one solve, all in solver units.

    data_idx/data_w/data_targets : vertices with a data correspondence, weights, targets (k, 3).
    marker_idx/marker_targets : marked vertices and marker positions (km, 3).
    """

    alpha: float
    beta: float
    gamma: float
    data_idx: np.ndarray
    data_w: np.ndarray
    data_targets: np.ndarray
    marker_idx: np.ndarray
    marker_targets: np.ndarray


@dataclass
class SolveStats:
    factorized: bool
    cg_iterations: int


def factorize(M: sp.csc_matrix) -> spla.SuperLU:
    """Sparse LU of the symmetric positive-definite M with diagonal pivoting (no fill blow-up)."""
    return spla.splu(
        M, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True, "DiagPivotThresh": 0.0}
    )


class AffineSolver:
    """Reusable solver for one resolution level."""

    def __init__(self, level: ResolutionLevel, *, cg_tol: float = 1e-7, cg_maxiter: int = 60):
        self.level = level
        self.cg_tol = cg_tol
        self.cg_maxiter = cg_maxiter
        self._lu: spla.SuperLU | None = None

    def reset(self) -> None:
        """Forget the factorisation (call at the start of a stage)."""
        self._lu = None

    def assemble(self, t: SystemTerms, x_reg: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
        """Normal equations ``M x = b`` for the three coordinates: M (4n, 4n), b (4n, 3)."""
        lv = self.level
        M = t.beta * lv.smooth_kron
        b = np.zeros((4 * lv.n, 3))
        if t.alpha > 0 and len(t.data_idx):
            M = M + t.alpha * lv.gram(t.data_idx, t.data_w)
            b += t.alpha * lv.rhs(t.data_idx, t.data_w, t.data_targets)
        if t.gamma > 0 and len(t.marker_idx):
            ones = np.ones(len(t.marker_idx))
            M = M + t.gamma * lv.gram(t.marker_idx, ones)
            b += t.gamma * lv.rhs(t.marker_idx, ones, t.marker_targets)
        eps = REGULARIZATION * max(float(M.diagonal().mean()), 1e-12)
        M = (M + eps * sp.identity(4 * lv.n)).tocsc()
        b += eps * x_reg
        return M, b

    def solve(
        self, t: SystemTerms, x0: np.ndarray, x_reg: np.ndarray
    ) -> tuple[np.ndarray, SolveStats]:
        """Minimise the energy; x0 (4n, 3) warm start, x_reg (4n, 3) regulariser target."""
        M, b = self.assemble(t, x_reg)
        if self._lu is None:
            self._lu = spla.splu(
                M,
                permc_spec="MMD_AT_PLUS_A",
                options={"SymmetricMode": True, "DiagPivotThresh": 0.0},
            )
            return self._lu.solve(b), SolveStats(factorized=True, cg_iterations=0)
        lu = self._lu
        P = spla.LinearOperator(M.shape, matvec=lambda r: lu.solve(r), dtype=np.float64)
        out = np.empty_like(x0)
        total = 0
        for c in range(3):
            count = [0]

            def cb(_xk: np.ndarray, count: list[int] = count) -> None:
                count[0] += 1

            xc, info = spla.cg(
                M,
                b[:, c],
                x0=x0[:, c],
                rtol=self.cg_tol,
                maxiter=self.cg_maxiter,
                M=P,
                callback=cb,
            )
            total += count[0]
            if info != 0:  # did not converge: refactorise and solve directly
                self._lu = spla.splu(
                    M,
                    permc_spec="MMD_AT_PLUS_A",
                    options={"SymmetricMode": True, "DiagPivotThresh": 0.0},
                )
                return self._lu.solve(b), SolveStats(factorized=True, cg_iterations=total)
            out[:, c] = xc
        return out, SolveStats(factorized=False, cg_iterations=total)


def energies(level: ResolutionLevel, t: SystemTerms, x: np.ndarray) -> dict[str, float]:
    """Unweighted E_d, E_s, E_m and the weighted total for affines x (4n, 3), solver units."""
    A = x.reshape(level.n, 4, 3)
    h = np.hstack([level.V, np.ones((level.n, 1))])
    X = np.einsum("nk,nkc->nc", h, A)
    e_d = float(np.sum(t.data_w * np.sum((X[t.data_idx] - t.data_targets) ** 2, axis=1)))
    diff = A[level.edges[:, 0]] - A[level.edges[:, 1]]
    e_s = float(np.sum(diff**2))
    e_m = float(np.sum((X[t.marker_idx] - t.marker_targets) ** 2)) if len(t.marker_idx) else 0.0
    return {
        "data": e_d,
        "smoothness": e_s,
        "marker": e_m,
        "total": t.alpha * e_d + t.beta * e_s + t.gamma * e_m,
    }
