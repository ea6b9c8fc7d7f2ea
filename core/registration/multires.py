"""Low-resolution template for the first pass of the schedule, and the map back to full resolution.

The low-resolution template is a subset of template vertices ("seeds", chosen by farthest-point
sampling over the surface). Every full vertex belongs to the region of its geodesically nearest
seed; two seeds are joined by a smoothness edge when their regions touch. After the low-resolution
pass, each full vertex takes a blend of the affines of its own seed and the neighbouring seeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from core.registration.operators import unique_edges


@dataclass(frozen=True)
class Hierarchy:
    """A two-level template hierarchy.

    Attributes
    ----------
    seeds : (k,) full-template indices of the low-resolution vertices.
    region : (n,) index into ``seeds`` of each full vertex's region.
    low_edges : (E_low, 2) smoothness edges between seeds (indices into ``seeds``).
    upsample : (n, k) sparse row-stochastic matrix: full affines = upsample @ low affines.
    """

    seeds: np.ndarray
    region: np.ndarray
    low_edges: np.ndarray
    upsample: sp.csr_matrix


def farthest_point_seeds(V: np.ndarray, k: int, required: np.ndarray | None = None) -> np.ndarray:
    """Greedy farthest-point sampling of ``k`` vertex indices from V (n, 3) (Euclidean).

    ``required`` indices come first (e.g. landmark vertices, so markers act on seeds).
    """
    n = len(V)
    k = min(k, n)
    req = np.unique(np.asarray([0] if required is None or len(required) == 0 else required))
    seeds = np.empty(max(k, len(req)), dtype=np.int64)
    seeds[: len(req)] = req
    d = np.full(n, np.inf)
    for r in req:
        np.minimum(d, np.linalg.norm(V - V[r], axis=1), out=d)
    for s in range(len(req), k):
        nxt = int(np.argmax(d))
        seeds[s] = nxt
        np.minimum(d, np.linalg.norm(V - V[nxt], axis=1), out=d)
    return seeds


def build_hierarchy(
    V: np.ndarray, F: np.ndarray, n_low: int = 2500, required: np.ndarray | None = None
) -> Hierarchy:
    """Build the low-resolution level of a template mesh V (n, 3), F (m, 3).

    ``n_low`` seeds (``required`` vertices among them); the upsampling blends a full vertex's
    region seed and its neighbouring seeds with Gaussian weights of the Euclidean distance
    (σ = the mean seed spacing).
    """
    n = len(V)
    edges = unique_edges(F)
    lengths = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    G = sp.coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    seeds = farthest_point_seeds(V, n_low, required)
    _, _, src = dijkstra(G, directed=False, indices=seeds, min_only=True, return_predecessors=True)
    seed_pos = -np.ones(n, dtype=np.int64)
    seed_pos[seeds] = np.arange(len(seeds))
    region = seed_pos[src]
    if (region < 0).any():
        raise ValueError("template mesh is not connected: some vertices reach no seed")
    ra, rb = region[edges[:, 0]], region[edges[:, 1]]
    cross = ra != rb
    low_edges = np.unique(np.sort(np.stack([ra[cross], rb[cross]], axis=1), axis=1), axis=0)

    # Candidates for each full vertex: its own seed and the seeds adjacent to that seed.
    k = len(seeds)
    Adj = sp.coo_matrix(
        (
            np.ones(2 * len(low_edges)),
            (np.r_[low_edges[:, 0], low_edges[:, 1]], np.r_[low_edges[:, 1], low_edges[:, 0]]),
        ),
        shape=(k, k),
    ).tocsr()
    Adj = (Adj + sp.identity(k, format="csr")).tocsr()
    Adj.data[:] = 1.0
    spacing = float(
        np.mean(np.linalg.norm(V[seeds[low_edges[:, 0]]] - V[seeds[low_edges[:, 1]]], axis=1))
    )
    Cand = Adj[region]  # (n, k) pattern of candidate seeds per full vertex
    Cand = Cand.tocoo()
    d2 = np.sum((V[Cand.row] - V[seeds[Cand.col]]) ** 2, axis=1)
    w = np.exp(-d2 / (2 * (0.5 * spacing) ** 2)) + 1e-12
    W = sp.csr_matrix((w, (Cand.row, Cand.col)), shape=(n, k))
    W = sp.diags(1.0 / np.asarray(W.sum(axis=1)).ravel()) @ W
    return Hierarchy(seeds=seeds, region=region, low_edges=low_edges, upsample=W.tocsr())
