"""Colour transfer (Allen et al. 2003, section 4.6): a scan's per-vertex colours carried to the
fitted body in template order.

Each template vertex takes the colour at its closest *compatible* scan point (the data term's
correspondences, :class:`core.registration.correspondence.ScanIndex`): on a triangle scan the
colour is interpolated barycentrically in the scan triangle (around the matched point) nearest
to the vertex; on a point cloud it is the matched point's. Vertices with no compatible scan data
(holes) are filled smoothly over the template: the harmonic interpolant of the observed colours
(graph Laplacian, Dirichlet data at the observed vertices).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from core.registration.correspondence import ScanIndex
from core.registration.fit import FitResult
from core.scan import Scan
from core.template import load_template


def barycentric(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(..., 3) barycentric coordinates of P's projection onto triangles ABC (clamped >= 0,
    renormalised; degenerate triangles give equal weights)."""
    v0, v1, v2 = B - A, C - A, P - A
    d00 = np.einsum("...i,...i->...", v0, v0)
    d01 = np.einsum("...i,...i->...", v0, v1)
    d11 = np.einsum("...i,...i->...", v1, v1)
    d20 = np.einsum("...i,...i->...", v2, v0)
    d21 = np.einsum("...i,...i->...", v2, v1)
    den = d00 * d11 - d01 * d01
    ok = np.abs(den) > 1e-30
    den = np.where(ok, den, 1.0)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    L = np.stack([1.0 - v - w, v, w], axis=-1)
    L = np.where(ok[..., None], L, 1.0 / 3.0)
    return L


def _sample_triangles(scan: Scan, colors: np.ndarray, X: np.ndarray, pid: np.ndarray) -> np.ndarray:
    """Colours at X (k, 3) from the scan triangles around matched points ``pid`` (k,)."""
    F = scan.F
    n = len(scan.V)
    inc = sparse.csr_matrix(
        (np.ones(F.size), (F.ravel(), np.repeat(np.arange(len(F)), 3))), shape=(n, len(F))
    )
    deg = np.diff(inc.indptr)
    out = colors[pid].astype(np.float64)  # isolated points: their own colour
    has = deg[pid] > 0
    if not has.any():
        return out
    rows = np.flatnonzero(has)
    p = pid[rows]
    dmax = int(deg[p].max())
    # incident faces of each matched point, padded by repeating its first face
    starts = inc.indptr[p]
    off = np.minimum(np.arange(dmax)[None, :], deg[p][:, None] - 1)
    faces = inc.indices[starts[:, None] + off]  # (r, dmax)
    T = scan.V[F[faces]]  # (r, dmax, 3 corners, 3)
    L = barycentric(X[rows][:, None, :], T[:, :, 0], T[:, :, 1], T[:, :, 2])
    inside = L.min(axis=-1)  # >= 0 where the projection falls inside the triangle
    Lc = np.clip(L, 0.0, None)
    Lc /= Lc.sum(axis=-1, keepdims=True)
    Q = np.einsum("rfc,rfcd->rfd", Lc, T)
    dist = np.linalg.norm(Q - X[rows][:, None, :], axis=-1)
    best = np.argmin(np.where(inside >= -1e-9, dist, dist + 1.0), axis=1)
    r = np.arange(len(rows))
    cols = colors[F[faces[r, best]]].astype(np.float64)  # (r, 3 corners, 3 channels)
    out[rows] = np.einsum("rc,rcd->rd", Lc[r, best], cols)
    return out


def harmonic_fill(values: np.ndarray, known: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Fill unknown rows of ``values`` smoothly: the harmonic interpolant on the graph.

    Parameters
    ----------
    values : (n, c) values; rows with ``known`` False are replaced.
    known : (n,) bool; at least one True per connected component that has unknowns (else those
        rows take the mean of the known values).
    edges : (e, 2) int graph edges (the template's).

    Returns
    -------
    (n, c) float64: known rows unchanged, unknown rows solving the uniform-weight Laplace
    equation with the known rows as Dirichlet data.
    """
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    known = np.asarray(known, dtype=bool)
    out = values.copy()
    unknown = np.flatnonzero(~known)
    if len(unknown) == 0:
        return out
    if not known.any():
        raise ValueError("no known values to fill from")
    E = np.asarray(edges, dtype=np.int64)
    W = sparse.coo_matrix((np.ones(2 * len(E)), (E.ravel(), E[:, ::-1].ravel())), shape=(n, n))
    W = W.tocsr()
    W.data[:] = 1.0
    L = sparse.diags(np.asarray(W.sum(axis=1)).ravel()) - W
    Luu = L[unknown][:, unknown].tocsc()
    Luk = L[unknown][:, np.flatnonzero(known)]
    # a tiny diagonal keeps components without known vertices solvable (they go to ~0 + mean)
    mean = values[known].mean(axis=0)
    rhs = -(Luk @ (values[known] - mean))
    lu = splu((Luu + sparse.identity(len(unknown)) * 1e-9).tocsc())
    out[unknown] = lu.solve(rhs) + mean
    return out


def colour_fit(result: FitResult, scan: Scan) -> None:
    """Give a fit result the colours of its scan, if the scan has any:
    sets ``result.colors`` and adds a report note (share of vertices filled). For a textured
    scan (``scan.textured``) also ``result.texture``: the (1024, 1024, 3) uint8 texture on the
    template UV layout taken from the scan's texture at full resolution
    (:func:`core.transfer.texture.transfer_texture`; the per-vertex colours fill the rest)."""
    if scan.colors is None:
        return
    colours, observed = transfer_colours(result.vertices, scan, F=result.faces)
    result.colors = colours
    result.report.notes.append(
        f"colours from the scan; {100 * (1 - observed.mean()):.1f} % of vertices had no scan "
        "colour within 1 cm and were filled smoothly"
    )
    if scan.textured is not None:
        from core.transfer.texture import bake_texture, transfer_texture

        result.texture, share = transfer_texture(
            result.vertices, scan.textured, bake_texture(colours)
        )
        result.report.notes.append(
            f"texture from the scan's texture at full resolution on {100 * share:.1f} % of "
            "the body's texels (the rest from the vertex colours)"
        )


def transfer_colours(
    V: np.ndarray,
    scan: Scan,
    *,
    max_distance: float = 0.01,
    max_angle_deg: float = 60.0,
    F: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Colours of a fitted body from its (coloured) scan.

    Parameters
    ----------
    V : (13380, 3) fitted body, template order, in the scan's canonical frame (metres).
    scan : the prepared scan with ``colors`` ((n, 3) uint8 or floats in [0, 1]).
    max_distance, max_angle_deg : compatibility (metres, degrees), as the data term; farther
        than ``max_distance`` from any compatible scan point a vertex is in a hole.
    F : template triangles for the normals (default the template's).

    Returns
    -------
    colours : (13380, 3) float64 RGB in [0, 1].
    observed : (13380,) bool: False where the colour was filled (no compatible scan data).
    """
    if scan.colors is None:
        raise ValueError("the scan has no colours")
    tpl = load_template()
    F = tpl.F if F is None else F
    V = np.asarray(V, dtype=np.float64)
    C = np.asarray(scan.colors)
    C = C / 255.0 if C.dtype.kind in "ui" else C.astype(np.float64)
    from core.io._geometry import vertex_normals

    N = vertex_normals(V, F)
    idx = ScanIndex(scan)
    corr = idx.closest_compatible(
        V, N, max_distance=max_distance, max_angle_deg=max_angle_deg, project=False
    )
    observed = np.isfinite(corr.distances)  # hole rims carry colour too
    out = np.zeros((len(V), 3))
    rows = np.flatnonzero(observed)
    if scan.F is not None and len(scan.F):
        out[rows] = _sample_triangles(scan, C, V[rows], corr.point_ids[rows])
    else:
        out[rows] = C[corr.point_ids[rows]]
    if not observed.any():
        raise ValueError("no template vertex has compatible scan data: nothing to colour from")
    out = harmonic_fill(out, observed, tpl.edges)
    return np.clip(out, 0.0, 1.0), observed
