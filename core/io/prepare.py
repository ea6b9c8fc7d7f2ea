"""Turn a raw scan into a :class:`core.scan.Scan` ready for registration.

Steps (all vectorised): map to the canonical frame (metres, +Y up); clean (weld exactly
coincident vertices, drop degenerate and duplicate triangles and unreferenced vertices, drop
duplicate points of a cloud); remove what is not the body (a floor plate or floor points, stray
blobs: :mod:`core.io.clean`); normals (from the file, else area-weighted for meshes or PCA of
the k nearest neighbours for clouds, oriented outward); boundary flags (open edges,
but not the zero-width cracks of T-junctions and slivers: :func:`_crack_edges`); confidence (from
the file, else estimated from the distance to the nearest boundary and isolation).
"""

from __future__ import annotations

import os

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from core.errors import InputFormatError
from core.geometry import row_norms
from core.io._geometry import normalize, vertex_normals
from core.io.clean import remove_non_body
from core.io.frame import apply_frame, detect_frame
from core.io.markers import read_markers
from core.io.orient import orient_components
from core.io.readers import read_mesh
from core.scan import FrameInfo, RawMesh, Scan
from core.threads import kd_workers, map_in_blocks

K_NEIGHBOURS = 10  # PCA normals and orientation
K_BOUNDARY = 20  # boundary test (larger: robust to random sampling)
BOUNDARY_OFFSET = 0.35  # tangent centroid offset / neighbourhood radius marking a cloud boundary
CONF_MIN = 0.2  # estimated confidence on a boundary and for isolated points
CONF_RAMP_MIN = 0.005  # m; the confidence ramp is max(this, 3 x median spacing) wide
#: Scans with more points are decimated on a voxel grid before preparation (registration uses
#: the scan at ~1 cm, the template's resolution; a 4 mm scanner gives ~150 k points).
DECIMATE_ABOVE = 600_000
DECIMATE_VOXEL_M = 0.004  # m, the voxel edge of that decimation (a 4 mm scanner's pitch)
#: Dimensionless, a fraction of the local edge length: a point within this × the length of an
#: open edge (the longer of the two edges compared) lies *on* it, so open edges that run along
#: each other this closely enclose no gap (a crack: :func:`_crack_edges`). 1 % is 10 µm on a
#: 1 mm edge, 40 µm at the 4 mm decimation pitch: above the rounding of coordinates written with
#: 6 significant digits (≤ 5e-6 × 2 m = 10 µm) or as float32 (≤ 0.1 µm), which moves a
#: T-junction's vertex off the edge it splits, and 100x below the width of any real hole, whose
#: two sides are at least one sample spacing (about one edge length) apart.
CRACK_TOL = 0.01
#: Two open edges along each other whose triangles lie on the same side (their directions
#: into the triangles, across the edges, within ~25°: cosine above this) are a rim doubled by
#: an overlapping patch (≈ 0°), not a crack, whose sides are ≈ 180° apart on a smooth body; the
#: folds of tiny triangles (a mouth pocket, marching-cubes folds) reach 35-60°.
CRACK_SAME_SIDE_COS = 0.9
K_CRACK = 32  # nearest index points searched per crack sample (a few edges meet at a vertex)
CRACK_CHUNK = 65_536  # crack samples per vectorised block (bounds the (chunk, k, 3) arrays)


def _unique_rows(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exactly equal rows -> (index of each unique row's first occurrence, in order; inverse).

    Hashes each row to one uint64 and sorts once (several times faster than ``np.unique`` on
    rows); a hash collision is detected and falls back to the exact row sort.
    """
    Xc = np.ascontiguousarray(X + 0 if X.dtype.kind == "f" else X)  # -0.0 -> +0.0
    n = len(Xc)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    u = Xc.view(np.uint64) if Xc.dtype.itemsize == 8 else Xc.astype(np.int64).view(np.uint64)
    h = np.zeros(n, np.uint64)
    for j in range(u.shape[1]):
        h = (h ^ u[:, j]) * np.uint64(0x9E3779B97F4A7C15)
        h ^= h >> np.uint64(29)
    hs = np.sort(h)  # a value sort first (several times faster than argsort)
    if not (hs[1:] == hs[:-1]).any():  # no duplicates: the common case
        idx = np.arange(n)
        return idx, idx
    order = np.argsort(h)
    hs = h[order]
    start = np.concatenate([[True], hs[1:] != hs[:-1]])
    gid = np.cumsum(start) - 1
    first = np.minimum.reduceat(order, np.flatnonzero(start))
    if not np.array_equal(Xc[order], Xc[first[gid]]):  # hash collision: exact fallback
        void = Xc.view(np.dtype((np.void, Xc.dtype.itemsize * Xc.shape[1]))).ravel()
        _, first, inv = np.unique(void, return_index=True, return_inverse=True)
        gid_of = inv.ravel()
    else:
        gid_of = np.empty(n, np.int64)
        gid_of[order] = gid
    rk = np.argsort(first, kind="stable")
    rank = np.empty_like(rk)
    rank[rk] = np.arange(len(rk))
    return first[rk], rank[gid_of]


def _take(a: np.ndarray | None, idx: np.ndarray) -> np.ndarray | None:
    return None if a is None else a[idx]


def _clean_mesh(raw: RawMesh, notes: list[str]) -> RawMesh:
    V, F = raw.V, raw.F
    first, inv = _unique_rows(V)
    if len(first) < len(V):
        notes.append(f"welded {len(V) - len(first):,} duplicate vertices")
    F = inv[F]
    V = V[first]
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
    if not keep.all():
        notes.append(f"dropped {int((~keep).sum()):,} degenerate triangles")
    F = F[keep]
    if len(F):
        Fs = np.sort(F, axis=1)
        fi, _ = _unique_rows(Fs)
        if len(fi) < len(F):
            notes.append(f"dropped {len(F) - len(fi):,} duplicate triangles")
            F = F[np.sort(fi)]
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    if not used.all():
        notes.append(f"dropped {int((~used).sum()):,} vertices not used by any triangle")
    new = np.cumsum(used) - 1
    sel = first[used]
    return RawMesh(
        V=V[used],
        F=new[F] if len(F) else None,
        normals=_take(raw.normals, sel),
        confidence=_take(raw.confidence, sel),
        colors=_take(raw.colors, sel),
    )


def _clean_cloud(raw: RawMesh, notes: list[str]) -> RawMesh:
    first, _ = _unique_rows(raw.V)
    if len(first) == len(raw.V):
        return raw
    notes.append(f"dropped {len(raw.V) - len(first):,} duplicate points")
    return RawMesh(
        V=raw.V[first],
        F=None,
        normals=_take(raw.normals, first),
        confidence=_take(raw.confidence, first),
        colors=_take(raw.colors, first),
    )


def decimate_voxel_grid(raw: RawMesh, voxel: float) -> RawMesh:
    """Vertex clustering on a voxel grid of edge ``voxel`` (the mesh's units).

    Every vertex in a cell is replaced by their mean (normals averaged, confidence and colours
    averaged); triangles are re-indexed, and those whose corners fall in fewer than 3 cells are
    dropped (duplicates are left to the mesh cleaning). Vectorised: one hash sort of the cells.

    Returns a new :class:`RawMesh` with one vertex per occupied cell (in cell order).
    """
    V = np.asarray(raw.V, dtype=np.float64)
    cell = np.floor((V - V.min(axis=0)) / voxel).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]  # < 2^63 for any body
    _, inv = np.unique(key, return_inverse=True)
    inv = inv.ravel()
    k = int(inv.max()) + 1
    count = np.bincount(inv, minlength=k).astype(np.float64)

    def mean(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        cols = [np.bincount(inv, a[:, j], minlength=k) for j in range(a.shape[1])]
        return np.stack(cols, axis=1) / count[:, None]

    F = None
    if raw.F is not None and len(raw.F):
        F = inv[raw.F]
        F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    normals = None
    if raw.normals is not None:
        normals = mean(raw.normals)
        nrm = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, nrm, out=np.zeros_like(normals), where=nrm > 1e-12)
    return RawMesh(
        V=mean(V),
        F=F,
        normals=normals,
        confidence=None
        if raw.confidence is None
        else np.bincount(inv, raw.confidence, minlength=k) / count,
        colors=None
        if raw.colors is None
        else np.clip(np.round(mean(raw.colors)), 0, 255).astype(np.uint8),
    )


def _radial(V: np.ndarray, slab: float = 0.05) -> np.ndarray:
    """Unit horizontal directions (n, 3) from the body's central vertical axis to each point.

    The axis passes through the centre of each horizontal slab's x/z bounding box (slabs
    ``slab`` metres thick), so a dense face or forward-pointing feet do not bias it.
    """
    b = np.floor((V[:, 1] - V[:, 1].min()) / slab).astype(np.int64)
    nb = int(b.max()) + 1
    lo = np.full((nb, 2), np.inf)
    hi = np.full((nb, 2), -np.inf)
    xz = V[:, [0, 2]]
    for j in range(2):
        np.minimum.at(lo[:, j], b, xz[:, j])
        np.maximum.at(hi[:, j], b, xz[:, j])
    with np.errstate(invalid="ignore"):  # empty slabs (never indexed) give inf - inf
        centre = (lo + hi) / 2.0
    r = np.zeros_like(V)
    r[:, [0, 2]] = xz - centre[b]
    return normalize(r, fallback=(0.0, 0.0, 0.0))


def _pca_normals(V: np.ndarray, nbr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PCA normals (n, 3) of the k-neighbourhoods and surface variation (n,) in [0, 1/3]."""
    parts = map_in_blocks(lambda rows: _pca_normals_of(V, nbr[rows]), len(nbr))
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _pca_normals_of(V: np.ndarray, nbr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_pca_normals` of the points whose neighbours are ``nbr`` (m, k)."""
    P = V[nbr]  # (m, k, 3)
    P -= P.mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", P, P)
    vals, vecs = np.linalg.eigh(C)
    var = vals[:, 0] / np.maximum(vals.sum(axis=1), 1e-300)
    return vecs[:, :, 0], np.clip(var, 0.0, 1.0)


def _orient_cloud(N: np.ndarray, var: np.ndarray, nbr: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Orient PCA normals consistently (Hoppe-style propagation over a minimum spanning tree).

    Edge cost: non-parallel normals, displacement along the normals (edges across thin parts)
    and noisy neighbourhoods are expensive. Tree edges costlier than ``0.5`` are cut; each
    remaining piece is turned so that its normals point away from the body's vertical axis on
    (weighted) average.
    """
    n, k = nbr.shape
    rows = np.repeat(np.arange(n), k - 1)
    cols = nbr[:, 1:].ravel()
    w = np.concatenate(map_in_blocks(lambda r: _edge_costs(N, var, nbr[r], V, r), n), axis=None)
    G = sparse.coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    G = G.maximum(G.T)
    T = csgraph.minimum_spanning_tree(G).tocoo()
    # one tree: a virtual node n joined to the first point of every connected part
    _, label = csgraph.connected_components(G, directed=False)
    roots = np.unique(label, return_index=True)[1]
    r = np.concatenate([T.row, np.full(len(roots), n)])
    c = np.concatenate([T.col, roots])
    U = sparse.coo_matrix((np.ones(len(r)), (r, c)), shape=(n + 1, n + 1)).tocsr()
    order, pred = csgraph.breadth_first_order(U, n, directed=False)
    parent = np.arange(n)
    sel = (order < n) & (pred[order] >= 0) & (pred[order] < n)
    parent[order[sel]] = pred[order[sel]]
    sign = np.where(np.einsum("ij,ij->i", N, N[parent]) < 0, -1.0, 1.0)
    sign[parent == np.arange(n)] = 1.0
    par = parent
    for _ in range(64):  # pointer jumping: sign = product of relative signs up to the root
        if np.all(par[par] == par):
            break
        sign = sign * sign[par]
        par = par[par]
    N = N * sign[:, None]
    keep = T.data <= 0.5
    pieces = sparse.coo_matrix((np.ones(int(keep.sum())), (T.row[keep], T.col[keep])), (n, n))
    npieces, plabel = csgraph.connected_components(pieces, directed=False)
    score = np.bincount(plabel, weights=np.einsum("ij,ij->i", N, _radial(V)), minlength=npieces)
    return np.where((score < 0)[plabel][:, None], -N, N)


def _edge_costs(
    N: np.ndarray, var: np.ndarray, nbr: np.ndarray, V: np.ndarray, rows: slice
) -> np.ndarray:
    """:func:`_orient_cloud`'s edge costs (m, k - 1) from the m points ``rows`` to their
    neighbours ``nbr`` (m, k) (the first: the point itself)."""
    # per point and neighbour: no (m·(k - 1), 3) copies of the point's own normal
    Nr, Vr = N[rows], V[rows]
    Nc = N[nbr[:, 1:]]
    dots = np.einsum("nkc,nc->nk", Nc, Nr)
    D = V[nbr[:, 1:]] - Vr[:, None, :]
    L = np.sqrt(np.einsum("nkc,nkc->nk", D, D))
    D = np.divide(D, L[:, :, None], out=np.zeros_like(D), where=(L > 1e-30)[:, :, None])
    across = np.abs(np.einsum("nc,nkc->nk", Nr, D)) + np.abs(np.einsum("nkc,nkc->nk", Nc, D))
    return 1.0 - np.abs(dots) + 0.5 * across + 3.0 * (var[rows, None] + var[nbr[:, 1:]]) + 1e-6


def _cloud_boundary(V: np.ndarray, N: np.ndarray, nbr: np.ndarray, dist: np.ndarray):
    off = V[nbr[:, 1:]].mean(axis=1) - V
    off -= np.einsum("ij,ij->i", off, N)[:, None] * N
    radius = dist[:, -1]
    return row_norms(off) > BOUNDARY_OFFSET * np.maximum(radius, 1e-12)


def _crack_edges(V: np.ndarray, E: np.ndarray, side: np.ndarray | None = None) -> np.ndarray:
    """Which open edges (e, 2) of a mesh are cracks: (e,) bool.

    A crack is an open edge that encloses no gap: every point of it lies on (within
    :data:`CRACK_TOL` × the longer edge's length of) another of the open edges ``E`` whose
    triangle is on the other side (``side`` (e, 3): unit directions from each edge into its
    triangle, across it; zero rows where that is undefined: an edge used by several triangles or
    by a zero-area one; two edges whose sides agree within :data:`CRACK_SAME_SIDE_COS` are a
    doubled rim, not a crack). That is a
    T-junction (a vertex on a neighbour's edge: the edge a–b on one side, a–m and m–b on the
    other, so all three are used once though the surface is closed), a seam of two unwelded
    sides that coincide, and the edges of a zero-area (degenerate) triangle that hangs off the
    surface (used once, or 3 times along the edge it lies on): any boundary loop of ~zero width.
    An edge of a real hole has no other open edge along its whole length (the hole's far side
    is at least a sample spacing away; its neighbours on the rim meet it only at its ends), so
    it is never one; nor is a fin (a triangle standing off an edge).

    Each edge's midpoint is tested first; only the edges it finds on another (few on a real
    scan) have their other points tested: max(3, ceil(length / h)) spread over the interior (h:
    the median open-edge length). A point looks for the other edges among the :data:`K_CRACK`
    nearest (within reach) of points placed on every open edge at most h apart (one cKDTree),
    then measures the exact point-to-segment distance. Vectorised over all edges (blocks of
    :data:`CRACK_CHUNK` points).
    """
    m = len(E)
    crack = np.zeros(m, bool)
    if m < 2:
        return crack
    P0 = V[E[:, 0]]
    D = V[E[:, 1]] - P0
    L = row_norms(D)
    L2 = np.maximum(L * L, 1e-300)
    # spacing of the points: the median edge, raised so that they stay at most ~9 per edge
    h = max(float(np.median(L)), float(L.sum()) / (8.0 * m), 1e-300)

    def spread(count: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points at the centres of ``count`` equal pieces of each of ``edges``; their edge."""
        owner = np.repeat(edges, count)
        j = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
        t = (j + 0.5) / np.repeat(count, count)
        return P0[owner] + t[:, None] * D[owner], owner

    pieces = np.maximum(1, np.ceil(L / h)).astype(np.int64)
    X, x_edge = spread(pieces, np.arange(m))  # every point of an edge is within h / 2 of these
    tree = cKDTree(X)
    k = min(K_CRACK, len(X))
    # a point within CRACK_TOL × max(both lengths) of an edge is within this of its points
    reach = h / 2.0 + CRACK_TOL * float(L.max()) * (1.0 + 1e-9)

    def on_other_edge(Q: np.ndarray, qe: np.ndarray) -> np.ndarray:
        """Whether each point Q (q, 3) of edge qe (q,) lies on another of the edges."""
        out = np.zeros(len(Q), bool)
        for lo in range(0, len(Q), CRACK_CHUNK):
            q, e = Q[lo : lo + CRACK_CHUNK], qe[lo : lo + CRACK_CHUNK]
            _, nb = tree.query(q, k=k, distance_upper_bound=reach, workers=kd_workers())
            i, j = np.nonzero(nb.reshape(len(q), k) < len(X))
            c = x_edge[nb.reshape(len(q), k)[i, j]]
            i, c = i[c != e[i]], c[c != e[i]]
            w = q[i] - P0[c]
            t = np.clip(np.einsum("ij,ij->i", w, D[c]) / L2[c], 0.0, 1.0)
            dist = row_norms(w - t[:, None] * D[c])
            hit = dist <= CRACK_TOL * np.maximum(L[e[i]], L[c])
            if side is not None:
                hit &= np.einsum("ij,ij->i", side[e[i]], side[c]) <= CRACK_SAME_SIDE_COS
            out[lo : lo + CRACK_CHUNK] = np.bincount(i[hit], minlength=len(q)) > 0
        return out

    # the midpoints first: a real hole's edges fail there
    cand = np.flatnonzero(on_other_edge(P0 + 0.5 * D, np.arange(m)))
    if len(cand) == 0:
        return crack
    ns = np.maximum(3, pieces[cand])
    Q, q_edge = spread(ns, cand)  # (t = 1/6, 1/2, 5/6 for a short edge)
    miss = ~on_other_edge(Q, q_edge)
    crack[cand] = np.bincount(q_edge[miss], minlength=m)[cand] == 0
    return crack


def _mesh_boundary(
    V: np.ndarray,
    F: np.ndarray,
    E: np.ndarray,
    counts: np.ndarray,
    edge_faces: np.ndarray,
    decimated: bool,
) -> tuple[np.ndarray, int]:
    """Boundary vertices (n,) bool of a mesh from its undirected edges, their use counts and a
    triangle using each, and how many vertices lie only on cracks (:func:`_crack_edges`), which
    are no boundary.

    Open edges are those not shared by two triangles; after vertex clustering, edges of folded
    (non-manifold) clusters are used 3-5 times: then only edges used once are borders.
    """
    boundary = np.zeros(len(V), bool)
    open_ = counts != 2
    if not open_.any():
        return boundary, 0
    Eo = E[open_]
    # the side of each edge used once: towards its triangle's third corner, across the edge
    a, b = V[Eo[:, 0]], V[Eo[:, 1]]
    c = V[F[edge_faces[open_]].sum(axis=1) - Eo.sum(axis=1)]
    d = b - a
    w = c - a
    w -= (np.einsum("ij,ij->i", w, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300))[
        :, None
    ] * d
    wl = row_norms(w)
    ok = (counts[open_] == 1) & (wl > CRACK_TOL * row_norms(d))  # not a zero-area triangle
    side = np.where(ok[:, None], w / np.where(ok, wl, 1.0)[:, None], 0.0)
    crack = _crack_edges(V, Eo, side)
    border = ~crack & ((counts[open_] == 1) if decimated else True)
    boundary[Eo[border].ravel()] = True
    on_crack = np.zeros(len(V), bool)
    on_crack[Eo[crack].ravel()] = True
    return boundary, int((on_crack & ~boundary).sum())


def _estimate_confidence(
    V: np.ndarray, boundary: np.ndarray, spacing: float, isolated: np.ndarray
) -> np.ndarray:
    """Estimated confidence (n,) in [CONF_MIN, 1]: CONF_MIN on the ``boundary`` (hole rims; not
    the cracks of T-junctions and slivers, :func:`_mesh_boundary`) and at ``isolated`` points,
    rising linearly to 1 over max(:data:`CONF_RAMP_MIN`, 3 × spacing) from the boundary."""
    ramp = max(CONF_RAMP_MIN, 3.0 * spacing)
    conf = np.ones(len(V))
    if boundary.any():
        d, _ = cKDTree(V[boundary]).query(V, k=1, distance_upper_bound=ramp, workers=kd_workers())
        conf = CONF_MIN + (1.0 - CONF_MIN) * np.clip(d / ramp, 0.0, 1.0)
    conf[isolated] = CONF_MIN
    return conf


def prepare_scan(raw: RawMesh, frame: FrameInfo, *, decimate_above: int = DECIMATE_ABOVE) -> Scan:
    """Map a raw scan to the canonical frame and complete it for registration.

    Parameters
    ----------
    raw : RawMesh in the file's units and axes (from :func:`core.io.readers.read_mesh`).
    frame : FrameInfo from :func:`core.io.frame.detect_frame`.
    decimate_above : scans with more vertices are first decimated on a
        :data:`DECIMATE_VOXEL_M` voxel grid (:func:`decimate_voxel_grid`); the notes say so.

    Returns
    -------
    Scan
        Metres, +Y up; ``normals`` (n, 3) unit and outward, ``confidence`` (n,) in [0, 1],
        ``boundary`` (n,) bool; ``notes`` say what was cleaned, removed, estimated or flipped;
        ``removed`` counts the floor and stray points left out (only the body's points are
        kept).
    """
    notes: list[str] = []
    m = apply_frame(raw, frame)
    decimated = len(m.V) > decimate_above
    if decimated:
        n0 = len(m.V)
        m = decimate_voxel_grid(m, DECIMATE_VOXEL_M)
        notes.append(
            f"dense scan: {n0:,} vertices decimated to {len(m.V):,} on a "
            f"{DECIMATE_VOXEL_M * 1000:g} mm voxel grid (vertex clustering) before preparation"
        )
    if m.F is not None and len(m.F):
        m = _clean_mesh(m, notes)
    if m.F is None or len(m.F) == 0:
        m = _clean_cloud(RawMesh(m.V, None, m.normals, m.confidence, m.colors), notes)
    m, non_body = remove_non_body(m)
    notes.extend(non_body.notes)
    V = m.V
    n = len(V)
    F = m.F
    isolated = np.zeros(n, bool)
    if F is not None:
        # consistent, outward winding per component (scanner parts may be wound inward)
        centres = (V[F[:, 0]] + V[F[:, 1]] + V[F[:, 2]]) / 3.0
        repair = orient_components(V, F, centres, _radial(centres))
        F = repair.F
        notes.extend(repair.notes)
        fn = repair.face_normals
        vn = vertex_normals(V, F, fallback=(0.0, 0.0, 0.0), face_normals=fn)
        # a vertex used only by zero-area triangles (height under CRACK_TOL x the edges) has no
        # normal of its own (its sum is rounding noise): it takes the mean of its triangles'
        # other corners' (a sliver's apex: its edge's ends), else the nearest vertex's
        u, w = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
        scale = np.einsum("ij,ij->i", u, u) + np.einsum("ij,ij->i", w, w)
        flat = np.ones(n, bool)
        flat[F[row_norms(fn) > CRACK_TOL * scale].ravel()] = False
        if flat.any():
            Ff = F[flat[F].any(axis=1)]
            acc = np.zeros((n, 3))
            for k in range(3):
                for j in (1, 2):
                    src = Ff[:, (k + j) % 3]
                    np.add.at(acc, Ff[:, k], vn[src] * ~flat[src][:, None])
            vn[flat] = normalize(acc[flat], fallback=(0.0, 0.0, 0.0))
            flat &= row_norms(vn) == 0.0
        if flat.any() and not flat.all():
            _, j = cKDTree(V[~flat]).query(V[flat], workers=kd_workers())
            vn[flat] = vn[~flat][j]
        vn[row_norms(vn) == 0.0] = (0.0, 1.0, 0.0)
        E, counts = repair.edges, repair.edge_counts
        boundary, n_crack = _mesh_boundary(V, F, E, counts, repair.edge_faces, decimated)
        if n_crack:
            notes.append(
                f"{n_crack:,} vertices on cracks of zero width (T-junctions, slivers) "
                "not counted as a boundary"
            )
        el = row_norms(V[E[:, 0]] - V[E[:, 1]])
        spacing = float(np.median(el)) if len(el) else 0.0
        A = sparse.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
        ncomp, label = csgraph.connected_components(A, directed=False)
        if ncomp > 1:
            size = np.bincount(label)
            isolated = size[label] < max(10, 0.001 * n)
        nbr = dist = None
    else:
        k = min(K_BOUNDARY, n)
        if n < 4:
            raise InputFormatError(f"the scan has only {n} distinct points; a body needs many more")
        tree = cKDTree(V)
        dist, nbr = tree.query(V, k=k, workers=-1)
        kn = min(K_NEIGHBOURS, n)
        pn, var = _pca_normals(V, nbr[:, :kn])
        vn = _orient_cloud(pn, var, nbr[:, :kn], V)
        spacing = float(np.median(dist[:, 1]))
        isolated = dist[:, -1] > 5.0 * max(float(np.median(dist[:, -1])), 1e-12)
    if m.normals is not None:
        N = m.normals
        ok = row_norms(N) > 1e-12
        N = np.where(ok[:, None], N, vn)
        N = normalize(N)
        if F is not None:  # per point: the sign of the (repaired) outward winding
            bad = np.einsum("ij,ij->i", N, vn) < 0
            if bad.any():
                N = np.where(bad[:, None], -N, N)
                notes.append(
                    f"normals from the file pointed inward at {int(bad.sum()):,} of {n:,} points "
                    "(against the outward winding); flipped those"
                )
        elif np.einsum("ij,ij->", N, _radial(V)) < 0:
            N = -N
            notes.append("normals from the file pointed inward; flipped all")
        notes.append("normals from file")
    else:
        N = vn
        notes.append("normals computed" if F is not None else "normals estimated (PCA)")
    if F is None:
        # boundary test needs oriented tangent planes only; recompute with final normals
        boundary = _cloud_boundary(V, N, nbr, dist)
    if m.confidence is not None:
        conf = np.clip(np.asarray(m.confidence, float), 0.0, 1.0)
        notes.append("confidence from file")
    else:
        conf = _estimate_confidence(V, boundary, spacing, isolated)
        notes.append("confidence estimated")
    if isolated.any():
        notes.append(f"{int(isolated.sum()):,} isolated points")
    return Scan(
        V=V,
        F=None if F is None else F.astype(np.int64),
        normals=N,
        confidence=conf,
        boundary=boundary,
        frame=frame,
        notes=notes,
        colors=None if m.colors is None else np.asarray(m.colors, dtype=np.uint8),
        removed=non_body.counts,
    )


def load_scan(
    path: str | os.PathLike | bytes,
    *,
    units: str = "auto",
    up: str = "auto",
    markers_path: str | os.PathLike | bytes | None = None,
    fmt: str | None = None,
    max_vertices: int = 5_000_000,
    max_faces: int = 10_000_000,
) -> tuple[Scan, dict[str, np.ndarray] | None]:
    """Read a scan (and optional markers) and prepare it for registration.

    Parameters
    ----------
    path : scan file (or its bytes, then give ``fmt``).
    units : {"auto", "m", "cm", "mm", "in"}; up : {"auto", "+x", "-x", "+y", "-y", "+z", "-z"}.
    markers_path : optional marker file (CSV/JSON) in the scan file's units and axes.
    fmt : scan format, by default from the extension or content.

    Returns
    -------
    (Scan, markers)
        The prepared scan (metres, +Y up) and the markers mapped with the same frame
        (name -> (3,) metres), or None when no marker file was given.
    """
    from core.template import load_template

    raw = read_mesh(path, fmt, max_vertices=max_vertices, max_faces=max_faces)
    markers = None
    if markers_path is not None:
        markers = read_markers(markers_path, valid_names=load_template().landmarks)
    frame = detect_frame(raw.surface()[0], units=units, up=up, markers=markers)
    scan = prepare_scan(raw, frame)
    scan.notes.insert(0, frame.describe(units, up))
    mapped = None
    if markers is not None:
        mapped = {k: frame.to_canonical(np.asarray(v)[None, :])[0] for k, v in markers.items()}
    return scan, mapped
