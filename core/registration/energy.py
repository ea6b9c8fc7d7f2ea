"""The registration energy's terms (Allen, Curless, Popović 2003, §3), each with its normal-equation
contribution and its value.

Unknowns: one 3×4 affine ``T_i`` per template vertex ``v_i`` (homogeneous ``ṽ_i = [v_i, 1]``),
stacked per output coordinate as ``x`` (4n, 3) (``core.registration.operators``). With the
correspondences fixed each term is quadratic, ``E = xᵀ M x − 2 bᵀ x + const`` per coordinate; the
solver (``core.registration.solver``) adds ``α M_d + β M_s + γ M_m`` and the right-hand sides.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from core.registration.operators import ResolutionLevel, homogeneous


def data_term(
    level: ResolutionLevel, idx: np.ndarray, w: np.ndarray, targets: np.ndarray
) -> tuple[sp.csr_matrix, np.ndarray]:
    """E_d = Σ_i w_i ‖T_i ṽ_i − c_i‖²: (M_d (4n, 4n), b_d (4n, 3)).

    ``idx`` (k,) vertices with a compatible closest point ``c_i`` (``targets`` (k, 3), solver
    units), ``w`` (k,) their confidence weights (``core.registration.correspondence``).
    """
    return level.gram(idx, w), level.rhs(idx, w, targets)


def marker_term(
    level: ResolutionLevel, idx: np.ndarray, w: np.ndarray, targets: np.ndarray
) -> tuple[sp.csr_matrix, np.ndarray]:
    """E_m = Σ_m w_m ‖T_m ṽ_m − p_m‖²: (M_m, b_m) for marked vertices ``idx`` (km,), markers
    ``targets`` (km, 3) and robust marker weights ``w`` (km,) (1 in the paper)."""
    return level.gram(idx, w), level.rhs(idx, w, targets)


def smoothness_term(level: ResolutionLevel) -> sp.csr_matrix:
    """E_s = Σ_(i,j)∈edges ‖T_i − T_j‖²_F: M_s = L ⊗ I₄ (L the edge graph's Laplacian), b_s = 0."""
    return level.smooth_kron


def data_energy(X: np.ndarray, idx: np.ndarray, w: np.ndarray, targets: np.ndarray) -> float:
    """Value of E_d for deformed vertices X (n, 3)."""
    return float(np.sum(w * np.sum((X[idx] - targets) ** 2, axis=1)))


def marker_energy(X: np.ndarray, idx: np.ndarray, w: np.ndarray, targets: np.ndarray) -> float:
    """Value of E_m for deformed vertices X (n, 3)."""
    if len(idx) == 0:
        return 0.0
    return float(np.sum(w * np.sum((X[idx] - targets) ** 2, axis=1)))


def smoothness_energy(A: np.ndarray, edges: np.ndarray) -> float:
    """Value of E_s for affines A (n, 4, 3) (solver layout) over ``edges`` (E, 2)."""
    diff = A[edges[:, 0]] - A[edges[:, 1]]
    return float(np.sum(diff**2))


def deformed(level: ResolutionLevel, x: np.ndarray) -> np.ndarray:
    """Deformed vertices ``T_i ṽ_i`` (n, 3) for unknowns x (4n, 3)."""
    return np.einsum("nk,nkc->nc", homogeneous(level.V), x.reshape(level.n, 4, 3))
