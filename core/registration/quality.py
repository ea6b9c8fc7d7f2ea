"""How good is a fit? Per-body-part residuals, data coverage and displacement, and a verdict.

A fit can look fine in its global numbers and still have lost a part (a head pulled into the neck
has little scan data nearby and the rest of the body hides it in the mean). :func:`assess_fit`
therefore measures every body part on its own and gives the fit one verdict:

``good``
    every part meets the *suspect* thresholds below;
``suspect``
    at least one part exceeds a *suspect* threshold (worth a look; usable with care);
``failed``
    at least one part exceeds a *failed* threshold: the part is lost, collapsed or misplaced and
    the body must not be used as it is.

Parts (the template's 16-part segmentation, :attr:`core.template.Template.part_names`, merged):
``head`` (head, neck), ``torso`` (torso, pelvis), ``arm_L``/``arm_R`` (upper arm, forearm),
``hand_L``/``hand_R``, ``leg_L``/``leg_R`` (thigh, shin), ``foot_L``/``foot_R``.

Per part (all distances metres):

- ``scan_to_fit_mean_m``, ``scan_to_fit_p95_m``: distance from the scan points whose nearest fitted
  vertex belongs to the part, to the fitted surface (exact point-to-triangle distance);
- ``fit_to_scan_mean_m``, ``fit_to_scan_p95_m``: distance from the part's own vertices (those a
  scanner captures: the template's ``bad_scan`` regions — ears, fingers, toes, eyes, mouth — are
  left out) to the scan surface (:func:`fit_to_scan_distance`);
- ``coverage``: fraction of those vertices with a *compatible* scan point (normals less than 60°
  apart) within ``COVERAGE_DISTANCE_M`` (15 mm);
- ``area_change``: how much the part's surface area changed against a reference body, relative
  to the whole body's: ``max(r, 1/r)``, ``r = (A_part / A_part,ref) / (A_body / A_body,ref)``
  (1 = in proportion; a head collapsed to 70 % of its size reads 2.0). The reference is the body
  the refinement started from (the body prior's personalised, posed template) when the caller
  gives it, else the template (real bodies then differ by up to 1.5: heavy arms, long bones);
- ``displacement_m``: distance between the centroid of the scan points assigned to the part
  within ``NEAR_DISTANCE_M`` (30 mm) of the fit and the centroid of the fitted vertices nearest
  them (a part shifted along its data).

Thresholds (``THRESHOLDS``; calibrated on simulated scans ``bench.cases`` and on deliberately
broken copies of good fits — a part moved by 3-15 cm or collapsed towards its joint; see
``tests/core/test_quality.py``):

======================  ===========  ==========
figure                  suspect if   failed if
======================  ===========  ==========
scan→fit p95            > 10 mm      never
fit→scan p95            > 30 mm      > 60 mm
coverage                < 0.70       < 0.40
displacement            > 10 mm      > 25 mm
======================  ===========  ==========

and a part is also ``failed`` when scan data around it is unexplained (scan→fit p95 > 25 mm)
*and* its own surface is off its data or shrunk/grown by the refinement (coverage < 0.70,
fit→scan p95 > 30 mm, or area change against the given reference > 1.25): a head collapsed into
the neck keeps its vertices on the neck's data (fit→scan and coverage look fine) but shrinks and
leaves the skull's scan points unexplained. A part that slid along its data onto a neighbour's
(a hand pulled up the forearm) shows only as unexplained scan data: ``suspect``, named.

Scan→fit alone never fails a part: scan points the body does not explain may be hair, clothing,
clutter or the floor as well as a misplaced part; a part off its data also loses coverage and
fit→scan, and those fail it. (Measured on ``core.synth.scanner_outputs`` cases: hair, mitten or
fist hands and floor clutter give hand/head/foot scan→fit p95 of 15-350 mm with the part in place.)

A part with fewer than ``MIN_POINTS`` scan points assigned has no scan→fit figures (reported as
NaN); it is judged by its fit→scan and coverage only. Hands and feet are held to thresholds 1.5×
looser (scanners capture them worst; they are small, so a few stray points move the p95).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from core.geometry import MeshDistance
from core.registration.correspondence import ScanIndex
from core.registration.operators import vertex_normals
from core.scan import Scan
from core.template import Template, load_template

Verdict = Literal["good", "suspect", "failed"]

PARTS: dict[str, tuple[str, ...]] = {
    "head": ("head", "neck"),
    "torso": ("torso", "pelvis"),
    "arm_L": ("upper_arm_L", "forearm_L"),
    "arm_R": ("upper_arm_R", "forearm_R"),
    "hand_L": ("hand_L",),
    "hand_R": ("hand_R",),
    "leg_L": ("thigh_L", "shin_L"),
    "leg_R": ("thigh_R", "shin_R"),
    "foot_L": ("foot_L",),
    "foot_R": ("foot_R",),
}
EXTREMITIES = ("hand_L", "hand_R", "foot_L", "foot_R")
EXTREMITY_FACTOR = 1.5

COVERAGE_DISTANCE_M = 0.015
COVERAGE_ANGLE_DEG = 60.0
MIN_POINTS = 30
SAMPLE_POINTS = 20_000
NEAR_DISTANCE_M = 0.03


@dataclass(frozen=True)
class Threshold:
    """One figure's limits: ``suspect`` and ``failed`` (metres, or a fraction for coverage)."""

    suspect: float
    failed: float
    higher_is_worse: bool = True


THRESHOLDS: dict[str, Threshold] = {
    "scan_to_fit_p95_m": Threshold(0.010, float("inf")),
    "fit_to_scan_p95_m": Threshold(0.030, 0.060),
    "coverage": Threshold(0.70, 0.40, higher_is_worse=False),
    "displacement_m": Threshold(0.010, 0.025),
}
LOST_SCAN_TO_FIT_M = 0.025
LOST_AREA_CHANGE = 1.25


@dataclass
class PartQuality:
    """Figures of one body part (metres; coverage a fraction in [0, 1])."""

    quality: Verdict
    scan_points: int
    scan_to_fit_mean_m: float
    scan_to_fit_p95_m: float
    fit_to_scan_mean_m: float
    fit_to_scan_p95_m: float
    coverage: float
    area_change: float
    displacement_m: float


@dataclass
class FitQuality:
    """A fit's verdict, the reasons for it (each naming the part) and per-part figures."""

    quality: Verdict
    reasons: list[str] = field(default_factory=list)
    parts: dict[str, PartQuality] = field(default_factory=dict)
    thresholds: dict[str, dict[str, float | None]] = field(default_factory=dict)  # None: never

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return asdict(self)

    def summary(self) -> str:
        """One line: the verdict and its reasons."""
        if not self.reasons:
            return f"quality: {self.quality}"
        return f"quality: {self.quality} ({'; '.join(self.reasons)})"


def part_labels(template: Template | None = None) -> tuple[np.ndarray, tuple[str, ...]]:
    """(13380,) int index into the returned part names (:data:`PARTS`) for every vertex."""
    tpl = template or load_template()
    labels = np.full(tpl.n_vertices, -1, dtype=np.int64)
    names = tuple(PARTS)
    for i, (_, members) in enumerate(PARTS.items()):
        for m in members:
            labels[tpl.part_mask(m)] = i
    if (labels < 0).any():  # pragma: no cover (the asset's segmentation covers every vertex)
        raise ValueError("template segmentation leaves vertices without a part")
    return labels, names


def _limits(part: str) -> dict[str, Threshold]:
    if part not in EXTREMITIES:
        return THRESHOLDS
    f = EXTREMITY_FACTOR
    return {
        k: Threshold(t.suspect * f, t.failed * f)
        if t.higher_is_worse
        else Threshold(t.suspect / f, t.failed / f, higher_is_worse=False)
        for k, t in THRESHOLDS.items()
    }


def _judge(part: str, figures: dict[str, float]) -> tuple[Verdict, list[str]]:
    verdict: Verdict = "good"
    reasons: list[str] = []
    rank = {"good": 0, "suspect": 1, "failed": 2}
    for key, lim in _limits(part).items():
        v = figures[key]
        if not np.isfinite(v):
            continue
        worse = (lambda a, b: a > b) if lim.higher_is_worse else (lambda a, b: a < b)
        level: Verdict | None = None
        if worse(v, lim.failed):
            level = "failed"
        elif worse(v, lim.suspect):
            level = "suspect"
        if level is None:
            continue
        if rank[level] > rank[verdict]:
            verdict = level
        if key == "coverage":
            reasons.append(f"{part}: only {v * 100:.0f} % of its surface has scan data nearby")
        elif key == "displacement_m":
            reasons.append(f"{part}: {v * 1000:.0f} mm away from its scan data")
        elif key == "scan_to_fit_p95_m":
            reasons.append(f"{part}: scan→fit p95 {v * 1000:.0f} mm")
        else:
            reasons.append(f"{part}: fit→scan p95 {v * 1000:.0f} mm")
    return verdict, reasons


def _triangle_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m,) areas of triangles F (m, 3) of vertices V (n, 3)."""
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def scan_spacing(index: ScanIndex, n: int = 2000) -> float:
    """Typical distance between neighbouring scan points (median over a subsample), metres."""
    ids = np.linspace(0, len(index.points) - 1, min(n, len(index.points))).astype(np.int64)
    d, _ = index.tree.query(index.points[ids], k=2, workers=-1)
    return float(np.median(d[:, 1]))


def fit_to_scan_distance(index: ScanIndex, X: np.ndarray) -> np.ndarray:
    """Distance (n,) from points X (n, 3) to the scan surface, metres.

    The nearest scan point's tangent plane stands in for the surface within one point spacing
    ``h`` of it: ``sqrt(d_n² + max(0, d_t - h)²)`` with ``d_n`` the distance along that point's
    normal and ``d_t`` the tangential distance (so sampling density does not count as error, but a
    vertex over a hole or off the body does).
    """
    d, j = index.tree.query(X, k=1, workers=-1)
    h = scan_spacing(index)
    dn = np.abs(np.einsum("nc,nc->n", X - index.points[j], index.normals[j]))
    dt = np.sqrt(np.maximum(d**2 - dn**2, 0.0))
    return np.sqrt(dn**2 + np.maximum(dt - h, 0.0) ** 2)


def assess_fit(
    scan: Scan | ScanIndex,
    X: np.ndarray,
    *,
    template: Template | None = None,
    sample: int = SAMPLE_POINTS,
    scan_to_fit: np.ndarray | None = None,
    sample_ids: np.ndarray | None = None,
    reference: np.ndarray | None = None,
) -> FitQuality:
    """Judge the fitted body ``X`` (13380, 3), metres, against ``scan`` (same frame).

    ``scan_to_fit`` (q,) with ``sample_ids`` (q,) may pass already computed distances of scan
    points ``sample_ids`` to the fitted surface; otherwise an evenly spaced subsample of at most
    ``sample`` scan points is measured. ``reference`` (13380, 3): the body the fit started from
    (for ``area_change``; default the template). Returns a :class:`FitQuality` (thresholds: module
    docstring).
    """
    tpl = template or load_template()
    X = np.asarray(X, dtype=np.float64)
    if X.shape != tpl.V.shape:
        raise ValueError(f"fitted body must be {tpl.V.shape}, got {X.shape}")
    index = scan if isinstance(scan, ScanIndex) else ScanIndex(scan)
    F = np.asarray(tpl.F, dtype=np.int64)
    labels, names = part_labels(tpl)
    captured = ~np.asarray(tpl.bad_scan_mask, dtype=bool)
    P_all = index.points
    if sample_ids is None or scan_to_fit is None:
        sample_ids = np.linspace(0, len(P_all) - 1, min(len(P_all), sample)).astype(np.int64)
        scan_to_fit = MeshDistance(X, F, k=3).distances(P_all[sample_ids])
    P = P_all[sample_ids]
    # scan points -> the part of their nearest fitted vertex
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(X).query(P, k=1, workers=-1)
    p_part = labels[nearest]
    # fitted vertices -> the scan surface, and compatible data within the coverage distance
    f2s = fit_to_scan_distance(index, X)
    corr = index.closest_compatible(
        X,
        vertex_normals(X, F),
        max_distance=COVERAGE_DISTANCE_M,
        max_angle_deg=COVERAGE_ANGLE_DEG,
        project=False,
    )
    covered = np.isfinite(corr.distances)
    tri_part = labels[F[:, 0]]
    a_fit = np.bincount(tri_part, _triangle_areas(X, F), minlength=len(names))
    ref = tpl.V if reference is None else np.asarray(reference, dtype=np.float64)
    a_tpl = np.bincount(tri_part, _triangle_areas(ref, F), minlength=len(names))
    ratio = (a_fit / a_tpl) / (a_fit.sum() / a_tpl.sum())
    area_change = np.maximum(ratio, 1.0 / np.maximum(ratio, 1e-9))
    parts: dict[str, PartQuality] = {}
    reasons: list[str] = []
    rank = {"good": 0, "suspect": 1, "failed": 2}
    verdict: Verdict = "good"
    for i, name in enumerate(names):
        own = (labels == i) & captured
        sel = p_part == i
        n_pts = int(sel.sum())
        if n_pts >= MIN_POINTS:
            d = scan_to_fit[sel]
            s2f_mean, s2f_p95 = float(d.mean()), float(np.percentile(d, 95))
            # the part's points nearest its data vs. the data itself: centroid offset
            near = sel & (scan_to_fit <= NEAR_DISTANCE_M)
            disp = float("nan")
            if near.sum() >= MIN_POINTS:
                disp = float(np.linalg.norm(P[near].mean(axis=0) - X[nearest[near]].mean(axis=0)))
        else:
            s2f_mean = s2f_p95 = disp = float("nan")
        figures = {
            "scan_to_fit_p95_m": s2f_p95,
            "fit_to_scan_p95_m": float(np.percentile(f2s[own], 95)),
            "coverage": float(covered[own].mean()),
            "area_change": float(area_change[i]),
            "displacement_m": disp,
        }
        pv, pr = _judge(name, figures)
        f = EXTREMITY_FACTOR if name in EXTREMITIES else 1.0
        off = (
            (reference is not None and figures["area_change"] > LOST_AREA_CHANGE)
            or figures["coverage"] < THRESHOLDS["coverage"].suspect / f
            or figures["fit_to_scan_p95_m"] > THRESHOLDS["fit_to_scan_p95_m"].suspect * f
        )
        if s2f_p95 > LOST_SCAN_TO_FIT_M * f and off and pv != "failed":
            pv = "failed"
            pr.insert(
                0,
                f"{name}: lost (scan data around it unexplained, its surface "
                f"{ratio[i] * 100:.0f} % of its proportion)",
            )
        if n_pts < MIN_POINTS:  # data for a whole part missing: the part may be lost
            pv = "failed" if figures["coverage"] < THRESHOLDS["coverage"].failed else pv
            pr.insert(0, f"{name}: only {n_pts} scan points near it")
            if pv == "good":
                pv = "suspect"
        parts[name] = PartQuality(
            quality=pv,
            scan_points=n_pts,
            scan_to_fit_mean_m=s2f_mean,
            scan_to_fit_p95_m=s2f_p95,
            fit_to_scan_mean_m=float(f2s[own].mean()),
            fit_to_scan_p95_m=figures["fit_to_scan_p95_m"],
            coverage=figures["coverage"],
            area_change=figures["area_change"],
            displacement_m=disp,
        )
        reasons.extend(pr)
        if rank[pv] > rank[verdict]:
            verdict = pv
    thresholds = {
        k: {"suspect": t.suspect, "failed": t.failed if np.isfinite(t.failed) else None}
        for k, t in THRESHOLDS.items()
    }
    return FitQuality(verdict, reasons, parts, thresholds)
