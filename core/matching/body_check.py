"""Cheap checks that a scan can be a standing human body (before a markerless fit).

A markerless fit finds the body from the scan alone, so a scan that is no body at all (a box, a
pole, a flat sheet, a floor plane, a body read in the wrong units) should be refused at once
with the numbers that show why, not after seconds of fitting. The checks need only the points
(metres, +Y up, as read): a few percentiles, no fitting.

- **Height** (robust extent along +Y) in :data:`HEIGHT_M`.
- **Width** (robust extent along the principal horizontal direction) between
  :data:`MIN_WIDTH` and :data:`MAX_WIDTH` × the height: a standing body is about a quarter of
  its height wide with the arms down and about as wide as tall with the arms stretched out.
- **Depth** (the perpendicular horizontal extent) at least :data:`MIN_DEPTH` × the height
  (not a flat sheet).
- **Profile**: a body is much narrower somewhere (neck, ankles) than at its widest (shoulders,
  hips, hands): across horizontal slabs from 5 % to 95 % of the height, the narrowest must be
  at most :data:`MAX_PROFILE_RATIO` × the widest (a box or a cylinder is ≈ 1).
- **Not round**: somewhere a body is much wider than deep (the two legs side by side, the
  shoulders, the arms): the largest slab aspect (extent along the slab's principal horizontal
  direction over the perpendicular one) must be at least :data:`MIN_SLAB_ASPECT` (a vase or a
  column, round at every height, is ≈ 1.0; measured bodies 5–6, arms down and BMI ~50
  included).

Bounds are loose on purpose, and these checks are the only refusal of a markerless fit: a body
that the fit matches poorly is a result with warnings, not an error.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from core.errors import NotABodyError

#: Plausible standing height, metres.
HEIGHT_M = (0.8, 2.6)
#: Principal horizontal extent over the height, [min, max].
MIN_WIDTH, MAX_WIDTH = 0.12, 1.3
#: Smaller horizontal extent over the height, min.
MIN_DEPTH = 0.03
#: Narrowest over widest horizontal slab, max.
MAX_PROFILE_RATIO = 0.75
#: Largest slab width over depth, min.
MIN_SLAB_ASPECT = 1.4
N_SLABS = 18
MAX_POINTS = 60_000


def _surface_points(V: np.ndarray, F: np.ndarray | None, rng: np.random.Generator) -> np.ndarray:
    """The vertices plus area-weighted samples of the triangles (coarse meshes have few
    vertices), at most :data:`MAX_POINTS`."""
    P = V
    if F is not None and len(F):
        F = np.asarray(F, dtype=np.int64)
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        total = float(area.sum())
        if np.isfinite(total) and total > 0:
            n = 20_000
            t = rng.choice(len(F), size=n, p=area / total)
            u, v = rng.random((2, n))
            flip = u + v > 1
            u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
            S = a[t] + u[:, None] * (b[t] - a[t]) + v[:, None] * (c[t] - a[t])
            P = np.concatenate([V, S])
    if len(P) > MAX_POINTS:
        P = P[rng.choice(len(P), MAX_POINTS, replace=False)]
    return P


def body_shape(V: np.ndarray, F: np.ndarray | None = None) -> dict[str, Any]:
    """Size and proportions of a scan in the canonical frame.

    Parameters
    ----------
    V : (n, 3) points, metres, +Y up.
    F : (m, 3) triangles or None.

    Returns
    -------
    dict with ``height_m``, ``width_m``, ``depth_m`` (robust extents: 0.1–99.9 percentiles;
    width/depth along the principal horizontal directions), ``profile_ratio`` (narrowest over
    widest slab width, NaN if fewer than 3 slabs hold points), ``slab_aspect`` (largest width
    over depth of a slab in its own principal directions, NaN likewise) and ``n_points``.
    """
    V = np.asarray(V, dtype=np.float64)
    finite = np.isfinite(V).all(axis=1)
    if F is not None and len(F) and not finite.all():
        F = np.asarray(F)[finite[np.asarray(F)].all(axis=1)]
        F = np.searchsorted(np.flatnonzero(finite), F)  # renumber onto the finite vertices
    V = V[finite]
    P = _surface_points(V, F, np.random.default_rng(0)) if len(V) else V
    if len(P) < 10:
        raise NotABodyError(
            f"the scan has {len(V)} usable points: too few to be a body", n_points=len(V)
        )
    lo, hi = np.percentile(P[:, 1], [0.1, 99.9])
    h = float(hi - lo)
    H = P[:, [0, 2]] - P[:, [0, 2]].mean(axis=0)
    _, vecs = np.linalg.eigh(H.T @ H)
    ab = H @ vecs[:, ::-1]  # columns: widest direction, then the perpendicular one
    e = np.percentile(ab, 99.9, axis=0) - np.percentile(ab, 0.1, axis=0)
    widths, aspects = [], []
    if h > 0:
        edges = lo + h * np.linspace(0.05, 0.95, N_SLABS + 1)
        which = np.searchsorted(edges, P[:, 1]) - 1
        min_n = max(10, int(0.002 * len(P)))
        for s in range(N_SLABS):
            q = ab[which == s]
            if len(q) >= min_n:
                ext = np.percentile(q, 99, axis=0) - np.percentile(q, 1, axis=0)
                widths.append(float(ext.max()))
                qc = q - q.mean(axis=0)
                _, sv = np.linalg.eigh(qc.T @ qc)
                own = np.percentile(qc @ sv, 99, axis=0) - np.percentile(qc @ sv, 1, axis=0)
                aspects.append(float(own.max() / max(own.min(), 1e-9)))
    ratio = float(min(widths) / max(widths)) if len(widths) >= 3 and max(widths) > 0 else np.nan
    aspect = float(max(aspects)) if len(aspects) >= 3 else np.nan
    return {
        "height_m": h,
        "width_m": float(e[0]),
        "depth_m": float(e[1]),
        "profile_ratio": ratio,
        "slab_aspect": aspect,
        "n_points": len(V),
    }


def check_body_shape(
    V: np.ndarray, F: np.ndarray | None = None, *, frame: str = ""
) -> dict[str, Any]:
    """Raise :class:`NotABodyError` when the scan cannot be a standing body; else its shape.

    Parameters
    ----------
    V : (n, 3) points, metres, +Y up (canonical frame).
    F : (m, 3) triangles or None.
    frame : how the file was read, for the message (e.g. ``"units mm, up +z"``).

    Returns
    -------
    :func:`body_shape` of the scan.
    """
    s = body_shape(V, F)
    h, w, d, r = s["height_m"], s["width_m"], s["depth_m"], s["profile_ratio"]
    read = f" (read as {frame})" if frame else ""
    size = f"{h:.3g} m tall, {w:.3g} m wide and {d:.3g} m deep{read}"
    if not HEIGHT_M[0] <= h <= HEIGHT_M[1]:
        raise NotABodyError(
            f"the scan is {size}: a standing body is {HEIGHT_M[0]:g}–{HEIGHT_M[1]:g} m tall. "
            "Are its units or up axis wrong? (give them when uploading, or 'auto')",
            check="height", **s,
        )  # fmt: skip
    if w > MAX_WIDTH * h:
        raise NotABodyError(
            f"the scan is {size}: wider than a standing body with its arms outstretched "
            f"(at most {MAX_WIDTH:g}× its height). Is the up axis wrong, or are there other "
            "objects (floor, walls) in the scan? Crop them.",
            check="width", **s,
        )  # fmt: skip
    if w < MIN_WIDTH * h:
        raise NotABodyError(
            f"the scan is {size}: too narrow for a standing body (at least {MIN_WIDTH:g}× its "
            "height across)",
            check="width", **s,
        )  # fmt: skip
    if d < MIN_DEPTH * h:
        raise NotABodyError(
            f"the scan is {size}: flat, not a body (at least {MIN_DEPTH:g}× its height deep)",
            check="depth", **s,
        )  # fmt: skip
    if np.isfinite(r) and r > MAX_PROFILE_RATIO:
        raise NotABodyError(
            f"the scan is {size} and about as wide at every height (narrowest slab "
            f"{100 * r:.0f} % of the widest): a body narrows at the neck and the ankles, this "
            "looks like a box or a column",
            check="profile", **s,
        )  # fmt: skip
    a = s["slab_aspect"]
    if np.isfinite(a) and a < MIN_SLAB_ASPECT:
        raise NotABodyError(
            f"the scan is {size} and round at every height (no slab more than {a:.2f}× as wide "
            "as deep): a body is much wider than deep somewhere (legs side by side, shoulders); "
            "this looks like a column or a vase",
            check="roundness", **s,
        )  # fmt: skip
    return s
