"""Plane sections of closed triangle meshes, convex-hull perimeters and mesh volume.

Everything is vectorised numpy: a section intersects every (selected) mesh edge with the plane at
once; faces crossed by the plane link their two crossing edges, and the connected components of
that graph are the closed section loops. A tape measure spans concavities, so circumferences are
the perimeters of convex hulls of section points, taken in the plane's own 2D coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial import ConvexHull, QhullError


class MeshTopology:
    """Edges of a triangle mesh and the edges of each face, computed once per face array.

    Parameters
    ----------
    F : (m, 3) int triangles.

    Attributes
    ----------
    edges : (E, 2) int64 unique undirected edges, ``i < j``; ``e0``, ``e1`` its columns.
    face_edges : (m', 3) int64 index into ``edges`` of each face's edges (01, 12, 20); ``-1``
        for an edge left out by :meth:`restrict`.
    """

    def __init__(self, F: np.ndarray) -> None:
        F = np.asarray(F, dtype=np.int64)
        if F.ndim != 2 or F.shape[1] != 3:
            raise ValueError(f"F must be (m, 3) triangles, got shape {F.shape}")
        half = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        E, inv = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True)
        self._set(E, inv.reshape(3, -1).T.copy())

    def _set(self, E: np.ndarray, FE: np.ndarray) -> None:
        self.edges: np.ndarray = E
        self.face_edges: np.ndarray = FE
        self.e0: np.ndarray = np.ascontiguousarray(E[:, 0])
        self.e1: np.ndarray = np.ascontiguousarray(E[:, 1])

    def restrict(self, vertex_mask: np.ndarray) -> MeshTopology:
        """The sub-topology of the edges whose two end vertices are in ``vertex_mask``.

        Parameters
        ----------
        vertex_mask : (n,) bool over the mesh's vertices.

        Returns
        -------
        A :class:`MeshTopology` holding only those edges (faces keep the ones they have; faces
        with fewer than two are dropped). Sections through it see only that part of the mesh.
        """
        vm = np.asarray(vertex_mask, dtype=bool)
        keep = vm[self.edges[:, 0]] & vm[self.edges[:, 1]]
        local = np.full(len(self.edges) + 1, -1, dtype=np.int64)
        local[np.flatnonzero(keep)] = np.arange(int(keep.sum()))
        FE = local[self.face_edges]  # index -1 (no edge) -> local[-1] = -1
        sub = object.__new__(MeshTopology)
        sub._set(self.edges[keep], FE[(FE >= 0).sum(axis=1) >= 2])
        return sub


@dataclass(frozen=True, eq=False)
class Section:
    """The points where a plane cuts a mesh's edges, grouped into connected loops.

    Attributes
    ----------
    points : (k, 3) float64 section points, metres (one per crossing edge).
    labels : (k,) int64 connected-component (loop) label of each point (computed on demand).
    origin : (3,) plane point; normal : (3,) unit plane normal.
    u, v : (3,) unit in-plane axes (``u x v = normal``).
    """

    points: np.ndarray
    origin: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    v: np.ndarray
    _topo: MeshTopology = field(repr=False)
    _ids: np.ndarray = field(repr=False)

    @cached_property
    def labels(self) -> np.ndarray:
        """(k,) int64 loop label of each point (a face cut by two of the edges joins them)."""
        k = len(self._ids)
        if k == 0:
            return np.zeros(0, dtype=np.int64)
        E = self._topo.edges
        compact = np.full(len(E) + 1, -1, dtype=np.int64)  # index -1 (no edge) -> -1
        compact[self._ids] = np.arange(k)
        FE = compact[self._topo.face_edges]
        hit = FE >= 0
        two = hit.sum(axis=1) == 2
        pairs = FE[two][hit[two]].reshape(-1, 2)
        return _components(k, pairs[:, 0], pairs[:, 1])

    @property
    def n_components(self) -> int:
        return int(self.labels.max()) + 1 if len(self.labels) else 0

    def to_2d(self, P: np.ndarray | None = None) -> np.ndarray:
        """(k, 2) in-plane coordinates (metres) of ``P`` (default the section points)."""
        P = self.points if P is None else np.asarray(P, dtype=np.float64)
        D = P - self.origin
        return np.stack([D @ self.u, D @ self.v], axis=-1)

    def piece(self, near: np.ndarray) -> np.ndarray:
        """Points of the loop nearest to ``near`` (3,): the loop whose 2D convex hull contains
        its projection, else the loop with the nearest point. (k', 3) float64."""
        if len(self.points) == 0:
            return self.points
        n = self.n_components
        if n == 1:
            return self.points
        q = self.to_2d(np.asarray(near, dtype=np.float64)[None])[0]
        P2 = self.to_2d()
        best, best_d = 0, np.inf
        for c in range(n):
            Q = P2[self.labels == c]
            if len(Q) >= 3 and _inside_hull(Q, q):
                return self.points[self.labels == c]
            d = float(np.min(np.sum((Q - q) ** 2, axis=1)))
            if d < best_d:
                best, best_d = c, d
        return self.points[self.labels == best]


def _components(k: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components of a graph of ``k`` nodes and edges ``a[i]-b[i]``: each node gets
    the smallest node index of its component (min-label propagation with pointer jumping;
    a few rounds for the short loops of a section). (k,) int64, relabelled 0..c-1."""
    lab = np.arange(k)
    for _ in range(k + 1):
        m = np.minimum(lab[a], lab[b])
        new = lab.copy()
        np.minimum.at(new, a, m)
        np.minimum.at(new, b, m)
        new = new[new[new]]
        if np.array_equal(new, lab):
            break
        lab = new
    return np.unique(lab, return_inverse=True)[1].astype(np.int64)


def _inside_hull(Q: np.ndarray, q: np.ndarray) -> bool:
    try:
        h = ConvexHull(Q)
    except QhullError:
        return False
    return bool(np.all(h.equations[:, :2] @ q + h.equations[:, 2] <= 1e-12))


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normal and two in-plane unit axes ``u, v`` with ``u x v = n``.

    Parameters
    ----------
    normal : (3,) non-zero plane normal (any length).

    Returns
    -------
    n, u, v : (3,) float64 unit vectors.
    """
    n = np.asarray(normal, dtype=np.float64)
    length = np.linalg.norm(n)
    if n.shape != (3,) or not np.isfinite(length) or length == 0:
        raise ValueError(f"normal must be a non-zero finite 3-vector, got {normal!r}")
    n = n / length
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(a, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return n, u, v


def plane_section(
    V: np.ndarray,
    F: np.ndarray | MeshTopology,
    origin: np.ndarray,
    normal: np.ndarray,
) -> Section:
    """Intersect a triangle mesh with a plane.

    Parameters
    ----------
    V : (n, 3) float vertices, metres.
    F : (m, 3) int triangles, or their precomputed :class:`MeshTopology` (faster when repeated;
        a :meth:`MeshTopology.restrict` one cuts only that part of the mesh, e.g. one limb).
    origin : (3,) a point of the plane, metres.
    normal : (3,) plane normal (any non-zero length).

    Returns
    -------
    Section: the crossing points and their loop labels. A vertex exactly on the plane counts as
    being on the positive side, so every face is crossed by 0 or 2 edges.
    """
    topo = F if isinstance(F, MeshTopology) else MeshTopology(np.asarray(F))
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must be (n, 3) vertices, got shape {V.shape}")
    o = np.asarray(origin, dtype=np.float64)
    if o.shape != (3,):
        raise ValueError(f"origin must be a 3-vector, got shape {o.shape}")
    n, u, v = plane_basis(normal)
    d = V @ n - float(o @ n)
    pos = d >= 0.0
    ids = np.flatnonzero(pos[topo.e0] != pos[topo.e1])
    a, b = topo.e0[ids], topo.e1[ids]
    da, db = d[a], d[b]
    t = (da / (da - db))[:, None]
    P = V[a] + t * (V[b] - V[a])
    return Section(points=P, origin=o, normal=n, u=u, v=v, _topo=topo, _ids=ids)


def convex_perimeter(points2d: np.ndarray) -> float:
    """Perimeter of the convex hull of 2D points (a taut tape around them).

    Parameters
    ----------
    points2d : (k, 2) float coordinates, metres.

    Returns
    -------
    Perimeter in metres; 0 for fewer than 2 points, twice the extent for collinear points.
    """
    Q = np.asarray(points2d, dtype=np.float64)
    if Q.ndim != 2 or Q.shape[1] != 2:
        raise ValueError(f"points2d must be (k, 2), got shape {Q.shape}")
    if len(Q) < 2:
        return 0.0
    try:
        h = ConvexHull(Q)
    except QhullError:  # degenerate: collinear points
        d = Q - Q.mean(axis=0)
        _, _, Vt = np.linalg.svd(d, full_matrices=False)
        s = d @ Vt[0]
        return float(2.0 * (s.max() - s.min()))
    ring = Q[h.vertices]  # counter-clockwise order in 2D
    return float(np.sum(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1)))


def section_circumference(
    V: np.ndarray,
    F: np.ndarray | MeshTopology,
    origin: np.ndarray,
    normal: np.ndarray,
    *,
    near: np.ndarray | None = None,
) -> float:
    """Convex-hull perimeter (metres) of a mesh's section by a plane.

    Parameters
    ----------
    V, F, origin, normal : as :func:`plane_section`.
    near : (3,) keep only the section loop nearest this point (see :meth:`Section.piece`);
        default every loop.

    Returns
    -------
    The perimeter in metres (0 when the plane misses the mesh).
    """
    s = plane_section(V, F, origin, normal)
    P = s.points if near is None else s.piece(near)
    return convex_perimeter(s.to_2d(P))


def mesh_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Enclosed volume of a closed triangle mesh by the divergence theorem.

    Parameters
    ----------
    V : (n, 3) float vertices, metres. F : (m, 3) int triangles (consistently oriented).

    Returns
    -------
    Volume in cubic metres (absolute value, so either winding works).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"V must be (n, 3) and F (m, 3), got {V.shape} and {F.shape}")
    X = V - V.mean(axis=0)  # origin at the centroid: less cancellation
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    i, j, k = F[:, 0], F[:, 1], F[:, 2]
    # a . (b x c), expanded to avoid building (m, 3) temporaries
    det = (
        x[i] * (y[j] * z[k] - z[j] * y[k])
        - y[i] * (x[j] * z[k] - z[j] * x[k])
        + z[i] * (x[j] * y[k] - y[j] * x[k])
    )
    return float(abs(det.sum()) / 6.0)
