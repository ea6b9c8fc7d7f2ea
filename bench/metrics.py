"""Accuracy metrics for registration benchmarks (pure numpy / scipy; inputs in metres).

All functions take positions in metres and return plain floats in **millimetres** (or boolean
masks), ready for printing and JSON. ``fit`` and ``truth`` are (n, 3) arrays in template vertex
order, so row *i* of both is the same anatomical point.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

MM = 1000.0


def _check_pair(fit: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fit = np.asarray(fit, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if fit.ndim != 2 or fit.shape[1] != 3 or fit.shape != truth.shape:
        raise ValueError(
            f"fit and truth must both be (n, 3) with the same n; got {fit.shape} and {truth.shape}"
        )
    return fit, truth


def summarize_mm(d: np.ndarray) -> dict[str, float]:
    """Mean, 95th percentile and maximum of distances ``d`` (n,) in metres, as millimetres.

    An empty ``d`` gives NaNs (e.g. a case without holes).
    """
    d = np.asarray(d, dtype=np.float64).ravel()
    if d.size == 0:
        return {"mean": float("nan"), "p95": float("nan"), "max": float("nan"), "n": 0}
    return {
        "mean": float(d.mean() * MM),
        "p95": float(np.percentile(d, 95) * MM),
        "max": float(d.max() * MM),
        "n": int(d.size),
    }


def vertex_errors(fit: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-vertex correspondence error ‖fit_i − truth_i‖ (n,), metres.

    Parameters
    ----------
    fit, truth : (n, 3) float, metres, same vertex order.
    """
    fit, truth = _check_pair(fit, truth)
    return np.linalg.norm(fit - truth, axis=1)


def correspondence_error(
    fit: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None
) -> dict[str, float]:
    """Correspondence error to the truth over all vertices, or those where ``mask`` is True.

    Parameters
    ----------
    fit, truth : (n, 3) float, metres, same vertex order.
    mask : (n,) bool or None; restricts the statistics to these vertices.

    Returns
    -------
    dict with ``mean``, ``p95``, ``max`` (millimetres) and ``n`` (vertices counted).
    """
    d = vertex_errors(fit, truth)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != d.shape:
            raise ValueError(f"mask must have shape {d.shape}; got {mask.shape}")
        d = d[mask]
    return summarize_mm(d)


def hole_mask(truth: np.ndarray, scan_points: np.ndarray, radius: float = 0.005) -> np.ndarray:
    """Template vertices "in holes": no scan point within ``radius`` of the true position.

    Method-independent (depends only on the truth and the scan).

    Parameters
    ----------
    truth : (n, 3) float, metres, true template vertex positions.
    scan_points : (m, 3) float, metres, scan points (same frame).
    radius : metres (default 5 mm).

    Returns
    -------
    (n,) bool, True where the nearest scan point is farther than ``radius``.
    """
    truth = np.asarray(truth, dtype=np.float64)
    scan_points = np.asarray(scan_points, dtype=np.float64)
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"truth must be (n, 3); got {truth.shape}")
    if scan_points.ndim != 2 or scan_points.shape[1] != 3 or len(scan_points) == 0:
        raise ValueError(f"scan_points must be a non-empty (m, 3) array; got {scan_points.shape}")
    if radius <= 0:
        raise ValueError(f"radius must be positive; got {radius}")
    d, _ = cKDTree(scan_points).query(truth, distance_upper_bound=radius)
    return ~np.isfinite(d)


def landmark_error(fit: np.ndarray, truth: np.ndarray, landmark_vertices: np.ndarray) -> float:
    """Mean ‖fit − truth‖ over the landmark vertices, millimetres.

    Parameters
    ----------
    fit, truth : (n, 3) float, metres, same vertex order.
    landmark_vertices : (k,) int vertex indices (the template's landmarks).
    """
    idx = np.asarray(landmark_vertices, dtype=np.int64).ravel()
    if idx.size == 0:
        raise ValueError("landmark_vertices is empty")
    d = vertex_errors(fit, truth)
    if idx.min() < 0 or idx.max() >= len(d):
        raise ValueError(f"landmark vertex indices must lie in [0, {len(d)})")
    return float(d[idx].mean() * MM)


def surface_distance_stats(d: np.ndarray) -> dict[str, float]:
    """Mean and 95th percentile of point-to-surface distances ``d`` (metres), millimetres.

    Use with exact distances from the scan points to the fitted mesh
    (``core.geometry.MeshDistance(fit_V, F).distances(scan.V)``).
    """
    s = summarize_mm(d)
    return {"mean": s["mean"], "p95": s["p95"], "n": s["n"]}
