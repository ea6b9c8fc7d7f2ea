"""Initial alignment: a similarity transform (scale, rotation, translation) from markers.

Maps template landmark vertices onto the measured markers, so a scan in any frame and unit
(already converted to metres by the reader) starts close. Markers that disagree with the rest are
reported and left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.errors import MarkerError
from core.geometry import Similarity, umeyama

__all__ = ["MarkerAlignment", "Similarity", "align_markers", "umeyama"]


@dataclass
class MarkerAlignment:
    """Result of :func:`align_markers`."""

    similarity: Similarity
    used: list[str]
    dropped: list[str]
    residuals: dict[str, float]  # metres, per used marker after alignment
    warnings: list[str] = field(default_factory=list)


def align_markers(
    template_landmarks: dict[str, np.ndarray],
    markers: dict[str, np.ndarray],
    *,
    min_markers: int = 3,
    outlier_distance: float = 0.45,
    warn_distance: float = 0.30,
) -> MarkerAlignment:
    """Similarity from template landmark positions to markers (both name -> (3,), metres).

    Markers whose residual exceeds ``outlier_distance`` after a robust fit are dropped with a
    warning; residuals above ``warn_distance`` are warned about (pose differences from the
    template, e.g. raised arms, legitimately cause some).

    Raises
    ------
    MarkerError
        Fewer than ``min_markers`` usable markers, or the markers are degenerate (collinear).
    """
    names = [k for k in markers if k in template_landmarks]
    if len(names) < min_markers:
        raise MarkerError(
            f"need at least {min_markers} markers named after template landmarks; "
            f"got {len(names)} ({', '.join(names) or 'none'})",
            n_markers=len(names),
        )
    src = np.array([template_landmarks[k] for k in names], dtype=np.float64)
    dst = np.array([markers[k] for k in names], dtype=np.float64)
    if not np.isfinite(dst).all():
        raise MarkerError("marker coordinates must be finite numbers")
    sv_s = np.linalg.svd(src - src.mean(0), compute_uv=False)
    sv_d = np.linalg.svd(dst - dst.mean(0), compute_uv=False)
    if sv_s[1] < 1e-2 * max(sv_s[0], 1e-12) or sv_d[1] < 1e-2 * max(sv_d[0], 1e-12):
        raise MarkerError("markers are (nearly) collinear: at least 3 spread-out markers needed")

    # Iteratively reweighted fit; then drop gross outliers and refit.
    w = np.ones(len(names))
    for _ in range(10):
        sim = umeyama(src, dst, w)
        r = np.linalg.norm(sim.apply(src) - dst, axis=1)
        scale = max(1.4826 * float(np.median(r)), 0.01)
        w = 1.0 / (1.0 + (r / (2.0 * scale)) ** 2)
    keep = r <= outlier_distance
    warnings: list[str] = []
    if keep.sum() < min_markers:
        raise MarkerError(
            "markers disagree with each other: no consistent set of "
            f"{min_markers} found (are they in the scan's frame and units, and correctly named?)"
        )
    dropped = [names[i] for i in np.flatnonzero(~keep)]
    for i in np.flatnonzero(~keep):
        warnings.append(
            f"marker {names[i]} is {r[i] * 100:.0f} cm from where the other markers place it: "
            "ignored (misnamed or misplaced?)"
        )
    used_idx = np.flatnonzero(keep)
    sim = umeyama(src[used_idx], dst[used_idx])
    r = np.linalg.norm(sim.apply(src[used_idx]) - dst[used_idx], axis=1)
    residuals = {names[i]: float(ri) for i, ri in zip(used_idx, r, strict=True)}
    for name, ri in residuals.items():
        if ri > warn_distance:
            warnings.append(
                f"marker {name} is {ri * 100:.0f} cm from the template's similarity alignment "
                "(a pose difference or a misplaced marker)"
            )
    if not 0.3 < sim.s < 3.0:
        warnings.append(f"markers imply a body {sim.s:.2f}× the template's size; check units")
    return MarkerAlignment(
        similarity=sim,
        used=[names[i] for i in used_idx],
        dropped=dropped,
        residuals=residuals,
        warnings=warnings,
    )
