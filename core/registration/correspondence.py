"""Closest *compatible* scan point for each template vertex (the data term's correspondences).

Compatible (Allen et al. 2003, §3): surface normals less than ``max_angle_deg`` apart and the point
within ``max_distance``. The data weight ``w_i`` is the scan's confidence ramp at that point, and 0
where the point lies on a hole boundary (so holes are filled by smoothness, not pulled to rims).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from core.geometry import vertex_areas, vertex_normals
from core.scan import Scan
from core.threads import kd_workers

#: Points per leaf of the scan's KD-tree (scipy's default 16). raw-35's markerless fit with a
#: retry (tests/core/test_markerless_speed.py), alternating runs: 7.37-7.57 s CPU with 32 vs
#: 7.86-8.00 s with 16; the search's queries alone 0.36 vs 0.52 s (64: 0.30 s, but slower on
#: the refinement's near ones).
KD_LEAFSIZE = 32
#: A mesh decimated from a finer surface (quadric edge collapse: its vertices stay on that surface,
#: few where it is flat, many where it bends) is read by its detail, not its sampling
#: (:attr:`ScanIndex.decimated`, :attr:`ScanIndex.resolution_m`). It shows in two spreads over a
#: fixed sample of vertices (90th over 10th percentile): of the distance to the nearest
#: neighbour, below this (``core.synth.scanner_outputs``' decimated meshes 2.7-3.0; marching
#: cubes 5-9, its vertices on the grid's edges; raw range scans 4.8-5.1; uniform random samples
#: 3) ...
DECIMATED_NEAREST_SPREAD_MAX = 3.5
#: ... and of the mean distance to the 8 nearest, at least this: the density follows the
#: surface's bends (decimated meshes 1.40-1.65; vertex clustering on a 8-12 mm grid, whose
#: cell means shrink the ends like a coarse grid does, 1.19-1.25; marching cubes 1.36-1.40 and
#: raw scans 1.25-1.31, both ruled out by the first spread). ``core.io.prepare.
#: decimate_voxel_grid``'s 4 mm clustering of big scans reads 2.0 / below this: not decimated.
DECIMATED_LOCAL_SPREAD_MIN = 1.32
#: The detail (metres) taken for a decimated mesh sampled coarser than it. On the truths
#: of ``core.synth.scanner_outputs``' decimated meshes (16 bodies from 5 and 7 mm grids, 12-20 k
#: vertices, sampling 7-8 mm) the scanned toes end 1-8 mm short of the truth's (mean 4.4: the
#: toe allowance's at 3.25 mm) and the mittens 0-3 (mean 1.3: the fingertip allowance's floor),
#: not the 14.6 and 9.5 mm that their sampling gave (``foot_end.toe_allowance``,
#: ``hand_length.tip_allowance``); 3 mm: toes 0.5 mm short on average, hands 2.3 long.
#: Decimated to 5 k vertices they still end 1-7.5 mm short. Vertex clustering on a 10-12 mm grid
#: leaves them 2-6 and 5-14 mm short: read by its sampling, as before.
DECIMATED_RESOLUTION_M = 0.003
#: Scan confidence at which a point's data weight reaches 1 (the paper's 0.2).
CONFIDENCE_FULL_AT = 0.2


#: A scan point stands for at most this many times the median point's area in
#: :func:`area_spread_sample` (a few huge triangles, a floor's or a bridged gap's, do not take
#: the sample).
AREA_SPREAD_CAP = 8.0


def area_spread_sample(
    V: np.ndarray, F: np.ndarray | None, n: int, ids: np.ndarray | None = None
) -> np.ndarray:
    """Indices of ``n`` scan points (of ``ids``; default all) spread over the surface by the area
    each stands for, in file order: the points at even steps of their cumulative area (a third of
    their triangles', at most :data:`AREA_SPREAD_CAP` × the median), so one standing for twice
    the area is picked twice as often (repeats allowed); points no triangle uses are never
    picked. A point cloud (``F`` None or empty), or fewer points than ``n``: an even stride.

    A decimated mesh keeps few vertices where it is flat and many where it bends: an even stride
    over its vertices weighed a heavy body's buttocks and knees over its thighs, and the closed
    meshes hole-filled from a raw scan and decimated (``closed_filled`` of
    ``core.synth.scanner_outputs``) had their thighs fitted turned 13-18° about their axes.
    """
    ids = np.arange(len(V)) if ids is None else np.asarray(ids, dtype=np.int64)
    if F is None or len(F) == 0 or len(ids) <= n:
        return ids[np.linspace(0, len(ids) - 1, min(n, len(ids))).astype(np.int64)]
    a = vertex_areas(np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64))[ids]
    pos = a[a > 0]
    if len(pos) == 0:
        return ids[np.linspace(0, len(ids) - 1, n).astype(np.int64)]
    c = np.cumsum(np.minimum(a, AREA_SPREAD_CAP * float(np.median(pos))))
    steps = (np.arange(n) + 0.5) * (c[-1] / n)
    return ids[np.minimum(np.searchsorted(c, steps), len(ids) - 1)]


def confidence_weight(c: np.ndarray, full_at: float = CONFIDENCE_FULL_AT) -> np.ndarray:
    """Paper's confidence ramp: 0 at c ≤ 0, 1 at c ≥ ``full_at``, linear between. (n,) → (n,)."""
    return np.clip(np.asarray(c, dtype=np.float64) / full_at, 0.0, 1.0)


@dataclass
class Correspondences:
    """Targets and weights for the data term.

    Attributes
    ----------
    targets : (n, 3) target positions (scan units), the closest compatible point projected onto
        its tangent plane; undefined where ``weights == 0``.
    weights : (n,) data weights w_i in [0, 1].
    distances : (n,) distance to the matched point (inf where none was compatible).
    on_boundary : (n,) bool, the matched point lies on a hole boundary.
    point_ids : (n,) index of the matched scan point (meaningless where ``weights == 0``).
    """

    targets: np.ndarray
    weights: np.ndarray
    distances: np.ndarray
    on_boundary: np.ndarray
    point_ids: np.ndarray


class ScanIndex:
    """A scan with a KD-tree, ready for repeated correspondence queries."""

    def __init__(self, scan: Scan, *, confidence_full_at: float = CONFIDENCE_FULL_AT) -> None:
        self.scan = scan
        self.confidence_full_at = confidence_full_at
        self.points = np.ascontiguousarray(scan.V, dtype=np.float64)
        self.normals = np.ascontiguousarray(scan.normals, dtype=np.float64)
        self.point_weight = confidence_weight(scan.confidence, confidence_full_at)
        self.boundary = np.asarray(scan.boundary, dtype=bool)
        self.tree = cKDTree(self.points, leafsize=KD_LEAFSIZE)
        self._spread: dict[int, np.ndarray] = {}

    def spread_sample(self, n: int, ids: np.ndarray | None = None) -> np.ndarray:
        """Indices of ``n`` scan points (of ``ids``; default all, cached per ``n``) for the
        scan→body terms: spread over the surface by area on a :attr:`decimated` mesh
        (:func:`area_spread_sample`), an even stride on anything else. A raw scan's triangles
        are largest where its range images graze the skin (their noisiest points): spread by
        area, ``bench.realworld``'s raw-19 was fitted 10.4 mm off the truth instead of 6.3."""
        if ids is None and n in self._spread:
            return self._spread[n]
        got = area_spread_sample(self.points, self.scan.F if self.decimated else None, n, ids)
        if ids is None:
            self._spread[n] = got
        return got

    @cached_property
    def _neighbour_distances(self) -> np.ndarray:
        """(≤ 3000, 8) distances (metres) from a fixed sample of points to their 8 nearest
        neighbours (inf where the scan has fewer points)."""
        n = len(self.points)
        if n < 2:
            return np.zeros((1, 8))
        rng = np.random.default_rng(0)
        sample = self.points[rng.choice(n, min(3000, n), replace=False)]
        d, _ = self.tree.query(sample, k=9, workers=kd_workers())
        return d[:, 1:]

    @cached_property
    def spacing_m(self) -> float:
        """The scan's sampling: median distance (metres) from a point to its nearest neighbour,
        over up to 3000 points (a fixed sample). Raw multi-view scans read 1.7 mm, closed meshes
        of 60-100 k vertices 2.7-2.9, booth meshes of 10-20 k vertices 4.9-7.3
        (``core.synth.scanner_outputs``)."""
        return float(np.median(self._neighbour_distances[:, 0]))

    @cached_property
    def decimated(self) -> bool:
        """Whether the scan is a mesh decimated from a finer surface: its vertices evenly spread
        (:data:`DECIMATED_NEAREST_SPREAD_MAX`) and denser where it bends
        (:data:`DECIMATED_LOCAL_SPREAD_MIN`)."""
        if self.scan.F is None or len(self.scan.F) == 0 or len(self.points) < 100:
            return False
        d = self._neighbour_distances
        p10, p90 = np.percentile(d[:, 0], [10, 90])
        q10, q90 = np.percentile(d.mean(axis=1), [10, 90])
        return bool(
            p90 < DECIMATED_NEAREST_SPREAD_MAX * p10 and q90 >= DECIMATED_LOCAL_SPREAD_MIN * q10
        )

    @cached_property
    def resolution_m(self) -> float:
        """The detail the scan's surface holds (metres), which rounds off fingertips and toes:
        its sampling (:attr:`spacing_m`), but at most :data:`DECIMATED_RESOLUTION_M` on a
        :attr:`decimated` mesh (a decimated mesh's 8 mm sampling is not its detail)."""
        if self.decimated:
            return min(self.spacing_m, DECIMATED_RESOLUTION_M)
        return self.spacing_m

    @cached_property
    def closing_radius_m(self) -> float:
        """Radius (metres) of the ball that reaches the whole scan surface from outside: what a
        closed mesh's software bridged (:func:`core.registration.closed_concavities.
        scan_closing_radius`); 0 for a raw scan or one with holes."""
        from core.registration.closed_concavities import scan_closing_radius

        return scan_closing_radius(
            self.points, self.normals, self.tree, self.spacing_m, self.boundary
        )

    def closest_compatible(
        self,
        X: np.ndarray,
        N: np.ndarray,
        *,
        max_distance: float,
        max_angle_deg: float = 90.0,
        k: int = 10,
        project: bool = True,
        smooth_radius: float = 0.003,
        rim_tolerance: float = 0.0015,
    ) -> Correspondences:
        """Match deformed template vertices X (n, 3) with unit normals N (n, 3) to the scan.

        Takes, among the ``k`` nearest scan points within ``max_distance``, the nearest whose
        normal is within ``max_angle_deg`` of the template normal. With ``project``, the target
        is X moved along that point's normal onto the locally averaged scan surface
        (``smooth_radius``, metres, 0 for the single matched tangent plane). A boundary point
        gives way to a compatible interior point at most ``rim_tolerance`` (metres) farther:
        in merged multi-view scans one view's rim lies inside another view's coverage.
        """
        k = max(1, min(k, len(self.points)))
        cos_lim = float(np.cos(np.deg2rad(max_angle_deg)))
        if project or k == 1:
            return self._match(
                X, N, max_distance, cos_lim, k, project, smooth_radius, rim_tolerance
            )
        # Without projection only the chosen point matters: where the nearest point is
        # compatible and interior it is the choice (the k-neighbour rule picks it first), so
        # one nearest-point query settles most vertices and the k query runs on the rest only
        # (identical result).
        n = len(X)
        d1, j1 = self.tree.query(X, k=1, distance_upper_bound=max_distance, workers=kd_workers())
        valid = np.isfinite(d1)
        jm = np.where(valid, j1, 0)
        dots = np.einsum("nc,nc->n", self.normals[jm], N)
        done = ~valid | ((dots > cos_lim) & ~self.boundary[jm])
        out = Correspondences(
            targets=self.points[jm],
            weights=np.where(valid, self.point_weight[jm], 0.0),
            distances=np.where(valid, d1, np.inf),
            on_boundary=np.zeros(n, dtype=bool),
            point_ids=jm,
        )
        redo = np.flatnonzero(~done)
        if len(redo):
            sub = self._match(
                X[redo], N[redo], max_distance, cos_lim, k, False, smooth_radius, rim_tolerance
            )
            out.targets[redo] = sub.targets
            out.weights[redo] = sub.weights
            out.distances[redo] = sub.distances
            out.on_boundary[redo] = sub.on_boundary
            out.point_ids[redo] = sub.point_ids
        return out

    def _match(
        self,
        X: np.ndarray,
        N: np.ndarray,
        max_distance: float,
        cos_lim: float,
        k: int,
        project: bool,
        smooth_radius: float,
        rim_tolerance: float,
    ) -> Correspondences:
        """:meth:`closest_compatible` from the ``k`` nearest points of every vertex."""
        n = len(X)
        d, j = self.tree.query(X, k=k, distance_upper_bound=max_distance, workers=kd_workers())
        if k == 1:
            d, j = d[:, None], j[:, None]
        valid = np.isfinite(d)
        jj = np.where(valid, j, 0)
        dots = np.einsum("nkc,nc->nk", self.normals[jj], N)
        ok = valid & (dots > cos_lim)
        has = ok.any(axis=1)
        first = np.argmax(ok, axis=1)
        # Overlapping views: a view's rim is not a hole where another view covers it. When a
        # compatible interior point is (almost) as close as the nearest compatible point, use
        # it; only where the rim is clearly nearest is the vertex over a real hole.
        interior = ok & ~self.boundary[jj]
        has_int = interior.any(axis=1)
        first_int = np.argmax(interior, axis=1)
        rows = np.arange(n)
        near_enough = has_int & (d[rows, first_int] <= d[rows, first] + rim_tolerance)
        first = np.where(near_enough, first_int, first)
        jm = jj[rows, first]
        dist = np.where(has, d[rows, first], np.inf)
        P = self.points[jm]
        if project:
            # Target: X moved along the matched normal onto the local surface, whose offset is
            # a Gaussian-weighted mean over the compatible neighbours' tangent planes (this
            # averages the scanner's range noise instead of fitting it).
            Np = self.normals[jm]
            offs = np.einsum("nkc,nkc->nk", X[:, None, :] - self.points[jj], self.normals[jj])
            dk = np.where(ok, d, np.inf)
            d0 = np.where(has, dist, 0.0)[:, None]
            gw = np.where(ok, np.exp(-(((dk - d0) / max(smooth_radius, 1e-9)) ** 2)), 0.0)
            gw_sum = np.maximum(gw.sum(axis=1), 1e-12)
            off = np.sum(gw * offs, axis=1) / gw_sum
            off = np.where(has, off, 0.0)
            P = X - off[:, None] * Np
        on_b = has & self.boundary[jm]
        w = np.where(has & ~on_b, self.point_weight[jm], 0.0)
        return Correspondences(targets=P, weights=w, distances=dist, on_boundary=on_b, point_ids=jm)

    def distance_to_points(self, X: np.ndarray) -> np.ndarray:
        """Distance (n,) from each of X (n, 3) to the nearest scan point."""
        d, _ = self.tree.query(X, k=1, workers=kd_workers())
        return d


def normal_line_targets(
    targets: np.ndarray,
    X0: np.ndarray,
    N0: np.ndarray,
    max_offset: float,
    smoother: sp.csr_matrix | None = None,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The data term's targets moved onto the body prior's normal lines.

    Each target (n, 3) is replaced by the point of the line through the body prior's vertex
    ``X0`` (n, 3) along its unit normal ``N0`` (n, 3) at the target's offset along that normal:
    the data say how far out the skin lies, the body prior where along the surface it belongs.
    A target farther than ``max_offset`` (metres) from that line is kept as it is and flagged:
    it is no skin over the vertex (the caller drops it). With ``smoother`` ((n, n),
    :func:`offset_smoother`) the offsets are its weighted means (``weights`` (n,): the data's,
    0 where none) over the flagged-near targets, so that a coarse scan sets only what it
    resolves and the body prior keeps its finer detail.
    Returns the targets (n, 3) and (n,) bool: those within ``max_offset`` of their line.
    """
    d = np.einsum("ij,ij->i", targets - X0, N0)
    on_line = X0 + d[:, None] * N0
    near = np.linalg.norm(targets - on_line, axis=1) < max_offset
    if smoother is not None:
        w = (np.ones(len(d)) if weights is None else np.asarray(weights, float)) * near
        num, den = smoother @ (w * d), smoother @ w
        d = np.where(den > 0, num / np.where(den > 0, den, 1.0), d)
        on_line = X0 + d[:, None] * N0
    return np.where(near[:, None], on_line, targets), near


def offset_smoother(X0: np.ndarray, N0: np.ndarray, sigma: float) -> sp.csr_matrix:
    """(n, n) Gaussian weights (scale ``sigma``, metres; cut at 2 sigma) between the vertices
    X0 (n, 3) whose unit normals N0 (n, 3) agree (dot > 0.5: not across a lip or an ear's
    rim), each vertex with itself at weight 1: the smoothing of :func:`normal_line_targets`."""
    n = len(X0)
    pairs = cKDTree(X0).query_pairs(2.0 * sigma, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    keep = np.einsum("ij,ij->i", N0[i], N0[j]) > 0.5
    i, j = i[keep], j[keep]
    g = np.exp(-np.sum((X0[i] - X0[j]) ** 2, axis=1) / (2.0 * sigma**2))
    rows = np.r_[i, j, np.arange(n)]
    cols = np.r_[j, i, np.arange(n)]
    return sp.csr_matrix((np.r_[g, g, np.ones(n)], (rows, cols)), shape=(n, n))


#: A point within this distance (metres) of the first fitted body whose normal points against
#: the body's (dot below :data:`AGAINST_BODY_DOT`) is turned (:func:`normals_against_body`).
NORMAL_CHECK_M = 0.05
AGAINST_BODY_DOT = -0.5
#: Fewer turned points than this are left as estimated (noise, thin gaps; most clouds' hands
#: turn 0.7-1.2 k points).
MIN_TURNED_NORMALS = 200


def normals_against_body(scan: Scan, X: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n,) bool: the scan's points whose normal points into the body ``X`` (13380, 3) fitted to
    them: within :data:`NORMAL_CHECK_M` of its nearest vertex, against that vertex's normal
    (dot < :data:`AGAINST_BODY_DOT`); F (m, 3): the body's triangles. A point cloud's normals
    are estimated (PCA) and oriented by propagation over the points, which can turn a whole limb
    over (``bench.realworld --wide``: cloud_wide-505/511/517's left leg, 62-99 % of its points,
    flipped at the crotch); the data term then finds no compatible points there (the left foot
    26-63 mm off, ``failed``)."""
    N_body = vertex_normals(X, np.asarray(F, dtype=np.int64))
    d, nearest = cKDTree(X).query(scan.V, workers=kd_workers())
    dots = np.einsum("ij,ij->i", scan.normals, N_body[nearest])
    return (d < NORMAL_CHECK_M) & (dots < AGAINST_BODY_DOT)


def turn_normals_against_body(
    scan: Scan, X: np.ndarray, F: np.ndarray, what: str, min_turned: float = MIN_TURNED_NORMALS
) -> str:
    """Turn, in place, the scan's normals that point into the body ``X`` (13380, 3; F its
    triangles; :func:`normals_against_body`) where at least ``min_turned`` do; returns the
    report's note, naming the body as ``what`` ("" where none were turned)."""
    turned = normals_against_body(scan, X, F)
    if turned.sum() < min_turned:
        return ""
    scan.normals = np.where(turned[:, None], -scan.normals, scan.normals)
    return (
        f"normals turned at {int(turned.sum()):,} of {len(turned):,} points: their "
        f"estimated orientation pointed into {what}"
    )


def other_foot_matches(
    X: np.ndarray,
    rows: np.ndarray,
    targets: np.ndarray,
    toe_side: np.ndarray,
    foot_side: np.ndarray,
) -> np.ndarray:
    """(len(rows),) bool: data pairs (vertex ``rows[i]`` of the body ``X`` (n, 3), scan point
    ``targets[i]``) of a toe whose point lies nearer to the other foot of ``X`` than to its own:
    with the feet close together a foot's toes would take the other foot's data. ``toe_side``
    (n,) int: 1 / 2 for the left / right foot's toe vertices, 0 for the rest; ``foot_side``
    (n,) int: the same for every vertex of each foot."""
    out = np.zeros(len(rows), bool)
    s = toe_side[rows]
    chk = np.flatnonzero(s > 0)
    if len(chk) == 0:
        return out
    feet = np.flatnonzero(foot_side > 0)
    _, j = cKDTree(X[feet]).query(targets[chk], workers=kd_workers())
    out[chk] = foot_side[feet[j]] != s[chk]
    return out
