"""Morphing between bodies in template order (Allen et al. 2003, section 4.1).

All bodies share the template's vertices, so a morph is a per-vertex blend and a set of bodies
is one mesh with morph targets: the first body as the base, one target per other body holding
its position and normal deltas. Any glTF viewer then slides between them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from core.io._geometry import vertex_normals
from core.io.writers import GlbMorphTarget, write_glb
from core.template import load_template

MAX_BODIES = 16


def _check_bodies(bodies: Sequence[np.ndarray], n: int) -> list[np.ndarray]:
    out = []
    for i, V in enumerate(bodies):
        V = np.asarray(V, dtype=np.float64)
        if V.shape != (n, 3):
            raise ValueError(
                f"body {i}: expected ({n}, 3) vertices in template order, got {V.shape}"
            )
        if not np.isfinite(V).all():
            raise ValueError(f"body {i} has non-finite vertices")
        out.append(V)
    return out


def morph(V0: np.ndarray, V1: np.ndarray, t: float) -> np.ndarray:
    """The in-between body ``(1 - t) V0 + t V1``.

    Parameters
    ----------
    V0, V1 : (n, 3) bodies in template order, metres.
    t : blend parameter in [0, 1]; 0 gives ``V0`` and 1 gives ``V1`` exactly (bit for bit).

    Returns
    -------
    (n, 3) float64 vertices, metres.
    """
    t = float(t)
    if not 0.0 <= t <= 1.0:
        raise ValueError(f"t must lie in [0, 1], got {t}")
    V0, V1 = _check_bodies([V0, V1], np.asarray(V0).shape[0] if np.ndim(V0) == 2 else -1)
    return (1.0 - t) * V0 + t * V1


def morph_colors(C0: np.ndarray, C1: np.ndarray, t: float) -> np.ndarray:
    """The in-between body's per-vertex colours ``(1 - t) C0 + t C1``, rounded.

    Parameters
    ----------
    C0, C1 : (n, 3) uint8 RGB colours of the two bodies (template order).
    t : blend parameter in [0, 1]; 0 gives ``C0`` and 1 gives ``C1`` exactly.

    Returns
    -------
    (n, 3) uint8.
    """
    t = float(t)
    if not 0.0 <= t <= 1.0:
        raise ValueError(f"t must lie in [0, 1], got {t}")
    C0, C1 = np.asarray(C0), np.asarray(C1)
    if C0.shape != C1.shape or C0.ndim != 2 or C0.shape[1] != 3:
        raise ValueError(f"colours must be two (n, 3) arrays, got {C0.shape} and {C1.shape}")
    blend = (1.0 - t) * C0.astype(np.float64) + t * C1.astype(np.float64)
    return np.clip(np.rint(blend), 0, 255).astype(np.uint8)


def morph_targets(
    bodies: Sequence[np.ndarray],
    names: Sequence[str] | None = None,
    F: np.ndarray | None = None,
) -> tuple[np.ndarray, list[GlbMorphTarget]]:
    """The base body and one morph target per other body.

    Parameters
    ----------
    bodies : 2..16 (n, 3) bodies in template order, metres; the first is the base.
    names : one name per body (default ``body1``, ``body2``, ...); targets take ``names[1:]``.
    F : (m, 3) triangles for the normals (default: the template's).

    Returns
    -------
    V0 : (n, 3) the base body.
    targets : ``len(bodies) - 1`` targets: position deltas ``V_k - V0`` (metres) and normal
        deltas ``N_k - N0`` (area-weighted unit vertex normals).
    """
    if not 2 <= len(bodies) <= MAX_BODIES:
        raise ValueError(f"give 2 to {MAX_BODIES} bodies, got {len(bodies)}")
    if F is None:
        F = load_template().F
    n = np.asarray(bodies[0]).shape[0] if np.ndim(bodies[0]) == 2 else -1
    Vs = _check_bodies(bodies, n)
    if names is None:
        names = [f"body{i}" for i in range(len(Vs))]
    if len(names) != len(Vs):
        raise ValueError(f"{len(names)} names for {len(Vs)} bodies")
    N0 = vertex_normals(Vs[0], F)
    targets = [
        GlbMorphTarget(str(name), V - Vs[0], vertex_normals(V, F) - N0)
        for name, V in zip(names[1:], Vs[1:], strict=True)
    ]
    return Vs[0], targets


def morph_glb(
    bodies: Sequence[np.ndarray],
    names: Sequence[str] | None = None,
    F: np.ndarray | None = None,
    *,
    colors: np.ndarray | None = None,
) -> bytes:
    """GLB of the first body with one morph target per other body (see :func:`morph_targets`),
    with ``COLOR_0`` from ``colors`` ((n, 3) uint8 or floats in [0, 1]: the first body's) if
    given."""
    if F is None:
        F = load_template().F
    V0, targets = morph_targets(bodies, names, F)
    return write_glb(None, V0, F, colors=colors, targets=targets)
