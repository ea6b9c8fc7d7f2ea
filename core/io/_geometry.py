"""Small vectorised mesh helpers shared by the readers, writers and scan preparation."""

from __future__ import annotations

import numpy as np

from core.geometry import face_normals, normalize
from core.geometry import vertex_normals as _vertex_normals

__all__ = ["edge_use_counts", "face_normals", "normalize", "vertex_normals"]


def vertex_normals(
    V: np.ndarray,
    F: np.ndarray | None,
    fallback=(0.0, 1.0, 0.0),
    face_normals: np.ndarray | None = None,
) -> np.ndarray:
    """Area-weighted unit vertex normals, (n, 3) float64 (:func:`core.geometry.vertex_normals`);
    vertices with no incident area get ``fallback`` (default +Y)."""
    return _vertex_normals(V, F, fallback=fallback, face_normals=face_normals)


def edge_use_counts(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (e, 2) int64 (sorted endpoints) and how many triangles use each."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).astype(np.int64)
    E.sort(axis=1)
    key = E[:, 0] * n + E[:, 1]
    uk, counts = np.unique(key, return_counts=True)
    return np.stack([uk // n, uk % n], axis=1), counts
