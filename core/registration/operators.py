"""Template operators for the affine-per-vertex registration, built once and cached.

Unknowns: one 3×4 affine ``T_i`` per template vertex. The energy separates over the three output
coordinates, so each coordinate ``c`` solves for ``x_c`` (4n,), where ``x_c[4i:4i+4]`` is row ``c``
of ``T_i``; all three share one system matrix.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from core.geometry import vertex_normals

__all__ = ["vertex_normals"]  # re-exported: the registration's callers import it from here


def unique_edges(F: np.ndarray) -> np.ndarray:
    """Unique undirected edges of a triangle mesh: (E, 2) int64, each row sorted."""
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).astype(np.int64)
    e.sort(axis=1)
    return np.unique(e, axis=0)


def graph_laplacian(edges: np.ndarray, n: int) -> sp.csr_matrix:
    """Combinatorial Laplacian (n, n) of an undirected edge list: ``Σ_edges (x_i - x_j)²``."""
    i, j = edges[:, 0], edges[:, 1]
    ones = np.ones(len(edges))
    A = sp.coo_matrix((np.r_[ones, ones], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    deg = np.asarray(A.sum(axis=1)).ravel()
    return (sp.diags(deg) - A).tocsr()


def homogeneous(V: np.ndarray) -> np.ndarray:
    """(n, 4) rows ``[x, y, z, 1]``."""
    return np.hstack([V, np.ones((len(V), 1))])


def apply_affines(A: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Apply per-vertex affines A (n, 3, 4) to V (n, 3): ``T_i v_i`` (n, 3)."""
    return np.einsum("nij,nj->ni", A, homogeneous(V))


@dataclass
class ResolutionLevel:
    """One resolution of the template, with the operators a solve needs.

    Attributes
    ----------
    V : (n, 3) template vertices at this level, solver units.
    edges : (E, 2) smoothness edges.
    smooth_kron : (4n, 4n) ``L ⊗ I4``: the smoothness term's matrix.
    data_mask : (n,) bool, False where the template is known to scan badly (w_i = 0).
    vertex_ids : (n,) indices of these vertices in the full template (identity at full res).
    """

    V: np.ndarray
    edges: np.ndarray
    smooth_kron: sp.csr_matrix
    data_mask: np.ndarray
    vertex_ids: np.ndarray

    @property
    def n(self) -> int:
        return len(self.V)

    @cached_property
    def fill_reducing_order(self) -> np.ndarray:
        """(4n,) int64 permutation of the unknowns for the sparse factorisation: SuperLU's
        minimum-degree ordering of the vertex graph (edges + diagonal), each vertex's four
        unknowns kept together. Depends on the graph only, so it is computed once per level:
        on the full template (53,520 unknowns) ordering + factorisation took 0.03 + 0.31 s CPU
        with 8.2 M factor entries, against 0.48-0.64 s and 9.0 M for SuperLU's own ordering of
        the whole matrix on every factorisation (``core.registration.solver.factorize``)."""
        n = self.n
        i, j = self.edges[:, 0], self.edges[:, 1]
        G = sp.coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsc()
        G.data[:] = 1.0
        G = G + sp.identity(n, format="csc") * 10.0  # the diagonal, dominant: no pivoting
        lu = spla.splu(
            G, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True, "DiagPivotThresh": 0.0}
        )
        order = np.argsort(lu.perm_c)
        return (4 * order[:, None] + np.arange(4)).ravel().astype(np.int64)

    def selector(self, idx: np.ndarray, weights: np.ndarray | None = None) -> sp.csr_matrix:
        """(k, 4n) matrix mapping ``x_c`` to ``(T_i v_i)_c`` for vertices ``idx``.

        ``weights`` (k,) scale the rows (use sqrt of term weights).
        """
        idx = np.asarray(idx, dtype=np.int64)
        k = len(idx)
        vals = homogeneous(self.V[idx])
        if weights is not None:
            vals = vals * weights[:, None]
        rows = np.repeat(np.arange(k), 4)
        cols = (4 * idx[:, None] + np.arange(4)).ravel()
        return sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(k, 4 * self.n))

    def gram(self, idx: np.ndarray, weights: np.ndarray) -> sp.csr_matrix:
        """Block-diagonal (4n, 4n) ``Σ_k w_k ṽ ṽᵀ`` placed at vertices ``idx``."""
        idx = np.asarray(idx, dtype=np.int64)
        h = homogeneous(self.V[idx])
        blocks = weights[:, None, None] * h[:, :, None] * h[:, None, :]
        rows = (4 * idx[:, None, None] + np.arange(4)[None, :, None]).repeat(4, axis=2)
        cols = (4 * idx[:, None, None] + np.arange(4)[None, None, :]).repeat(4, axis=1)
        return sp.csr_matrix(
            (blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(4 * self.n, 4 * self.n)
        )

    def rhs(self, idx: np.ndarray, weights: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """(4n, 3) right-hand side ``Σ_k w_k ṽ_k p_kᵀ`` at vertices ``idx``."""
        idx = np.asarray(idx, dtype=np.int64)
        h = homogeneous(self.V[idx]) * weights[:, None]
        prod = (h[:, :, None] * targets[:, None, :]).reshape(len(idx), 12)
        out = np.empty((self.n, 12))
        for k in range(12):
            out[:, k] = np.bincount(idx, prod[:, k], minlength=self.n)
        return out.reshape(4 * self.n, 3)


def make_level(
    V: np.ndarray, edges: np.ndarray, data_mask: np.ndarray, vertex_ids: np.ndarray
) -> ResolutionLevel:
    """Build a :class:`ResolutionLevel` from vertices (solver units) and smoothness edges."""
    L = graph_laplacian(edges, len(V))
    Lk = sp.kron(L, sp.identity(4, format="csr"), format="csr")
    return ResolutionLevel(
        V=np.ascontiguousarray(V, dtype=np.float64),
        edges=edges,
        smooth_kron=Lk,
        data_mask=np.asarray(data_mask, dtype=bool),
        vertex_ids=np.asarray(vertex_ids, dtype=np.int64),
    )
