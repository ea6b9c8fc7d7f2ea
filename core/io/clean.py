"""What a scan holds that is not the body: a floor plate or floor points, and stray blobs.

Booth software leaves a floor plate under closed meshes (a disc reaching 8–15 cm beyond the
feet); raw scans carry floor points around the feet and a few stray blobs (dust, cables, the
booth's frame). Fitted around, they inflate the scan→fit figures and make the quality check blame
a foot. :func:`non_body_points` finds them in the canonical frame (metres, +Y up; either end of
the vertical is tried for the floor, as an auto-detected up axis may be upside down):

- **floor** (an end of the vertical): levels up to :data:`FLOOR_BAND` from the end are tried;
  at each, the points within :data:`LAYER` of it are checked against the *footprint* of what
  stands on it (the points :data:`FOOT_GAP` – :data:`FOOT_GAP` + :data:`FOOT_SLAB` above:
  feet and toes), rasterised on a :data:`CELL` grid, grown by :data:`FOOT_MARGIN` and with
  holes filled (so flat-cut soles lie inside it). A floor is there when a level's points
  outside the footprint cover at least :data:`FLOOR_MIN_AREA` on a plane at most
  :data:`FLOOR_MAX_TILT_DEG` from horizontal. Then every point at or below the layer's top
  (its 99th height percentile above the plane, plus :data:`FLOOR_TOL`) is floor — under the
  feet too (a plate's underside); the feet stand on the floor, so only their lowest
  :data:`FLOOR_TOL` may go with it. A closed mesh with flat-cut soles and no plate has no
  layer outside its feet: nothing is removed (measured on ``core.synth.scanner_outputs``
  cases without a floor: at most 10 cm² outside the footprint; the floor ring of
  raw_clutter-10: 7,900 cm²).
- **stray blobs**: the remaining points are clustered on a :data:`STRAY_VOXEL` grid, voxels
  linked when their centres are within :data:`STRAY_GAP` (point clouds have no connectivity,
  and a raw multi-view scan's arm, hand or head may be a separate mesh component: only the
  spatial gap counts). A cluster other than the largest (the body) is stray when all its points
  are at least :data:`STRAY_GAP` from the body's and the stray clusters together hold at most
  :data:`STRAY_MAX_SHARE` of the points (a head, ~8 %, is never one); a body part separated
  from the rest by less than the gap is never one.

No floor is removed when what would remain is less than :data:`MIN_KEPT_HEIGHT` tall or holds
fewer than :data:`MIN_KEPT_POINTS` points (a floor without a body: ``core.matching.body_check``
refuses it); a body on a floor of many more points than its own is cleaned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from core.geometry import kept_faces
from core.scan import RawMesh

FLOOR_BAND = 0.03  # m; a floor's top lies at most this far from an end of the vertical
LEVEL_STEP = 0.002  # m; levels tried
LAYER = 0.003  # m; points within this of a level form its layer
FOOT_GAP = 0.005  # m; the footprint's slab starts this far above the level...
FOOT_SLAB = 0.03  # m; ...and is this thick (feet and toes standing on the level)
CELL = 0.01  # m; footprint raster cell
FOOT_MARGIN = 0.03  # m; the footprint grows by this (scanner noise, sloping toes)
FLOOR_MIN_AREA = 0.005  # m² (50 cm²) of a layer outside the footprint: a floor
FLOOR_MAX_TILT_DEG = 5.0  # a floor is perpendicular to the up axis within this
FLOOR_TOL = 0.003  # m; points up to this above the floor's top go with it
STRAY_VOXEL = 0.01  # m; clustering grid
STRAY_GAP = 0.03  # m; voxel centres closer than this are linked; a stray cluster's points are
# all at least this far from the main body's
STRAY_MAX_SHARE = 0.05  # clusters apart from the main body hold at most this share: stray
MIN_KEPT_HEIGHT = 0.5  # m; what remains of a scan without its floor is at least this tall...
MIN_KEPT_POINTS = 100  # ...and has at least this many points


@dataclass
class NonBody:
    """What :func:`non_body_points` found.

    keep : (n,) bool, True for the body's points. floor : (n,) bool floor points (plate, floor
    layer); stray : (n,) bool points of stray clusters. floor_end : ``"bottom"``, ``"top"`` or
    None; floor_level_m : height of the floor's top surface (metres, +Y) or None;
    stray_clusters : how many clusters were stray.
    """

    keep: np.ndarray
    floor: np.ndarray
    stray: np.ndarray
    floor_end: str | None = None
    floor_level_m: float | None = None
    stray_clusters: int = 0

    @property
    def counts(self) -> dict[str, int]:
        """``{"floor_points": …, "stray_points": …}``: the report's ``removed``."""
        return {"floor_points": int(self.floor.sum()), "stray_points": int(self.stray.sum())}

    @property
    def notes(self) -> list[str]:
        """What was removed, in words (empty when nothing was)."""
        out = []
        if self.floor.any():
            out.append(
                f"removed {int(self.floor.sum()):,} floor points (a floor layer perpendicular to "
                f"the up axis at the {self.floor_end} of the scan, reaching beyond the feet; its "
                f"top at {self.floor_level_m * 1000:.0f} mm)"
            )
        if self.stray.any():
            out.append(
                f"removed {int(self.stray.sum()):,} stray points ({self.stray_clusters} "
                f"clusters at least {STRAY_GAP * 100:.0f} cm from the body)"
            )
        return out


def _outside(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Which of the horizontal points Q (k, 2) lie outside the footprint of the horizontal
    points P (p, 2) — rasterised on :data:`CELL`, grown by :data:`FOOT_MARGIN`, holes filled —
    (k,) bool."""
    lo = np.minimum(P.min(axis=0), Q.min(axis=0)) - 2 * FOOT_MARGIN
    hi = np.maximum(P.max(axis=0), Q.max(axis=0)) + 2 * FOOT_MARGIN
    shape = tuple(np.ceil((hi - lo) / CELL).astype(np.int64) + 1)
    occ = np.zeros(shape, bool)
    ip = np.floor((P - lo) / CELL).astype(np.int64)
    occ[ip[:, 0], ip[:, 1]] = True
    r = round(FOOT_MARGIN / CELL)
    disc = np.hypot(*np.mgrid[-r : r + 1, -r : r + 1]) <= r
    grown = ndimage.binary_fill_holes(ndimage.binary_dilation(occ, structure=disc))
    iq = np.floor((Q - lo) / CELL).astype(np.int64)
    return ~grown[iq[:, 0], iq[:, 1]]


def _floor_at(V: np.ndarray, sign: float) -> tuple[np.ndarray, float] | None:
    """The floor at the bottom (``sign`` +1) or the top (-1) of the scan V (n, 3), metres, +Y
    up: (n,) bool floor points and the height (+Y) of its top, or None (no floor there).

    Levels ``l`` from the end up to :data:`FLOOR_BAND` are tried in :data:`LEVEL_STEP` steps:
    the points within :data:`LAYER` of ``l`` outside the footprint of the points
    :data:`FOOT_GAP` to :data:`FOOT_GAP` + :data:`FOOT_SLAB` above ``l`` are the floor's
    candidates; the level whose candidates cover the largest area wins if that area is at
    least :data:`FLOOR_MIN_AREA`.
    """
    h = sign * V[:, 1]
    h0 = float(np.percentile(h, 0.01))  # robust to a few outliers beyond the end
    near = np.flatnonzero(h < h0 + FLOOR_BAND + FOOT_GAP + FOOT_SLAB)
    hn, Xz = h[near], V[near][:, [0, 2]]
    best: tuple[float, np.ndarray] | None = None
    for lev in h0 + np.arange(0.0, FLOOR_BAND + 1e-9, LEVEL_STEP):
        layer = np.flatnonzero(np.abs(hn - lev) <= LAYER)
        foot = (hn >= lev + FOOT_GAP) & (hn < lev + FOOT_GAP + FOOT_SLAB)
        if len(layer) < 20 or foot.sum() < 20:
            continue
        cand = layer[_outside(Xz[foot], Xz[layer])]
        if len(cand) < 20:
            continue
        area = len(np.unique(np.floor(Xz[cand] / CELL).astype(np.int64), axis=0)) * CELL**2
        if area >= FLOOR_MIN_AREA and (best is None or area > best[0]):
            best = (area, near[cand])
    if best is None:
        return None
    C = V[best[1]]
    # the layer's plane, height = a x + b z + c (least squares, then again without the 10 %
    # farthest: a foot's edge)
    A = np.c_[C[:, 0], C[:, 2], np.ones(len(C))]
    y = sign * C[:, 1]
    use = np.ones(len(C), bool)
    for _ in range(2):
        coef = np.linalg.lstsq(A[use], y[use], rcond=None)[0]
        res = y - A @ coef
        dev = np.abs(res - np.median(res))
        use = dev <= np.percentile(dev, 90)
    if np.degrees(np.arctan(np.hypot(coef[0], coef[1]))) > FLOOR_MAX_TILT_DEG:
        return None
    top = float(np.percentile(res, 99)) + FLOOR_TOL
    floor = h - (coef[0] * V[:, 0] + coef[1] * V[:, 2] + coef[2]) <= top
    level = sign * float(np.median(A @ coef) + top)
    return floor, level


def _stray(V: np.ndarray) -> tuple[np.ndarray, int]:
    """Points (n,) bool of the clusters apart from the main body (see the module docstring),
    and how many clusters that is."""
    n = len(V)
    cell = np.floor((V - V.min(axis=0)) / STRAY_VOXEL).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    k = len(count)
    centre = np.stack([np.bincount(inv, V[:, j], minlength=k) for j in range(3)], 1)
    centre /= count[:, None]
    pairs = cKDTree(centre).query_pairs(STRAY_GAP, output_type="ndarray")
    G = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(k, k))
    ncl, lab = connected_components(G, directed=False)
    none = np.zeros(n, bool), 0
    if ncl == 1:
        return none
    size = np.bincount(lab, weights=count, minlength=ncl)
    main = int(np.argmax(size))
    plab = lab[inv]
    # voxel centres are not the points: a cluster is stray only if every one of its points is
    # at least the gap from the main body's points. A point lies within sqrt(3) voxels of its
    # voxel's centre, so only voxels whose centres are within the gap plus two of those of a
    # voxel of the other side can hold such a pair; the exact test runs on their points only.
    reach = STRAY_GAP + 2.0 * np.sqrt(3.0) * STRAY_VOXEL
    main_vox = np.flatnonzero(lab == main)
    other_vox = np.flatnonzero(lab != main)
    d, _ = cKDTree(centre[main_vox]).query(centre[other_vox], distance_upper_bound=reach)
    other_vox = other_vox[np.isfinite(d)]
    near = np.zeros(0, np.int64)
    if len(other_vox):
        d, _ = cKDTree(centre[other_vox]).query(centre[main_vox], distance_upper_bound=reach)
        main_vox = main_vox[np.isfinite(d)]
        in_other = np.zeros(k, bool)
        in_other[other_vox] = True
        in_main = np.zeros(k, bool)
        in_main[main_vox] = True
        other = np.flatnonzero(in_other[inv])
        d, _ = cKDTree(V[in_main[inv]]).query(V[other], distance_upper_bound=STRAY_GAP)
        near = np.unique(plab[other[np.isfinite(d)]])
    stray = np.zeros(ncl, bool)
    stray[np.setdiff1d(np.arange(ncl), np.r_[near, main])] = True
    if not stray.any() or size[stray].sum() > STRAY_MAX_SHARE * n:
        return none
    return stray[plab], int(stray.sum())


def non_body_points(V: np.ndarray) -> NonBody:
    """Floor and stray-blob points of a scan V (n, 3), metres, +Y up (module docstring)."""
    V = np.asarray(V, dtype=np.float64)
    n = len(V)
    none = np.zeros(n, bool)
    out = NonBody(keep=np.ones(n, bool), floor=none.copy(), stray=none.copy())
    if n < 100:
        return out
    best = None
    for sign, end in ((1.0, "bottom"), (-1.0, "top")):
        got = _floor_at(V, sign)
        if got is not None and (best is None or got[0].sum() > best[0].sum()):
            best = (*got, end)
    left = None if best is None else V[~best[0], 1]
    if left is not None and len(left) >= MIN_KEPT_POINTS and np.ptp(left) >= MIN_KEPT_HEIGHT:
        out.floor, out.floor_level_m, out.floor_end = best
    rest = np.flatnonzero(~out.floor)
    if len(rest) >= 100:
        st, ncl = _stray(V[rest])
        if st.any():
            out.stray[rest[st]] = True
            out.stray_clusters = ncl
    out.keep = ~(out.floor | out.stray)
    return out


def remove_non_body(m: RawMesh) -> tuple[RawMesh, NonBody]:
    """``m`` (metres, +Y up) without its floor and stray points (:func:`non_body_points`).

    Triangles with a removed corner go; so do vertices left without a triangle (a mesh's row
    along the cut, counted with the floor or stray points they touched). Returns the kept mesh
    (arrays subset, triangles re-indexed) and what was found (its ``keep`` over ``m.V``).
    """
    nb = non_body_points(m.V)
    if nb.keep.all():
        return m, nb
    keep = nb.keep
    F = m.F
    if F is not None and len(F):
        F = F[keep[F].all(axis=1)]
        used = np.zeros(len(keep), bool)
        used[F.ravel()] = True
        orphan = keep & ~used
        if orphan.any():  # the cut's row: with whichever removal its triangles touched
            tri = m.F[orphan[m.F].any(axis=1)]
            by_stray = np.zeros(len(keep), bool)
            by_stray[tri[nb.stray[tri].any(axis=1)].ravel()] = True
            nb.stray |= orphan & by_stray
            nb.floor |= orphan & ~by_stray
            keep = nb.keep = ~(nb.floor | nb.stray)
        F = kept_faces(F, keep)  # (orphans have no faces: only the renumbering)
    sub = RawMesh(
        V=m.V[keep],
        F=F,
        normals=None if m.normals is None else m.normals[keep],
        confidence=None if m.confidence is None else m.confidence[keep],
        colors=None if m.colors is None else m.colors[keep],
    )
    return sub, nb


__all__ = ["NonBody", "non_body_points", "remove_non_body"]
