"""Marker screening: markers are evidence, left out only when both the scan and their neighbours
contradict them.

A marker is **dropped** only when it is

1. far from the scan surface (more than ``surface_distance``, 3 cm: a marker sits on the skin), and
2. inconsistent with its neighbours: the similarity that maps the template landmarks of its
   ``k`` nearest marked neighbours (template distance) onto their markers places it more than
   ``neighbour_distance`` (8 cm) from where it was measured.

Markers that only one of the two contradicts are kept; the body prior weighs them robustly
(``core.registration.shape_prior``: Cauchy weights whose scale anneals from 30 cm to 3 cm), and
a marker consistent with its neighbours keeps at least ``CONSISTENT_WEIGHT_FLOOR`` of its weight
whatever the current body fit says — the prior may be wrong (a flexed head), the marker and its
neighbours rarely are together. The numbers allow other teams' conventions (markers 2–5 cm off our
definitions) and catch misnamed or swapped markers (20 cm and more from their neighbours'
prediction).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.registration.correspondence import ScanIndex
from core.registration.initialization import umeyama

SURFACE_DISTANCE_M = 0.03
NEIGHBOUR_DISTANCE_M = 0.08
NEIGHBOURS = 6
CONSISTENT_WEIGHT_FLOOR = 0.5


@dataclass
class MarkerScreening:
    """Result of :func:`screen_markers` (distances in metres)."""

    kept: list[str]
    dropped: list[str]
    surface_distance: dict[str, float]  # to the nearest scan point
    neighbour_residual: dict[str, float]  # from the neighbours' similarity prediction
    consistent: dict[str, bool]  # neighbour_residual <= neighbour_distance
    warnings: list[str] = field(default_factory=list)


def neighbour_residuals(
    template_landmarks: dict[str, np.ndarray],
    markers: dict[str, np.ndarray],
    *,
    k: int = NEIGHBOURS,
) -> dict[str, float]:
    """Distance (metres) from each marker to where its ``k`` nearest marked neighbours put it.

    For marker ``m`` the neighbours are the ``k`` markers whose template landmarks are nearest
    ``m``'s landmark; a similarity (Umeyama, Cauchy-reweighted against one bad neighbour) maps
    their landmarks onto their markers and is applied to ``m``'s landmark. NaN with fewer than 3
    other markers.
    """
    names = [n for n in markers if n in template_landmarks]
    L = np.array([template_landmarks[n] for n in names], dtype=np.float64).reshape(-1, 3)
    M = np.array([markers[n] for n in names], dtype=np.float64).reshape(-1, 3)
    out: dict[str, float] = {}
    for i, name in enumerate(names):
        others = np.delete(np.arange(len(names)), i)
        if len(others) < 3:
            out[name] = float("nan")
            continue
        d = np.linalg.norm(L[others] - L[i], axis=1)
        nb = others[np.argsort(d)[:k]]
        w = np.ones(len(nb))
        for _ in range(4):
            sim = umeyama(L[nb], M[nb], w)
            r = np.linalg.norm(sim.apply(L[nb]) - M[nb], axis=1)
            w = 1.0 / (1.0 + (r / 0.05) ** 2)
        out[name] = float(np.linalg.norm(sim.apply(L[i][None])[0] - M[i]))
    return out


def screen_markers(
    index: ScanIndex,
    template_landmarks: dict[str, np.ndarray],
    markers: dict[str, np.ndarray],
    *,
    surface_distance: float = SURFACE_DISTANCE_M,
    neighbour_distance: float = NEIGHBOUR_DISTANCE_M,
) -> MarkerScreening:
    """Drop markers that both the scan surface and their neighbours contradict (module doc)."""
    names = list(markers)
    if not names:
        return MarkerScreening([], [], {}, {}, {})
    dist = index.distance_to_points(np.array([markers[n] for n in names], dtype=np.float64))
    nres = neighbour_residuals(template_landmarks, markers)
    kept: list[str] = []
    dropped: list[str] = []
    warnings: list[str] = []
    consistent: dict[str, bool] = {}
    for name, d in zip(names, dist, strict=True):
        r = nres.get(name, float("nan"))
        ok_nb = bool(np.isfinite(r) and r <= neighbour_distance)
        consistent[name] = ok_nb
        if d > surface_distance and not ok_nb:
            dropped.append(name)
            why = (
                ""
                if not np.isfinite(r)
                else f" and {r * 100:.0f} cm from where its neighbours put it"
            )
            warnings.append(
                f"marker {name} is {d * 100:.1f} cm from the scan{why}: ignored "
                "(misplaced or misnamed?)"
            )
        else:
            kept.append(name)
            if d > surface_distance:
                warnings.append(
                    f"marker {name} is {d * 100:.1f} cm from the scan but agrees with its "
                    "neighbours: kept"
                )
    return MarkerScreening(
        kept,
        dropped,
        {n: float(d) for n, d in zip(names, dist, strict=True)},
        nres,
        consistent,
        warnings,
    )
