"""Orientation repair of raw meshes: consistent winding per component, outward normals.

Scanner software often delivers meshes whose parts are wound differently (a raw multi-view scan
with both arms' faces wound inward, a body merged with a hair or floor component wound the other
way). One global flip cannot fix that. Per edge-connected patch of triangles we

1. make the winding **consistent**: two triangles sharing a manifold edge must traverse it in
   opposite directions; a breadth-first tree over the patch's triangles propagates one
   orientation (relative flips multiplied up to the root by pointer jumping);
2. make it **outward**: a closed patch (no boundary edge) by the sign of its enclosed volume; an
   open one (at least :data:`OWN_SHARE` of the area) that is clearly a tube or shell about its
   own centroid (an arm: area-weighted mean cosine between normals and directions from the
   centroid ≥ :data:`DECISIVE`, not contradicted by the body's vertical axis) by that; every
   other open patch keeps the winding of most of the area, judged by the normals pointing away
   from the vertical axis (a small patch may face the axis legitimately: an inner thigh seen
   between the legs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from core.geometry import face_normals, row_norms

#: Smallest |area-weighted mean cosine| between normals and directions from an open patch's
#: centroid (or from the vertical axis) that counts as evidence of its side.
DECISIVE = 0.2
#: Smallest share of the total area of an open patch that may decide its own side.
OWN_SHARE = 0.002


@dataclass
class OrientationRepair:
    """What :func:`orient_components` changed.

    F : (m, 3) int64 triangles, consistently wound and facing outward per patch.
    n_patches : edge-connected triangle patches; n_rewound : patches whose winding was
    inconsistent (some triangles flipped); n_flipped : patches turned to face outward;
    triangles_flipped : triangles whose winding changed in total.
    edges : (e, 2) int64 undirected edges (sorted endpoints); edge_counts : (e,) triangles using
    each (as :func:`core.io._geometry.edge_use_counts`, computed on the way); edge_faces : (e,)
    int64 a triangle using each edge (the only one of an edge used once); face_normals : (m, 3)
    of the repaired triangles, length twice the area.
    """

    F: np.ndarray
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    edge_counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    face_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    n_patches: int = 0
    n_rewound: int = 0
    n_flipped: int = 0
    triangles_flipped: int = 0
    notes: list[str] = field(default_factory=list)


def _patches_and_relative_signs(
    F: np.ndarray,
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Edge-connected patches of triangles and, per triangle, the flip (±1) that makes its
    patch consistently wound; which triangles have a boundary (single-use) edge; the undirected
    edges, their use counts and a triangle using each."""
    m = len(F)
    a = np.ascontiguousarray(F, dtype=np.int64)  # (m, 3): half-edge 3 f + k is a[f, k] -> b[f, k]
    b = a[:, [1, 2, 0]]
    lo, hi = np.minimum(a, b).ravel(), np.maximum(a, b).ravel()
    n = int(F.max()) + 1
    key = lo * n + hi
    # group the half-edges by key: one value sort of key and half-edge index packed into an
    # int64 (several times faster than argsort) where they fit, else an argsort
    shift = int(3 * m - 1).bit_length()
    if (n * n - 1).bit_length() + shift <= 62:
        packed = np.sort((key << shift) | np.arange(3 * m, dtype=np.int64))
        ks, order = packed >> shift, packed & ((1 << shift) - 1)
    else:
        order = np.argsort(key)  # equal keys need no order: a group is used as a whole
        ks = key[order]
    start = np.empty(len(ks), bool)
    start[0] = True
    np.not_equal(ks[1:], ks[:-1], out=start[1:])
    first = np.flatnonzero(start)
    count = np.diff(np.r_[first, len(ks)])
    uk = ks[first]
    E = np.stack([uk // n, uk % n], axis=1)
    fo = order // 3  # triangle of each sorted half-edge
    on_boundary = np.zeros(m, bool)
    on_boundary[fo[first[count == 1]]] = True
    # manifold edges: exactly two uses -> a pair of adjacent triangles
    two = first[count == 2]
    f1, f2 = fo[two], fo[two + 1]
    fwd = (a < b).ravel()
    same_dir = fwd[order[two]] == fwd[order[two + 1]]  # inconsistent winding
    rel = np.where(same_dir, -1.0, 1.0)
    G = sparse.coo_matrix((np.ones(len(f1)), (f1, f2)), shape=(m, m)).tocsr()
    n_patch, label = csgraph.connected_components(G, directed=False)
    if not same_dir.any():  # consistently wound already (the common case)
        return n_patch, label, np.ones(m), on_boundary, E, count, fo[first]
    roots = np.unique(label, return_index=True)[1]
    r = np.r_[f1, np.full(len(roots), m)]
    c = np.r_[f2, roots]
    U = sparse.coo_matrix((np.ones(len(r)), (r, c)), shape=(m + 1, m + 1)).tocsr()
    order_bfs, pred = csgraph.breadth_first_order(U, m, directed=False)
    parent = np.arange(m)
    sel = (order_bfs < m) & (pred[order_bfs] >= 0) & (pred[order_bfs] < m)
    parent[order_bfs[sel]] = pred[order_bfs[sel]]
    # relative sign of each triangle to its tree parent (looked up by the sorted pair key)
    pk = np.minimum(f1, f2) * m + np.maximum(f1, f2)
    po = np.argsort(pk)
    pk, prel = pk[po], rel[po]
    idx = np.flatnonzero(parent != np.arange(m))
    q = np.minimum(idx, parent[idx]) * m + np.maximum(idx, parent[idx])
    sign = np.ones(m)
    sign[idx] = prel[np.minimum(np.searchsorted(pk, q), len(pk) - 1)]
    par = parent
    for _ in range(64):  # pointer jumping: product of relative signs up to the root
        if np.all(par[par] == par):
            break
        sign = sign * sign[par]
        par = par[par]
    return n_patch, label, sign, on_boundary, E, count, fo[first]


def orient_components(
    V: np.ndarray, F: np.ndarray, centres: np.ndarray, radial: np.ndarray
) -> OrientationRepair:
    """Consistent, outward winding per edge-connected patch (see the module docstring).

    Parameters
    ----------
    V : (n, 3) vertices, metres, +Y up. F : (m, 3) int triangles; centres : (m, 3) their
    centroids.
    radial : (m, 3) unit horizontal directions from the body's vertical axis to each triangle's
        centre (the fallback "outward" of open patches).
    """
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return OrientationRepair(F=F)
    if len(centres) != len(F) or len(radial) != len(F):
        raise ValueError("centres and radial need one row per triangle")
    n_patch, label, sign, on_boundary, E, counts, edge_faces = _patches_and_relative_signs(F)
    fn = face_normals(V, F)  # length 2·area
    area = row_norms(fn)
    # the tree's root is arbitrary: keep the original winding of most of each patch's area
    if (sign < 0).any():
        keep_share = np.bincount(label, area * (sign > 0), minlength=n_patch)
        sign = (
            sign
            * np.where(2 * keep_share < np.bincount(label, area, minlength=n_patch), -1, 1)[label]
        )
    flip = sign < 0
    rewound = np.unique(label[flip]) if flip.any() else np.zeros(0, np.int64)
    F = np.where(flip[:, None], F[:, [0, 2, 1]], F)
    fn = np.where(flip[:, None], -fn, fn)
    # closed patches: enclosed volume (about the patch's centroid, for precision)
    cw = np.stack(
        [np.bincount(label, area * centres[:, k], minlength=n_patch) for k in range(3)], 1
    )
    cw /= np.maximum(np.bincount(label, area, minlength=n_patch), 1e-300)[:, None]
    d = centres - cw[label]
    dist = np.maximum(np.sqrt(np.einsum("ij,ij->i", d, d)), 1e-300)
    vol = np.bincount(label, np.einsum("ij,ij->i", fn, d), minlength=n_patch)
    closed = np.bincount(label, on_boundary, minlength=n_patch) == 0
    self_cos = np.bincount(
        label, np.einsum("ij,ij->i", fn, d) / dist, minlength=n_patch
    ) / np.maximum(np.bincount(label, area, minlength=n_patch), 1e-300)
    axis_score = np.bincount(label, np.einsum("ij,ij->i", fn, radial), minlength=n_patch)
    p_area = np.maximum(np.bincount(label, area, minlength=n_patch), 1e-300)
    axis_cos = axis_score / p_area
    # default: the winding of most of the area, judged by the axis (scanners wind consistently;
    # a small patch facing the axis, an inner thigh, is no evidence against it)
    majority_in = axis_score.sum() < 0
    # an open patch overrides it only when it is clearly a tube or a shell around its own
    # centroid (an arm) and the axis does not clearly say otherwise
    own = (
        (p_area >= OWN_SHARE * p_area.sum())
        & (np.abs(self_cos) >= DECISIVE)
        & ~((np.abs(axis_cos) >= DECISIVE) & (np.sign(axis_cos) != np.sign(self_cos)))
    )
    inward = np.where(closed, vol < 0, np.where(own, self_cos < 0, majority_in))
    # a patch whose winding was mixed has no original side to keep: the axis decides if it can
    mixed = np.zeros(n_patch, bool)
    mixed[rewound] = True
    by_axis = mixed & ~closed & ~own & (np.abs(axis_cos) >= DECISIVE)
    inward = np.where(by_axis, axis_cos < 0, inward)
    turn = inward[label]
    F = np.where(turn[:, None], F[:, [0, 2, 1]], F)
    out = OrientationRepair(
        F=F,
        face_normals=np.where(turn[:, None], -fn, fn),
        edges=E,
        edge_counts=counts,
        edge_faces=edge_faces,
        n_patches=int(n_patch),
        n_rewound=len(rewound),
        n_flipped=int(inward.sum()),
        triangles_flipped=int(np.sum(flip ^ turn)),
    )
    if len(rewound):
        out.notes.append(
            f"winding made consistent in {len(rewound)} of {n_patch} components "
            f"({int(flip.sum()):,} triangles)"
        )
    if inward.any():
        out.notes.append(
            f"normals of {int(inward.sum())} of {n_patch} components pointed inward: flipped"
        )
    return out
