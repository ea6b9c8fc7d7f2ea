"""Small vectorised mesh helpers shared by the readers, writers and scan preparation."""

from __future__ import annotations

import numpy as np


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted face normals (cross products, length = 2 * area), shape (m, 3)."""
    a = V[F[:, 0]]
    b = V[F[:, 1]] - a
    c = V[F[:, 2]] - a
    out = np.empty_like(b)
    out[:, 0] = b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]
    out[:, 1] = b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2]
    out[:, 2] = b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]
    return out


def vertex_normals(
    V: np.ndarray,
    F: np.ndarray | None,
    fallback=(0.0, 1.0, 0.0),
    face_normals: np.ndarray | None = None,
) -> np.ndarray:
    """Area-weighted unit vertex normals, (n, 3) float64.

    Vertices with no incident area get ``fallback``.
    """
    V = np.asarray(V, dtype=np.float64)
    n = len(V)
    N = np.zeros((n, 3))
    if F is not None and len(F):
        fn = _face_normals(V, F) if face_normals is None else face_normals
        idx = F.ravel()
        for c in range(3):
            N[:, c] = np.bincount(idx, weights=np.repeat(fn[:, c], 3), minlength=n)
    return normalize(N, fallback)


def normalize(N: np.ndarray, fallback=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Rows scaled to unit length; zero or non-finite rows become ``fallback``."""
    N = np.asarray(N, dtype=np.float64)
    L = np.linalg.norm(N, axis=1)
    ok = np.isfinite(L) & (L > 1e-30)
    out = np.empty_like(N)
    out[ok] = N[ok] / L[ok, None]
    out[~ok] = np.asarray(fallback, dtype=np.float64)
    return out


def edge_use_counts(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (e, 2) int64 (sorted endpoints) and how many triangles use each."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).astype(np.int64)
    E.sort(axis=1)
    key = E[:, 0] * n + E[:, 1]
    uk, counts = np.unique(key, return_counts=True)
    return np.stack([uk // n, uk % n], axis=1), counts


_face_normals = face_normals
