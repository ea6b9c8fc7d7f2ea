"""Solve the registration energy for fixed correspondences.

With correspondences fixed, E = α·E_d + β·E_s + γ·E_m is a sparse linear least-squares problem in
the affines, separable over the three output coordinates (one shared matrix, three right-hand
sides). The normal-equation matrix is factorised once and reused across correspondence updates
while the data weights stay the same (see :class:`AffineSolver`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from core.registration.energy import (
    data_energy,
    data_term,
    deformed,
    marker_energy,
    marker_term,
    smoothness_energy,
    smoothness_term,
)
from core.registration.operators import ResolutionLevel, homogeneous

REGULARIZATION = 1e-8  # ε‖T − T₀‖², relative to the mean diagonal: keeps tiny cases well-posed


@dataclass
class SystemTerms:
    """The energy terms of one solve, all in solver units.

    data_idx/data_w/data_targets : vertices with a data correspondence, weights, targets (k, 3).
    marker_idx/marker_targets : marked vertices and marker positions (km, 3).
    marker_w : (km,) per-marker weights (robust weights of the body prior); default 1.
    """

    alpha: float
    beta: float
    gamma: float
    data_idx: np.ndarray
    data_w: np.ndarray
    data_targets: np.ndarray
    marker_idx: np.ndarray
    marker_targets: np.ndarray
    marker_w: np.ndarray | None = None

    @property
    def marker_weights(self) -> np.ndarray:
        if self.marker_w is None:
            return np.ones(len(self.marker_idx))
        return np.asarray(self.marker_w, dtype=np.float64)


@dataclass
class SolveStats:
    factorized: bool
    changed_fraction: float  # share of vertices whose data weight changed since the factorisation


class Factorization:
    """Sparse LU of a symmetric positive-definite M (m, m) with diagonal pivoting, its unknowns
    taken in a given fill-reducing ``order`` (m,) (SuperLU's own minimum-degree ordering of M
    when None); :meth:`solve` answers in M's own order."""

    def __init__(self, M: sp.spmatrix, order: np.ndarray | None = None) -> None:
        opts = {"SymmetricMode": True, "DiagPivotThresh": 0.0}
        self.order = order
        if order is None:
            self.lu = spla.splu(sp.csc_matrix(M), permc_spec="MMD_AT_PLUS_A", options=opts)
        else:
            Mp = sp.csr_matrix(M)[order][:, order].tocsc()
            self.lu = spla.splu(Mp, permc_spec="NATURAL", options=opts)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """M⁻¹ b for b (m,) or (m, r)."""
        if self.order is None:
            return self.lu.solve(b)
        x = np.empty_like(b, dtype=np.float64)
        x[self.order] = self.lu.solve(np.ascontiguousarray(b[self.order]))
        return x


def factorize(M: sp.spmatrix, order: np.ndarray | None = None) -> Factorization:
    """:class:`Factorization` of the symmetric positive-definite M (no fill blow-up)."""
    return Factorization(M, order)


class AffineSolver:
    """Reusable solver for one resolution level.

    The factorisation is reused while the data weights stay (almost) the same: only the targets
    change from one correspondence update to the next. When fewer than ``refactor_fraction`` of
    the vertices changed weight, vertices that lost their correspondence keep their factorised
    weight with their current position as target (a proximal step), and vertices that gained one
    wait for the next factorisation. At convergence (weights stable) the solution minimises the
    paper's energy exactly.
    """

    def __init__(self, level: ResolutionLevel, *, refactor_fraction: float = 0.03) -> None:
        self.level = level
        self.refactor_fraction = refactor_fraction
        self._lu: Factorization | None = None
        self._w: np.ndarray | None = None  # per-vertex data weights of the factorisation
        self._key: tuple[float, float, float] | None = None

    def reset(self) -> None:
        """Forget the factorisation (call at the start of a stage)."""
        self._lu = None
        self._w = None
        self._key = None

    def _matrix(self, t: SystemTerms, w: np.ndarray) -> tuple[sp.csr_matrix, float]:
        lv = self.level
        M = t.beta * smoothness_term(lv)
        idx = np.flatnonzero(w > 0)
        if t.alpha > 0 and len(idx):
            M = M + t.alpha * lv.gram(idx, w[idx])  # M_d of data_term
        if t.gamma > 0 and len(t.marker_idx):
            M = M + t.gamma * lv.gram(t.marker_idx, t.marker_weights)  # M_m of marker_term
        eps = REGULARIZATION * max(float(M.diagonal().mean()), 1e-12)
        return (M + eps * sp.identity(4 * lv.n)).tocsr(), eps

    def solve(
        self, t: SystemTerms, x0: np.ndarray, x_reg: np.ndarray
    ) -> tuple[np.ndarray, SolveStats]:
        """Minimise the energy for fixed correspondences; x0 (4n, 3) the current affines,
        x_reg (4n, 3) the regulariser's target."""
        lv = self.level
        w_new = np.zeros(lv.n)
        w_new[t.data_idx] = t.data_w if t.alpha > 0 else 0.0
        targets = np.zeros((lv.n, 3))
        targets[t.data_idx] = t.data_targets
        key = (t.alpha, t.beta, t.gamma)
        changed = 1.0
        if self._w is not None and self._key == key:
            changed = float(np.mean(np.abs(w_new - self._w) > 0.05))
        factorized = False
        if self._lu is None or changed > self.refactor_fraction:
            M, self._eps = self._matrix(t, w_new)
            self._lu = factorize(M, lv.fill_reducing_order)
            self._w, self._key = w_new, key
            factorized = True
        w = self._w
        assert w is not None
        # vertices factorised with a weight but without a match now: stay where they are
        lost = (w > 0) & (w_new <= 0)
        if lost.any():
            X = np.einsum("nk,nkc->nc", homogeneous(lv.V[lost]), x0.reshape(lv.n, 4, 3)[lost])
            targets[lost] = X
        b = self._eps * x_reg
        idx = np.flatnonzero(w > 0)
        if t.alpha > 0 and len(idx):
            b = b + t.alpha * data_term(lv, idx, w[idx], targets[idx])[1]
        if t.gamma > 0 and len(t.marker_idx):
            b = b + t.gamma * marker_term(lv, t.marker_idx, t.marker_weights, t.marker_targets)[1]
        return self._lu.solve(b), SolveStats(factorized=factorized, changed_fraction=changed)


def energies(level: ResolutionLevel, t: SystemTerms, x: np.ndarray) -> dict[str, float]:
    """Unweighted E_d, E_s, E_m and the weighted total for affines x (4n, 3), solver units
    (``core.registration.energy``)."""
    X = deformed(level, x)
    e_d = data_energy(X, t.data_idx, t.data_w, t.data_targets)
    e_s = smoothness_energy(x.reshape(level.n, 4, 3), level.edges)
    e_m = marker_energy(X, t.marker_idx, t.marker_weights, t.marker_targets)
    return {
        "data": e_d,
        "smoothness": e_s,
        "marker": e_m,
        "total": t.alpha * e_d + t.beta * e_s + t.gamma * e_m,
    }
