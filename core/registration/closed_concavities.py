"""Concavities that scanner software closes: where a closed mesh's surface is not the skin.

Booth-scanner software delivers watertight meshes whose surface bridges every gap narrower than
its hole filling reaches: armpits and the crotch webbed, eye sockets, ears and the gaps between
fingers and toes filled, the gluteal and breast folds smoothed over. Such a surface is
*accessible* everywhere by a ball of some radius r (a ball of radius r touching the surface from
outside meets no other part of it); a raw scan's is not (armpits, ears, fingers: 8-11 % of a raw
multi-view scan's points are inaccessible at r = 8 mm, 0.1 % of a booth mesh's). The refinement
takes the body's vertices that such a ball cannot reach on the body prior from the body prior,
not from the bridging surface over them (the body prior itself fits the scan as it is: masked
there as well, the 8 twin pairs of ``bench.realworld`` read 4.23 mm, not 4.38, but
closed_plate-15's shoulders slid 8-13 mm further off, ``tests/core/test_markerless_search.py``).

The same software rounds off the body's *convex* detail narrower than its grid: the nose's
wings, the lips, the chin's edge, the ears' rims. Those vertices are the ones a ball of about the
mesh's resolution cannot reach from *inside* the body (:func:`rounded_off`), and the refinement
takes them from the body prior too (:data:`ROUNDED_OFF_PER_RESOLUTION`).

And it fuses the fingers into mittens: the hull over the fingers, with the hand and wrist under
it, lies outside the skin. The refinement takes the open hands and the forearm next to them from
the body prior as well (:func:`mitten_hands`).
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from core.geometry import MeshDistance, vertex_normals
from core.registration.shape_prior import fisted_rest
from core.template import load_template
from core.threads import kd_workers

if TYPE_CHECKING:
    from core.template import Template

#: Ball radii tried for a scan's closing (metres), smallest first.
CLOSING_RADII_M = (0.004, 0.006, 0.008, 0.010, 0.012, 0.014)
#: Smallest closing radius (metres) taken as a closed mesh's: below it the bridged gaps are
#: within the scan's noise.
MIN_CLOSING_RADIUS_M = 0.006
#: Largest share of a scan's points on hole boundaries for a hole-filled mesh: above it the scan
#: has holes and no closing (raw scans 9 %, the simulated held-in scans 9-18 %; closed meshes
#: 0-0.9 %, a floor plate cut off). Without this, sparse raw scans (6 mm spacing) read 14 mm.
MAX_BOUNDARY_SHARE = 0.02
#: Share of a scan's points a ball of the closing radius may fail to reach (sampling, noise).
INACCESSIBLE_SHARE = 0.005
#: Scan points tested (a random sample; the share is what counts).
SAMPLE = 20_000
#: Radius of the inner ball of :func:`rounded_off`, per unit of a closed mesh's detail
#: (``ScanIndex.resolution_m``: 5-6 mm on the closed meshes of 14-20 k vertices of
#: ``bench.realworld``, so 6-7 mm; 3 mm on a decimated one). On those meshes of the twin
#: diagnostic (8 closed_lowres bodies) the data-taking vertices a 6 mm inner ball cannot reach
#: (10 % of them: 61 % of the face nearest the pronasale, 31 % nearest the menton, 40 % round
#: the eyes) lay 3.9 mm from the mesh's surface on their true body, the others 1.4 mm. Taken
#: from the body prior, the closed/raw twins read 3.24 -> 3.17 mm and the closed fits'
#: correspondence 6.53 -> 6.45 mm (1.5x: 3.18 / 6.47; 1.8x: 3.20 / 6.51, the hands' palms then
#: lost their data too). In the body prior as well (its data rows): twins 3.38, worse.
ROUNDED_OFF_PER_RESOLUTION = 1.2
#: Depth (metres) the inner ball of :func:`rounded_off` may cut through the surface.
ROUNDED_OFF_DEPTH_M = 0.001
#: A closed mesh's fist is bridged where a ball of this many times the mesh's closing radius
#: cannot reach the body prior's fist (:func:`fist_bridges`): the palm inside the curled fingers
#: and the fingers' pads (at 8 mm, 480 of a hand's 1 596 vertices). The bridging surface's data
#: pulled the fists of the twin diagnostic's fisted closed meshes (seeds 16 and 24) 5-8 mm
#: towards the body (their raw twins 1-3 mm): the body prior now leaves those vertices out
#: (fisted twins 3.80 / 3.11 -> 2.72 / 2.99 mm, their body priors' 3.77 / 3.07 -> 1.97 / 2.68).
FIST_BRIDGE_PER_CLOSING = 1.0
#: Reach (metres, on the template) of a closed mesh's mitten up the forearm from the hand
#: (:func:`mitten_hands`). On the twin diagnostic's 8 closed_lowres bodies (their mittens a hull
#: of the fingers 4-6 mm out, reaching up to 3 cm past the hand) the refined hands' palms and
#: backs lay 4.6 mm outside the truth's skin (the raw twins' 0.1, the body priors' 0.4) and the
#: forearm's last 1, 2, 3 cm 4.9, 3.9, 2.4 mm out (raw -0.1 to -0.4). With the hands alone taken
#: from the body prior: twins 3.09 -> 3.05 mm; with this band too 3.02 (4 cm: 3.01); the
#: closed meshes' correspondence 6.43 -> 6.35 mm. A fist's hand keeps its data (its curled
#: fingers are what places the fist: twins 3.05 without it). In the body prior as well (the
#: band's data rows): 3.03, worse. Only in the markerless soft-marker round (``core.registration.
#: fit.iter_fit``).
MITTEN_WRIST_BAND_M = 0.03


def inaccessible(P: np.ndarray, N: np.ndarray, tree: cKDTree, r: float, tol: float) -> np.ndarray:
    """(q,) bool: points P (q, 3) with outward unit normals N (q, 3) where a ball of radius r
    (metres) touching from outside holds a point of ``tree`` deeper than ``tol`` inside it."""
    d, _ = tree.query(P + r * N, workers=kd_workers())
    return d < r - tol


def scan_closing_radius(
    V: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    spacing_m: float,
    boundary: np.ndarray | None = None,
    seed: int = 0,
) -> float:
    """Largest ball radius (metres, :data:`CLOSING_RADII_M`) that reaches all but
    :data:`INACCESSIBLE_SHARE` of the scan's points V (n, 3) (KD-tree ``tree``) from outside
    along their normals N (n, 3); 0 when even the smallest does not (a raw scan: its
    concavities are the body's); 0 too for a scan with holes (``boundary`` (n,) bool, hole
    boundary points: more than :data:`MAX_BOUNDARY_SHARE` of them), which no software closed."""
    if boundary is not None and len(boundary) and np.mean(boundary) > MAX_BOUNDARY_SHARE:
        return 0.0
    V = np.asarray(V, np.float64)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(V), min(SAMPLE, len(V)), replace=False)
    P, Nn = V[pick], np.asarray(N, np.float64)[pick]
    tol = max(0.001, spacing_m)
    best = 0.0
    for r in CLOSING_RADII_M:
        if inaccessible(P, Nn, tree, r, tol).mean() > INACCESSIBLE_SHARE:
            break
        best = r
    return best


def _ball_unreachable(
    X: np.ndarray,
    F: np.ndarray,
    r: float,
    depth_m: float,
    vertices: np.ndarray | None,
    side: float,
) -> np.ndarray:
    """(n,) bool: vertices of X (n, 3) (the ``vertices`` given, default all) where a ball of
    radius r touching the surface on ``side`` (+1 outside, -1 inside, along the vertex normal)
    cuts more than ``depth_m`` into the surface elsewhere."""
    X = np.asarray(X, np.float64)
    out = np.zeros(len(X), bool)
    if r <= 0:
        return out
    ids = np.arange(len(X)) if vertices is None else np.asarray(vertices, np.int64)
    N = vertex_normals(X, np.asarray(F, np.int64))
    # k = 3 nearest vertices' triangles: the same verdicts as k = 8 on the template, 2.5x faster
    d = MeshDistance(X, F, k=3).distances(X[ids] + side * r * N[ids])
    out[ids] = d < r - depth_m
    return out


def closed_over(
    X: np.ndarray,
    F: np.ndarray,
    r: float,
    depth_m: float = 0.002,
    vertices: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) bool: vertices of the body X (n, 3), faces F (m, 3), that a ball of radius r
    (metres) touching from outside along the vertex normal cannot reach: it cuts more than
    ``depth_m`` into the body's surface elsewhere (a closed mesh bridges them). Only the
    ``vertices`` given (indices; default all) are tested, the others read False."""
    return _ball_unreachable(X, F, r, depth_m, vertices, 1.0)


def rounded_off(
    X: np.ndarray,
    F: np.ndarray,
    r: float,
    depth_m: float = ROUNDED_OFF_DEPTH_M,
    vertices: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) bool: vertices of the body X (n, 3), faces F (m, 3), that a ball of radius r
    (metres) touching from inside along the vertex normal cannot reach: convex detail
    narrower than the ball (a coarse closed mesh rounds it off). ``vertices`` as for
    :func:`closed_over`."""
    return _ball_unreachable(X, F, r, depth_m, vertices, -1.0)


def mitten_hands(template: Template, fists: str = "") -> np.ndarray:
    """(n,) bool: the template's hands and the vertices of their forearms within
    :data:`MITTEN_WRIST_BAND_M` of them (rest pose), for the sides ("L", "R") not in ``fists``:
    where a closed mesh's fused mittens lie outside the skin."""
    TV = np.asarray(template.V, np.float64)
    out = np.zeros(len(TV), bool)
    for x in "LR":
        if x in fists:
            continue
        hand = template.part_mask(f"hand_{x}")
        d = cKDTree(TV[hand]).query(TV, distance_upper_bound=MITTEN_WRIST_BAND_M)[0]
        out |= hand | ((d < MITTEN_WRIST_BAND_M) & template.part_mask(f"forearm_{x}"))
    return out


@cache
def fist_bridges(fists: str, closing_radius_m: float) -> np.ndarray:
    """(n,) bool: the template's vertices of the hands of ``fists`` (sides "L", "R") that a
    ball of :data:`FIST_BRIDGE_PER_CLOSING` times ``closing_radius_m`` (a closed mesh's,
    metres) cannot reach from outside on the template with those hands curled into the body
    prior's fist (:func:`core.registration.shape_prior.fisted_rest`): the palm and the curled
    fingers' pads, which a closed mesh's fused fist bridges over."""
    tpl = load_template()
    X = fisted_rest(np.asarray(tpl.V, np.float64), fists)
    out = np.zeros(len(X), bool)
    for x in fists:
        out |= closed_over(
            X,
            np.asarray(tpl.F, np.int64),
            FIST_BRIDGE_PER_CLOSING * closing_radius_m,
            vertices=np.flatnonzero(tpl.part_mask(f"hand_{x}")),
        )
    out.setflags(write=False)
    return out
