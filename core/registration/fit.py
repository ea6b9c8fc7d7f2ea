"""Fit the template body to a scan with markers (Allen, Curless, Popović 2003, §3).

``fit`` optimises one 3×4 affine per template vertex under E = α·E_d + β·E_s + γ·E_m, following
a :class:`Schedule` from a low- to the full-resolution template, and returns the fitted body in
template vertex order. The steps, each a function here: :func:`screen_and_align` (marker
screening, initial similarity) → :func:`initial_body` (the body prior) → :class:`SolverFrame` →
:func:`one_stage` per schedule stage → :func:`final_report` (distances, per-part quality); then
:func:`fit` retries a fit whose quality is not good (:data:`RETRIES`).

Solver units: positions are expressed in millimetres about the body's centre inside the solver
(``unit_scale=1000``), as the paper's CAESAR scans were; the α/β/γ weights are the paper's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp

from core.errors import FitError, MarkerError
from core.geometry import MeshDistance
from core.registration.closed_concavities import (
    MIN_CLOSING_RADIUS_M,
    MITTEN_WRIST_BAND_M,
    ROUNDED_OFF_PER_RESOLUTION,
    closed_over,
    fist_bridges,
    mitten_hands,
    rounded_off,
)
from core.registration.correspondence import (
    CONFIDENCE_FULL_AT,
    ScanIndex,
    normal_line_targets,
    offset_smoother,
    other_foot_matches,
)
from core.registration.initialization import MarkerAlignment, Similarity, align_markers
from core.registration.markers import CONSISTENT_WEIGHT_FLOOR, screen_markers
from core.registration.multires import Hierarchy, build_hierarchy
from core.registration.operators import (
    ResolutionLevel,
    apply_affines,
    make_level,
    unique_edges,
    vertex_normals,
)
from core.registration.quality import (
    LOST_SCAN_TO_FIT_M,
    MAX_UNSEEN_SHARE,
    SAMPLE_POINTS,
    FitQuality,
    assess_fit,
    part_labels,
    spread_allowance,
    spread_warning,
)
from core.registration.schedule import Schedule, Stage
from core.registration.shape_prior import (
    PriorFit,
    PriorOptions,
    arm_pose,
    feet_sides,
    fit_body_prior,
)
from core.registration.solver import AffineSolver, SystemTerms, energies
from core.scan import Scan
from core.template import Template, load_template
from core.threads import map_in_threads, single_blas_thread


@dataclass
class Progress:
    """One correspondence update: reported to callbacks and yielded by :func:`iter_fit`."""

    stage: int  # 0-based
    n_stages: int
    iteration: int  # 0-based within the stage
    resolution: str
    energy: dict[str, float]
    max_step_m: float  # largest vertex move in this update, metres
    elapsed_s: float

    @property
    def fraction(self) -> float:
        """Rough completion in [0, 1]."""
        return min(1.0, (self.stage + 0.5) / self.n_stages)


@dataclass
class StageReport:
    stage: int
    alpha: float
    beta: float
    gamma: float
    resolution: str
    iterations: int
    converged: bool
    energy: dict[str, float]
    seconds: float
    factorizations: int
    reused_factorizations: int


@dataclass
class FitReport:
    """What a fit did: energies, timings, distances (metres), warnings."""

    stages: list[StageReport] = field(default_factory=list)
    seconds: float = 0.0
    scan_to_fit_mean_m: float = float("nan")
    scan_to_fit_p95_m: float = float("nan")
    no_data_fraction: float = float("nan")  # no compatible scan point (holes), of all vertices
    template_region_fraction: float = float("nan")  # taken from the template (ears, fingers...)
    markers_used: list[str] = field(default_factory=list)
    markers_dropped: list[str] = field(default_factory=list)
    marker_residuals_m: dict[str, float] = field(default_factory=dict)
    marker_weights: dict[str, float] = field(default_factory=dict)  # robust weight in E_m, 0..1
    scale: float = float("nan")
    units: str | None = None
    up: str | None = None
    scan_vertices: int = 0  # the scan's points the fit used (after removing what is not the body)
    scan_faces: int = 0
    # points of the file left out as not the body (core.io.clean): floor_points, stray_points;
    # scan_vertices and the scan→fit figures count only the kept points
    removed: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    quality: FitQuality | None = None  # per-part check and verdict (core.registration.quality)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return asdict(self)


@dataclass
class FitResult:
    """The fitted body.

    Attributes
    ----------
    vertices : (13380, 3) float64 fitted template, metres, in the scan's (canonical) frame.
    faces : (26756, 3) template triangles.
    affines : (13380, 3, 4) per-vertex affines mapping the (personalised) template, metres, to
        scan metres.
    data_weight : (13380,) final data-term weight of each vertex (0: filled by smoothness).
    report : :class:`FitReport`.
    colors : (13380, 3) float64 RGB in [0, 1] from a coloured scan
        (:func:`core.transfer.colour.colour_fit`), else None.
    texture : (1024, 1024, 3) uint8 texture on the template UV layout from a textured scan
        (:func:`core.transfer.colour.colour_fit`), else None.
    body_prior : the body prior the refinement started from (shape coefficients, bone
        rotations, similarity: ``core.registration.shape_prior.PriorFit``), None without it.
    """

    vertices: np.ndarray
    faces: np.ndarray
    affines: np.ndarray
    data_weight: np.ndarray
    report: FitReport
    colors: np.ndarray | None = None
    texture: np.ndarray | None = None
    body_prior: PriorFit | None = None


class FitCancelled(Exception):  # noqa: N818 (a cancellation, not an error)
    """Raised when a progress callback returns False."""


@dataclass
class TemplateOperators:
    """Per-template precomputation shared by all fits (cached; the low level is built lazily)."""

    template: Template
    full: ResolutionLevel
    centre: np.ndarray  # (3,) metres, template centroid
    unit_scale: float
    n_low: int

    @cached_property
    def hierarchy(self) -> Hierarchy:
        tpl = self.template
        lm = np.array(sorted(tpl.landmarks.values()), dtype=np.int64)
        return build_hierarchy(tpl.V, np.asarray(tpl.F, np.int64), n_low=self.n_low, required=lm)

    @cached_property
    def low(self) -> ResolutionLevel:
        h = self.hierarchy
        return make_level(self.full.V[h.seeds], h.low_edges, self.full.data_mask[h.seeds], h.seeds)


_OPERATORS: dict[tuple[int, int, float], TemplateOperators] = {}


def template_operators(
    template: Template | None = None, *, n_low: int = 2500, unit_scale: float = 1000.0
) -> TemplateOperators:
    """Build (once per template and settings) the operators a fit needs."""
    template = template or load_template()
    key = (id(template), n_low, unit_scale)
    if key in _OPERATORS:
        return _OPERATORS[key]
    V, F = template.V, np.asarray(template.F, dtype=np.int64)
    centre = V.mean(axis=0)
    Vs = (V - centre) * unit_scale
    bad = template.extras.get("mask_bad_scan")
    data_mask = np.ones(len(V), bool) if bad is None else ~np.asarray(bad, dtype=bool)
    full = make_level(Vs, unique_edges(F), data_mask, np.arange(len(V)))
    ops = TemplateOperators(template, full, centre, unit_scale, n_low)
    _OPERATORS[key] = ops
    return ops


#: a scan whose detail is finer than this (``ScanIndex.resolution_m``, metres: its sampling, at
#: most 3 mm on a decimated mesh) shows the toes: they take
#: data (:func:`fit_data_mask`; in the body prior, and in a refinement without one: after it
#: they are in :func:`sole_band`). Raw multi-view scans read 1.7 mm, closed meshes of 60-100 k
#: vertices 2.7-2.9; booth meshes of 10-20 k vertices (4.9-7.3) fuse and round the toes off
#: (their toes' data put ``bench.realworld``'s closed_lowres-4/-8 feet 6 -> 14 / 5 -> 12 mm off).
TOE_DATA_MAX_SPACING_M = 0.004


#: height (metres) above the template's soles below which its feet take no data in the
#: refinement after a body prior (:func:`sole_band`): soles, the heels' undersides, the toes and
#: the feet's lower sides, where scanners see least (a raw scan's floor contact band is cut or
#: in shadow, grazing views along the floor; booth software cuts the soles flat 3-8 mm up,
#: fuses them with a floor plate and rounds the toes off). The body prior fits the feet whole;
#: refined, their lower part only got worse: ``bench.realworld``'s 8 closed_lowres/raw twins,
#: feet 4.97 -> 5.40 / 3.05 -> 4.00 mm off the truth with that data, 4.68 / 3.07 without it
#: (twins 3.88 -> 3.67 mm; a band of 2 cm: 3.75, 3 cm: 3.69, the whole foot: 3.71).
SOLE_BAND_M = 0.045


def sole_band(template: Template) -> np.ndarray:
    """(n,) bool: the template's foot vertices less than :data:`SOLE_BAND_M` above its soles."""
    feet = template.part_mask("foot_L") | template.part_mask("foot_R")
    y = np.asarray(template.V, np.float64)[:, 1]
    return feet & (y < y.min() + SOLE_BAND_M)


#: After a body prior the refinement's data term moves each vertex only along the body prior's
#: normal there (:func:`core.registration.correspondence.normal_line_targets`): the scan says how
#: far out the skin lies, the body prior where along the surface a vertex belongs. With the
#: closest compatible points' own tangent planes the refinement slid the skin 0.5-1.1 mm along
#: the surface on torso, arms and legs, on average away from the truth, and differently on two
#: deliveries of one body (``bench.realworld``'s closed_lowres/raw twins: their along-surface
#: difference 2.7-4.6 -> 3.1-4.9 mm by part). Not on the hands and feet, whose refinement moved
#: them along the surface towards the truth. Twin diagnostic (8 pairs, with a limb twist prior
#: later taken out): twins 3.62 -> 3.55 mm, correspondence closed 6.61 -> 6.60, raw 5.67 -> 5.60;
#: ``bench.realworld`` varied 40 as landed (with the hands' corrections from 2 mm): twins 3.63 ->
#: 3.58, correspondence 7.16 -> 7.07 mm.
NORMAL_LINE_FREE_PARTS = ("hand_L", "hand_R", "foot_L", "foot_R")
#: A target farther than this (metres) from the body prior's normal line is dropped: the scan
#: shows no skin over the vertex there (a heavy body's crotch, thighs that touch: on the normal
#: line such targets put vertices 2-10 cm off the scan, fit->scan p95 7.3 -> 10.7 mm). They were
#: kept as matched, and slid the crotch along the surface 2-25 mm, on 0, 4 and 28 of the twin
#: diagnostic's 8 bodies away from the truth (closed_lowres/raw-28, BMI 39: crotch 27 -> 35 /
#: 30 -> 39 mm off). Dropped: twins 3.02 -> 2.96 mm, correspondence closed / raw 6.35 / 5.52
#: -> 6.30 / 5.46 mm, fit->scan raw 1.83 -> 1.68 mm, scan->fit p95 unchanged.
NORMAL_LINE_MAX_OFFSET_M = 0.01
#: The normal lines' offsets are averaged over the body prior's surface (Gaussian, this many
#: times the scan's detail ``ScanIndex.resolution_m``): the scan sets the skin where it resolves
#: it, the body prior keeps what is finer (a 10-14 mm grid's mesh rounds the nose, lips and eye
#: sockets off; the prior's own detail, with the mesh's offset below it, is closer to the
#: truth). Twin diagnostic (``bench.realworld``'s 8 closed_lowres / raw pairs; twins, head
#: twins, correspondence closed / raw, mm): none 3.14, 1.70, 6.44 / 5.55; 1 × 3.13; 2 × 3.09,
#: 1.55, 6.43 / 5.52; 3 × 3.10; 4.5 × 3.10. Not below :data:`OFFSET_SMOOTHING_MIN_M` (metres):
#: a dense scan's own detail is the skin's.
OFFSET_SMOOTHING_PER_RESOLUTION = 2.0
OFFSET_SMOOTHING_MIN_M = 0.003
#: ... nor above this (metres): on booth meshes of 6-7 mm detail (``bench.realworld --booth``)
#: 12-15 mm averaged their torsos' and limbs' offsets too (scan→fit p95 3.22 -> 3.51 mm,
#: fit→scan 2.97 -> 3.08); at 8 mm 3.31 and 2.99, correspondence 10.11 -> 10.09 (uncapped
#: 10.10), the twin diagnostic unchanged (3.09)
OFFSET_SMOOTHING_MAX_M = 0.008


def toes_take_data(index: ScanIndex) -> bool:
    """Whether the scan's surface is detailed enough to show the toes
    (:data:`TOE_DATA_MAX_SPACING_M`)."""
    return index.resolution_m < TOE_DATA_MAX_SPACING_M


def closed_mesh_note(
    radius_m: float, bridged: int, rounded: int, rounded_radius_m: float, mittens: int
) -> str:
    """The report's note on a hole-filled closed mesh (its concavities bridged by a ball of
    ``radius_m`` metres; ``bridged`` template vertices under the bridges; ``rounded`` vertices
    of convex detail narrower than an inner ball of ``rounded_radius_m``; ``mittens`` vertices
    of the open hands and their wrists, :func:`core.registration.closed_concavities.
    mitten_hands`)."""
    return (
        f"hole-filled closed mesh: its software bridged the gaps narrower than a "
        f"{radius_m * 1000:.0f} mm ball (armpits, crotch, between fingers and toes); the "
        f"{bridged:,} template vertices under the bridges keep the body prior's skin, and so do "
        f"the {rounded:,} of convex detail narrower than its resolution (a "
        f"{rounded_radius_m * 1000:.0f} mm ball inside: nose, lips, chin, ears' rims), which it "
        "rounds off"
        + (
            f", and the {mittens:,} of the open hands and the {MITTEN_WRIST_BAND_M * 100:.0f} cm "
            "of forearm next to them, which its fused mittens inflate"
            if mittens
            else ""
        )
        + ". Such meshes also smooth and shrink small parts, so the hands' and feet's "
        "correspondence is less certain than on a raw scan (fits of a 10-14 mm closed mesh and "
        "of the raw scan of one body put the hands 5 mm, the feet 3 mm apart on average)"
    )


def decimated_mesh_note(index: ScanIndex) -> str | None:
    """The report's note on a mesh read by its detail rather than its sampling
    (:attr:`ScanIndex.resolution_m`: a mesh decimated by its software from a finer surface), or
    None where the two are the same."""
    from core.registration.foot_end import toe_allowance
    from core.registration.hand_length import tip_allowance

    if not index.decimated or index.resolution_m >= index.spacing_m:
        return None
    return (
        f"decimated mesh (its vertices evenly spread, denser where it bends): sampled every "
        f"{index.spacing_m * 1000:.1f} mm but read as a {index.resolution_m * 1000:.0f} mm "
        f"surface, so the fingertips and toe tips are set {tip_allowance(index) * 1000:.0f} and "
        f"{toe_allowance(index) * 1000:.0f} mm past the scanned hands' and feet's ends (where its "
        "software rounded the ends off more than that, they are a few mm short)"
    )


def fit_data_mask(ops: TemplateOperators, fists: str = "", toes: bool = False) -> np.ndarray:
    """(13380,) bool: the vertices that take data in a fit — all but the template's regions
    that scan badly (``data_mask``), except that the fingers of a hand fitted as a fist
    (``fists``: sides "L", "R") take data: curled, their backs and knuckles are the fist's
    scanned surface. Without their data the fist's end was the shape space's, not the scan's:
    the fisted hands of ``bench.realworld``'s closed_lowres-16/24 hung 10-13 mm past the
    scanned fist, their wrists 15-19 mm down the forearm (hands 24-25 mm off the truth; with
    their data 11-15 mm; the raw twins' 13-17 -> 5-8 mm).
    ``toes``: the toes take data too (a finely sampled scan, :data:`TOE_DATA_MAX_SPACING_M`;
    without them a foot's length was the shape space's: forefeet 8-10 mm long at the toe tip),
    a toe's pairs with the other foot's data dropped
    (:func:`core.registration.correspondence.other_foot_matches`)."""
    if not fists and not toes:
        return ops.full.data_mask
    tpl = ops.template
    dm = ops.full.data_mask.copy()
    if toes:
        dm |= np.asarray(tpl.mask("toes"), bool)
    for x in fists:
        dm |= tpl.part_mask(f"hand_{x}") & np.asarray(tpl.mask("fingers"), bool)
    return dm


def _check_scan(scan: Scan) -> None:
    V = np.asarray(scan.V)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 100:
        raise FitError(f"scan needs at least 100 points as an (n, 3) array; got shape {V.shape}")
    if not np.isfinite(V).all():
        raise FitError("scan has non-finite coordinates (NaN or Inf)")
    for name in ("normals", "confidence", "boundary"):
        a = getattr(scan, name)
        if a is None or len(a) != len(V):
            raise FitError(f"scan.{name} must have one entry per point ({len(V)})")


def scan_index(
    scan: Scan, index: ScanIndex | None = None, confidence_full_at: float = CONFIDENCE_FULL_AT
) -> ScanIndex:
    """``index`` when it is this scan's with this confidence ramp, else a new one (the scan
    checked first: a NaN point is a ``FitError``, not scipy's ``ValueError``). Build it once
    for several fits of one scan and pass it as their ``index``."""
    _check_scan(scan)
    if index is None or index.scan is not scan or index.confidence_full_at != confidence_full_at:
        index = ScanIndex(scan, confidence_full_at=confidence_full_at)
    return index


def iter_fit(
    scan: Scan,
    markers: dict[str, np.ndarray],
    *,
    schedule: Schedule | None = None,
    template: Template | None = None,
    max_distance: float = 0.10,
    max_angle_deg: float = 90.0,
    confidence_full_at: float = CONFIDENCE_FULL_AT,
    marker_far_distance: float = 0.10,
    n_low: int = 2500,
    unit_scale: float = 1000.0,
    shape_prior: bool = True,
    marker_outlier_distance: float = 0.05,
    initial_similarity: Similarity | None = None,
    prior_options: PriorOptions | dict[str, Any] | None = None,
    marker_trust: float | None = None,
    part_weights: dict[str, float] | None = None,
    index: ScanIndex | None = None,
    assess: bool = True,
    prior_restart: PriorRestart | None = None,
    soft_markers: bool = False,
    absent_parts: tuple[str, ...] = (),
) -> Iterator[Progress | FitResult]:
    """Generator form of :func:`fit`: yields :class:`Progress` per update, then the result.

    Parameters
    ----------
    scan : the scan, metres, canonical frame (see ``core.io.prepare``).
    markers : landmark name -> (3,) position, metres, same frame as the scan.
    schedule : stage weights and iteration limits; default :meth:`Schedule.refine` after the
        body prior, :meth:`Schedule.paper` without it.
    max_distance : metres; farther scan points are not compatible (paper: 10 cm).
    max_angle_deg : normals more than this apart are not compatible (paper: 90°).
    confidence_full_at : confidence at which the data weight reaches 1 (paper: 0.2).
    marker_far_distance : metres; when every marker is farther than this from the scan, the
        markers are in another frame or unit: ``FitError``. Single markers are screened by
        ``core.registration.markers`` (dropped only when both the scan and their neighbours
        contradict them).
    marker_outlier_distance : metres; after the body prior, markers farther than this from the
        fitted body are named in a warning (they keep their robust weight).
    shape_prior : personalise the template first (``core.registration.shape_prior``); False runs
        the paper's method from the plain template.
    initial_similarity : template → scan alignment to start from when ``markers`` is empty
        (markerless fitting, ``core.matching``).
    prior_options : tuning of ``fit_body_prior`` (:class:`PriorOptions`, or a dict of its fields).
    marker_trust : minimum robust weight (0..1) of every marker in the body prior (default: half
        for markers that agree with their neighbours, 0 for the others); a retry sets 1.
    part_weights : quality part name (``core.registration.quality.PARTS``) -> multiplier of
        that part's data weight in the body prior (a retry raises a lost part's).
    index : the scan's KD-tree index (``ScanIndex(scan, confidence_full_at=...)``) when the
        caller fits the same scan several times (markerless rounds, retries); built otherwise.
    assess : measure the result (scan→fit distances, per-part quality check). False for an
        intermediate fit whose vertices alone are used (markerless rounds): the report's
        distances stay NaN and its ``quality`` None (saves ~0.25 s CPU per fit).
    prior_restart : also start the body prior from an earlier fit's and keep the better of the
        two (:class:`PriorRestart`; markerless rounds); the notes give both scores.
    soft_markers : the markers are landmarks an earlier fit predicted (markerless rounds), not
        placed on the body: the body prior weighs them against the data, and the refinement's
        marker term (the weak guard, γ) holds the landmarks where the body prior put them, not at
        the predictions. With the predictions the refinement pulled the first shape-space fit's
        errors back in (``bench.realworld`` closed-vs-raw twins, 8 bodies: 4.13 -> 4.04 mm).
    absent_parts : quality parts the scan does not hold (``core.matching.markerless.
        feet_in_scan``: a scan that ends above the soles): the quality check calls them suspect
        as the body prior's guess, not failed for their missing data, and no retry is run for them.
    """
    t_start = time.perf_counter()
    if schedule is None:
        schedule = Schedule.refine() if shape_prior else Schedule.paper()
    _check_scan(scan)
    ops = template_operators(template, n_low=n_low, unit_scale=unit_scale)
    tpl = ops.template
    report = FitReport(scan_vertices=len(scan.V), scan_faces=0 if scan.F is None else len(scan.F))
    report.notes.extend(scan.notes)
    report.removed = dict(scan.removed)
    if any(report.removed.values()):
        what = ", ".join(f"{v:,} {k.replace('_', ' ')}" for k, v in report.removed.items() if v)
        report.warnings.append(
            f"removed from the scan as not the body: {what}; the scan→fit figures and the "
            f"quality check are over the {len(scan.V):,} kept points"
        )
    if scan.frame is not None:
        report.units, report.up = scan.frame.units, scan.frame.up

    index = scan_index(scan, index, confidence_full_at)
    markers, align, consistent = screen_and_align(
        index, tpl, markers, report,
        marker_far_distance=marker_far_distance,
        initial_similarity=initial_similarity, shape_prior=shape_prior,
    )  # fmt: skip
    body = initial_body(
        index, ops, markers, align, consistent, report,
        shape_prior=shape_prior, max_distance=max_distance,
        marker_outlier_distance=marker_outlier_distance, prior_options=prior_options,
        marker_trust=marker_trust, part_weights=part_weights, prior_restart=prior_restart,
    )  # fmt: skip
    frame = SolverFrame.of(body, unit_scale)
    marker_pos = frame.to_solver(
        np.array([markers[k] for k in align.used], dtype=np.float64).reshape(-1, 3)
    )
    if soft_markers and body.prior is not None:  # the guard at the body prior's landmarks
        marker_pos = frame.to_solver(body.V[body.marker_vid])
    Vs = frame.to_solver_template(body.V)
    # the data mask of this fit: a fist's curled fingers take data (see :func:`fit_data_mask`);
    # after a body prior the feet's lower part (toes included) is the body prior's
    toes = body.prior is None and toes_take_data(index)
    mitten_sides = ""  # hands that keep the body prior inside a closed mesh's mittens
    dm = fit_data_mask(ops, PriorOptions.of(prior_options).fists if shape_prior else "", toes)
    if body.prior is not None:
        dm = dm & ~sole_band(tpl)
        if index.closing_radius_m >= MIN_CLOSING_RADIUS_M:
            r = index.closing_radius_m
            under = closed_over(body.V, tpl.F, r, vertices=np.flatnonzero(dm))
            dm = dm & ~under
            r_in = ROUNDED_OFF_PER_RESOLUTION * index.resolution_m
            rounded = rounded_off(body.V, tpl.F, r_in, vertices=np.flatnonzero(dm))
            dm = dm & ~rounded
            # the mittens keep the body prior's hands only in the markerless round, whose body
            # prior places them: a marker fit's, on a fast schedule, can leave them 6-7 cm off,
            # and their data brings them back (closed_hair-1: hands 63 / 69 mm off without it,
            # under 50 with it). Per vertex where the body prior lies within 1 cm of the scan
            # instead: twins 2.95, but hands resting on the hip took the hip's data
            # (closed_plate-27 11.35 -> 13.39 mm, closed_touching-17 4.96 -> 5.72)
            mittens = np.zeros_like(dm)
            if soft_markers:
                fists = PriorOptions.of(prior_options).fists
                mittens = mitten_hands(tpl, fists) & dm
                dm = dm & ~mittens
                mitten_sides = "".join(x for x in "LR" if x not in fists)
            report.notes.append(
                closed_mesh_note(r, int(under.sum()), int(rounded.sum()), r_in, int(mittens.sum()))
            )
        if (dec := decimated_mesh_note(index)) is not None:
            report.notes.append(dec)
    full = replace(ops.full, V=Vs, data_mask=dm)
    needs_low = any(st.resolution == "low" for st in schedule.stages)
    low = (
        replace(ops.low, V=Vs[ops.low.vertex_ids], data_mask=dm[ops.low.vertex_ids])
        if needs_low
        else None
    )
    state = _StageState()
    state.mitten_sides = mitten_sides
    if toes:  # a toe's pairs with the other foot's data are dropped
        state.toe_guard = feet_sides(len(dm))
    if body.prior is not None:  # the body prior places the skin along the surface
        X0 = frame.to_world(apply_affines(np.broadcast_to(frame.A0, (full.n, 3, 4)), Vs))
        on = np.ones(len(X0), dtype=bool)
        for part in NORMAL_LINE_FREE_PARTS:
            on &= ~tpl.part_mask(part)
        N0 = vertex_normals(X0, np.asarray(tpl.F, np.int64))
        state.normal_lines = (X0, N0, on)
        sigma = min(OFFSET_SMOOTHING_PER_RESOLUTION * index.resolution_m, OFFSET_SMOOTHING_MAX_M)
        if sigma >= OFFSET_SMOOTHING_MIN_M:
            state.offset_smoother = offset_smoother(X0[on], N0[on], sigma)
            report.notes.append(
                f"refinement: the skin's offsets from the body prior averaged over "
                f"{sigma * 1000:.1f} mm ({OFFSET_SMOOTHING_PER_RESOLUTION:g} × the scan's detail, "
                f"at most {OFFSET_SMOOTHING_MAX_M * 1000:g} mm): "
                "what is finer (a coarse mesh's rounded nose and lips) is the body prior's"
            )
    for si, st in enumerate(schedule.stages):
        want = low if st.resolution == "low" else full
        assert want is not None
        state.enter(want, frame.A0, ops)
        yield from one_stage(
            si, len(schedule.stages), st, state, index, ops, full, frame, body, marker_pos,
            report, max_distance=max_distance, max_angle_deg=max_angle_deg, t_start=t_start,
        )  # fmt: skip
    yield final_report(
        scan, index, ops, full, frame, body, state, report,
        max_distance=max_distance, max_angle_deg=max_angle_deg,
        shape_prior=shape_prior, t_start=t_start, assess=assess, absent_parts=absent_parts,
    )  # fmt: skip


# --------------------------------------------------------------------------- the named steps


def screen_and_align(
    index: ScanIndex,
    tpl: Template,
    markers: dict[str, np.ndarray],
    report: FitReport,
    *,
    marker_far_distance: float,
    initial_similarity: Similarity | None,
    shape_prior: bool,
) -> tuple[dict[str, np.ndarray], MarkerAlignment, dict[str, bool]]:
    """Marker screening and the initial similarity.

    Unknown names are an error (readers reject them earlier); a marker is dropped only when both
    the scan and its neighbours contradict it (``core.registration.markers``); the similarity
    comes from the markers that agree (``align_markers``), the others stay in as evidence.
    Returns the kept markers, the alignment (``used`` = kept) and who agrees with neighbours.
    """
    markers = {k: np.asarray(v, dtype=np.float64) for k, v in markers.items()}
    unknown = sorted(set(markers) - set(tpl.landmarks))
    if unknown:
        raise MarkerError(f"unknown marker names: {', '.join(unknown)}", unknown=unknown)
    tl = {k: tpl.V[i] for k, i in tpl.landmarks.items()}
    consistent: dict[str, bool] = {}
    if markers:
        names = list(markers)
        dist = index.distance_to_points(np.array([markers[k] for k in names]))
        if (dist > marker_far_distance).all():
            raise FitError(
                f"all markers are more than {marker_far_distance * 100:.0f} cm from the scan: "
                "are they in the scan's units and frame?",
                nearest_m=float(dist.min()),
            )
        screening = screen_markers(index, tl, markers)
        report.warnings.extend(screening.warnings)
        report.markers_dropped.extend(screening.dropped)
        for k in screening.dropped:
            markers.pop(k)
        consistent = screening.consistent
    if markers or initial_similarity is None:
        align = align_markers(tl, markers)
        report.warnings.extend(align.warnings)
        align = MarkerAlignment(align.similarity, list(markers), [], align.residuals)
    else:  # markerless: the caller chose the initial alignment
        if not shape_prior:
            raise FitError("a fit without markers needs the body prior (shape_prior=True)")
        align = MarkerAlignment(initial_similarity, [], [], {})
    report.markers_used = align.used
    report.marker_residuals_m = align.residuals
    return markers, align, consistent


@dataclass(frozen=True)
class PriorRestart:
    """A second start for the body prior, kept where it explains the scan better.

    prior : an earlier body prior fit of the same scan; its similarity, pose and coefficients
        start a second fit beside the usual one (markers' alignment, rest pose).
    score : body vertices (13380, 3), metres, scan frame -> mismatch with the scan, lower is
        better (``core.matching.markerless.two_way_score``).
    margin : the earlier fit's start is kept only where it scores lower by more than this (a
        near tie keeps the usual start).
    iterations : Gauss-Newton iterations of the second fit (None: as the usual one's); it
        starts from a converged fit.
    """

    prior: PriorFit
    score: Callable[[np.ndarray], float]
    margin: float = 0.0
    iterations: int | None = None


@dataclass
class InitialBody:
    """The body the affine refinement starts from.

    V : (13380, 3) metres (the prior's posed, personalised body, already in the scan frame; or
    the template). sim : template-side → scan similarity still to apply (identity after the
    prior). marker_vid : (km,) marked vertices. marker_w : (km,) robust marker weights (E_m).
    prior : the body prior's fit (None without the shape prior).
    """

    V: np.ndarray
    sim: Similarity
    marker_vid: np.ndarray
    marker_w: np.ndarray
    prior: PriorFit | None = None


#: How a fit's report note on the hands' lengths set by the body prior begins.
HAND_LENGTH_NOTE = "hand length set"


def initial_body(
    index: ScanIndex,
    ops: TemplateOperators,
    markers: dict[str, np.ndarray],
    align: MarkerAlignment,
    consistent: dict[str, bool],
    report: FitReport,
    *,
    shape_prior: bool,
    max_distance: float,
    marker_outlier_distance: float,
    prior_options: PriorOptions | dict[str, Any] | None,
    marker_trust: float | None,
    part_weights: dict[str, float] | None,
    prior_restart: PriorRestart | None = None,
) -> InitialBody:
    """Initial body: the body prior (``fit_body_prior``: shape, pose, similarity) with annealed
    robust marker weights, floored for markers their neighbours agree with; or the template."""
    tpl = ops.template
    marker_vid = np.array([tpl.landmarks[k] for k in align.used], dtype=np.int64)
    if not shape_prior:
        report.scale = align.similarity.s
        report.marker_weights = {k: 1.0 for k in align.used}
        return InitialBody(tpl.V, align.similarity, marker_vid, np.ones(len(align.used)))
    floor = np.array([CONSISTENT_WEIGHT_FLOOR * consistent.get(k, False) for k in align.used])
    if marker_trust is not None:
        floor = np.full(len(align.used), float(marker_trust))
    vw = None
    if part_weights:
        labels, pnames = part_labels(tpl)
        vw = np.ones(tpl.n_vertices)
        for pname, f in part_weights.items():
            vw[labels == pnames.index(pname)] = float(f)
    po = PriorOptions.of(prior_options)
    marker_pos = np.array([markers[k] for k in align.used], dtype=np.float64).reshape(-1, 3)

    def prior_from(sim: Similarity, options: PriorOptions) -> PriorFit:
        dm = fit_data_mask(ops, options.fists, toes_take_data(index))
        if options.fists and index.closing_radius_m >= MIN_CLOSING_RADIUS_M:
            # a closed mesh's fused fist: the bridge over its palm is not the fist's skin
            dm = dm & ~fist_bridges(options.fists, index.closing_radius_m)
        return fit_body_prior(
            index, tpl.V, np.asarray(tpl.F, dtype=np.int64), marker_vid, marker_pos, sim,
            data_mask=dm,
            max_distance=max_distance,
            marker_floor=floor,
            vertex_weight=vw, measure=False, **options.kwargs(),
        )  # fmt: skip

    if prior_restart is None:
        prior = prior_from(align.similarity, po)
    else:  # the two starts' body priors are independent: fitted side by side
        p0 = prior_restart.prior
        restarted = replace(
            po,
            initial_pose=p0.pose,
            initial_coefficients=p0.coefficients,
            iterations=prior_restart.iterations or po.iterations,
        )
        prior, again = map_in_threads(
            lambda a: prior_from(*a), [(align.similarity, po), (p0.similarity, restarted)]
        )
        s_new, s_again = prior_restart.score(prior.X), prior_restart.score(again.X)
        use_again = s_again < s_new - prior_restart.margin
        kept = "the earlier fit's" if use_again else "the markers' alignment"
        report.notes.append(
            f"start of the body prior: the markers' alignment scored {s_new:.3f}, the earlier "
            f"fit's pose and shape {s_again:.3f} (two-way): {kept} kept"
        )
        if use_again:
            prior = again
    report.scale = prior.similarity.s
    report.marker_residuals_m = {
        k: float(r) for k, r in zip(align.used, prior.marker_residuals_m, strict=True)
    }
    report.notes.append(
        f"body prior: {len(prior.coefficients)} shape coefficients, "
        f"{len(prior.pose)} bone rotations; marker rms {prior.rms_marker_m * 1000:.1f} mm, "
        f"data rms {prior.rms_data_m * 1000:.1f} mm; its last iteration moved it "
        f"{prior.last_step_m * 1000:.2f} mm (mean)"
    )
    if prior.hand_lengths:
        report.notes.append(
            f"{HAND_LENGTH_NOTE} (the fingers take no data): "
            + "; ".join(h.note() for h in prior.hand_lengths)
        )
    if prior.foot_lengths:
        report.notes.append(
            "feet set to their length (the toes take no data on coarse scans): "
            + "; ".join(f.note() for f in prior.foot_lengths)
        )
    # markers the fitted body cannot reach and their neighbours contradict: weighed down
    # (robust weights of the prior, carried into E_m), never dropped for the prior's sake
    marker_w = prior.marker_weights.copy()
    for name, r, wm in zip(align.used, prior.marker_residuals_m, marker_w, strict=True):
        if r > marker_outlier_distance:
            how = (
                "kept: it agrees with its neighbours"
                if consistent.get(name, False)
                else f"weighed down to {wm:.2f} (misplaced or misnamed?)"
            )
            report.warnings.append(f"marker {name} is {r * 100:.1f} cm from the fitted body: {how}")
    report.marker_weights = {k: float(w) for k, w in zip(align.used, marker_w, strict=True)}
    return InitialBody(
        prior.X, Similarity(1.0, np.eye(3), np.zeros(3)), marker_vid, marker_w, prior
    )


@dataclass
class SolverFrame:
    """Solver frame: millimetres (``u``) about the similarity-mapped body centre.

    A scan-frame point x (metres) is ``(x - c_scan) · u`` in the solver; a template-side point v
    is ``(v - cb) · u`` and the initial affine ``A0`` (3, 4) maps it (``[s R | 0]``).
    """

    u: float
    cb: np.ndarray  # (3,) template-side centre, metres
    c_scan: np.ndarray  # (3,) its image in the scan frame, metres
    A0: np.ndarray  # (3, 4)

    @classmethod
    def of(cls, body: InitialBody, u: float) -> SolverFrame:
        cb = body.V.mean(axis=0)
        sim = body.sim
        A0 = np.hstack([sim.s * sim.R, np.zeros((3, 1))])
        return cls(u, cb, sim.apply(cb[None])[0], A0)

    def to_solver(self, X: np.ndarray) -> np.ndarray:
        return (X - self.c_scan) * self.u

    def to_world(self, Xs: np.ndarray) -> np.ndarray:
        return Xs / self.u + self.c_scan

    def to_solver_template(self, V: np.ndarray) -> np.ndarray:
        return (V - self.cb) * self.u

    def affines_to_world(self, A: np.ndarray) -> np.ndarray:
        """Solver affines (n, 3, 4) → metres: ``x = A_s (u (v - cb)) / u + c_scan``."""
        A_m = A.copy()
        A_m[:, :, 3] = (
            A[:, :, 3] / self.u + self.c_scan - np.einsum("nij,j->ni", A[:, :, :3], self.cb)
        )
        return A_m


def x_from_affines(A: np.ndarray) -> np.ndarray:
    """(n, 3, 4) affines → (4n, 3) solver unknowns (row c of T_i in x[4i:4i+4, c])."""
    return np.ascontiguousarray(A.transpose(0, 2, 1)).reshape(-1, 3)


def affines_from_x(x: np.ndarray) -> np.ndarray:
    """(4n, 3) solver unknowns → (n, 3, 4) affines."""
    return x.reshape(-1, 4, 3).transpose(0, 2, 1)


@dataclass
class _StageState:
    """The refinement's running state across stages: level, its solver, unknowns, regulariser."""

    level: ResolutionLevel | None = None
    solver: AffineSolver | None = None
    x: np.ndarray | None = None
    x_reg: np.ndarray | None = None
    toe_guard: tuple[np.ndarray, np.ndarray] | None = None  # (toe sides, foot sides) (n,)
    #: the body prior's vertices and unit normals (13380, 3) in the scan frame, and (13380,)
    #: bool the vertices whose data targets move onto its normal lines (NORMAL_LINE_FREE_PARTS)
    normal_lines: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    #: the smoothing of the normal lines' offsets over the ``on`` vertices (full resolution),
    #: where its scale reaches :data:`OFFSET_SMOOTHING_MIN_M` (:func:`offset_smoother`)
    offset_smoother: sp.csr_matrix | None = None
    #: full-resolution vertices whose data target lay off the body prior's normal line in the
    #: last iteration (no skin over them: dropped), or None
    no_skin: np.ndarray | None = None
    #: the sides ("L", "R") whose hands keep the body prior inside a closed mesh's mittens
    mitten_sides: str = ""

    def enter(self, want: ResolutionLevel, A0: np.ndarray, ops: TemplateOperators) -> None:
        """Switch to resolution ``want`` (start from A0, or blend low-resolution affines up)."""
        if self.level is not want:
            if self.level is None or self.x is None:
                self.x = x_from_affines(np.broadcast_to(A0, (want.n, 3, 4)))
            else:  # low -> high: blend the low-resolution affines
                A_low = affines_from_x(self.x).reshape(self.level.n, 12)
                self.x = x_from_affines((ops.hierarchy.upsample @ A_low).reshape(-1, 3, 4))
            self.x_reg = self.x.copy()
            self.level = want
            self.solver = AffineSolver(want)
        assert self.solver is not None
        self.solver.reset()


def one_stage(
    si: int,
    n_stages: int,
    st: Stage,
    state: _StageState,
    index: ScanIndex,
    ops: TemplateOperators,
    full: ResolutionLevel,
    frame: SolverFrame,
    body: InitialBody,
    marker_pos: np.ndarray,
    report: FitReport,
    *,
    max_distance: float,
    max_angle_deg: float,
    t_start: float,
) -> Iterator[Progress]:
    """One stage of the schedule: correspondence updates (closest compatible points, E_d with
    confidence weights) and solves of α·E_d + β·E_s + γ·E_m until the largest step is below the
    stage's tolerance; yields :class:`Progress`, appends a :class:`StageReport`."""
    t_stage = time.perf_counter()
    level, solver = state.level, state.solver
    assert level is not None and solver is not None and state.x is not None
    assert state.x_reg is not None
    if level is not full:
        low_pos = {int(v): i for i, v in enumerate(level.vertex_ids)}
        m_idx = np.array([low_pos[int(v)] for v in body.marker_vid], dtype=np.int64)
    else:
        m_idx = body.marker_vid
    F_full = np.asarray(ops.template.F, dtype=np.int64)
    x = state.x
    n_fact = n_reused = 0
    converged = False
    en: dict[str, float] = {}
    it = 0
    for it in range(st.max_iterations):
        A = affines_from_x(x)
        Xs = apply_affines(A, level.V)
        if st.alpha > 0:
            # normals of the deformed full mesh, sampled at this level's vertices
            if level is full:
                X_full = Xs
            else:
                A_full = (ops.hierarchy.upsample @ A.reshape(level.n, 12)).reshape(-1, 3, 4)
                X_full = apply_affines(A_full, full.V)
            N = vertex_normals(X_full, F_full)[level.vertex_ids]
            Xw = frame.to_world(Xs)
            corr = index.closest_compatible(
                Xw, N, max_distance=max_distance, max_angle_deg=max_angle_deg
            )
            w = corr.weights * level.data_mask
            if state.normal_lines is not None:
                X0, N0, on = (a[level.vertex_ids] for a in state.normal_lines)
                smooth = state.offset_smoother if level is full else None
                corr.targets[on], near = normal_line_targets(
                    corr.targets[on], X0[on], N0[on], NORMAL_LINE_MAX_OFFSET_M,
                    smooth, w[on],
                )  # fmt: skip
                far = np.flatnonzero(on)[~near]
                w[far] = 0.0  # no skin over the vertex: no data
                if level is full:
                    state.no_skin = far
            if state.toe_guard is not None:  # a toe's data on the other foot is no toe's
                toe_side, foot_side = state.toe_guard
                vid = level.vertex_ids
                cand = np.flatnonzero(w > 0)
                bad = other_foot_matches(
                    Xw, cand, corr.targets[cand], toe_side[vid], foot_side[vid]
                )
                w[cand[bad]] = 0.0
            d_idx = np.flatnonzero(w > 0)
            d_w, d_t = w[d_idx], frame.to_solver(corr.targets[d_idx])
        else:
            d_idx, d_w, d_t = np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
        terms = SystemTerms(
            st.alpha, st.beta, st.gamma, d_idx, d_w, d_t, m_idx, marker_pos, body.marker_w
        )
        x_new, stats = solver.solve(terms, x, state.x_reg)
        n_fact += int(stats.factorized)
        n_reused += int(not stats.factorized)
        X_new = apply_affines(affines_from_x(x_new), level.V)
        step = float(np.max(np.linalg.norm(X_new - Xs, axis=1))) / frame.u
        x = x_new
        state.x = x
        en = energies(level, terms, x)
        yield Progress(si, n_stages, it, st.resolution, en, step, time.perf_counter() - t_start)
        if step < st.tolerance_m:
            converged = True
            break
    report.stages.append(
        StageReport(
            si,
            st.alpha,
            st.beta,
            st.gamma,
            st.resolution,
            it + 1,
            converged,
            en,
            time.perf_counter() - t_stage,
            n_fact,
            n_reused,
        )
    )


def final_report(
    scan: Scan,
    index: ScanIndex,
    ops: TemplateOperators,
    full: ResolutionLevel,
    frame: SolverFrame,
    body: InitialBody,
    state: _StageState,
    report: FitReport,
    *,
    max_distance: float,
    max_angle_deg: float,
    shape_prior: bool,
    t_start: float,
    assess: bool = True,
    absent_parts: tuple[str, ...] = (),
) -> FitResult:
    """Final report: the fitted body in metres, its data weights and no-data fraction, the
    scan→fit distance (mean, p95) and the per-part quality check (``core.registration.quality``;
    ``absent_parts``: parts the scan does not hold); without ``assess`` only the body and its
    data weights."""
    F_full = np.asarray(ops.template.F, dtype=np.int64)
    if state.level is None or state.x is None:  # no refinement stage: the body prior's result
        A = np.broadcast_to(frame.A0, (full.n, 3, 4)).copy()
    else:
        A = affines_from_x(state.x)
        if state.level is not full:
            A = (ops.hierarchy.upsample @ A.reshape(state.level.n, 12)).reshape(-1, 3, 4)
    X = frame.to_world(apply_affines(A, full.V))
    # final correspondences, for the data weights and the no-data fraction of the result: only
    # the matched points count, not their projected targets (the nearest-point shortcut)
    final = index.closest_compatible(
        X, vertex_normals(X, F_full), max_distance=max_distance, max_angle_deg=max_angle_deg,
        project=False,
    )  # fmt: skip
    weights_full = final.weights * full.data_mask
    unseen = np.zeros(full.n, bool)
    if state.no_skin is not None and len(state.no_skin):
        unseen[state.no_skin] = True
        weights_full[unseen] = 0.0
        report.notes.append(
            f"refinement: {int(unseen.sum()):,} vertices where the scan shows no skin over the "
            f"body prior (their closest data lay over {NORMAL_LINE_MAX_OFFSET_M * 1000:.0f} mm "
            "along the surface: thighs or folds pressed together, a heavy body's crotch, "
            "occluded skin) keep the body prior's; the quality check's fit→scan p95 leaves "
            f"them out where they are at most {MAX_UNSEEN_SHARE:.0%} of a part"
        )
    report.no_data_fraction = float(np.mean(~(final.weights > 0)))
    report.template_region_fraction = float(np.mean(~full.data_mask))
    if not assess:
        report.seconds = time.perf_counter() - t_start
        return FitResult(
            vertices=X, faces=F_full, affines=frame.affines_to_world(A),
            data_weight=weights_full, report=report, body_prior=body.prior,
        )  # fmt: skip
    # scan→fit distance on a fixed subsample of scan points, shared with the per-part check
    sample = np.linspace(0, len(scan.V) - 1, min(len(scan.V), SAMPLE_POINTS)).astype(np.int64)
    d = MeshDistance(X, F_full, k=3).distances(scan.V[sample])
    report.scan_to_fit_mean_m = float(np.mean(d))
    report.scan_to_fit_p95_m = float(np.percentile(d, 95))
    report.quality = assess_fit(
        index,
        X,
        template=ops.template,
        scan_to_fit=d,
        sample_ids=sample,
        reference=body.V if shape_prior else None,
        unseen=unseen,
        mittens=state.mitten_sides,
        mitten_m=index.closing_radius_m,
        absent=absent_parts,
    )
    if report.quality.quality != "good":
        report.warnings.append(report.quality.summary())
    layers = spread_warning(report.quality)
    if layers:
        report.warnings.append(layers)
    report.seconds = time.perf_counter() - t_start
    return FitResult(
        vertices=X, faces=F_full, affines=frame.affines_to_world(A), data_weight=weights_full,
        report=report, body_prior=body.prior,
    )  # fmt: skip


RETRIES = (
    # (name, options): tried in this order while the fit's quality is not good, each a change
    # of the caller's options from the body-prior start (initial_pose) of the best attempt so
    # far; "arm_abduction" starts the body prior's upper arms of the sides whose arm or hand is
    # not good that far out (skipped when both arms and hands are good)
    ("arms started 10° out", {"arm_abduction": 10.0}),
    ("arms started 30° out", {"arm_abduction": 30.0}),
    ("markers trusted", {"marker_trust": 1.0}),
    ("lost parts weighted x4, scan→body pairs", {"part_weight": 4.0, "bidirectional": True}),
)
_RANK = {"good": 0, "suspect": 1, "failed": 2}


def attempt_score(res: FitResult) -> tuple[int, float, int, float]:
    """Lower is better: verdict, the scan→fit p95 summed over the parts not good (unexplained
    data where the fit is weak; a part without scan points near it counts as lost,
    ``LOST_SCAN_TO_FIT_M``), their number, the whole scan's scan→fit p95. The sum before the
    number: a part lost far off its data can hide the others' flaws (marker closed_touching-17
    of ``bench.realworld``: a head 108 mm off, alone failed, won over a head 53 mm off with a
    hand too far along its forearm, both failed; scan→fit p95 37 vs 2 mm)."""
    q = res.report.quality
    if q is None:
        return (0, 0.0, 0, res.report.scan_to_fit_p95_m)
    weak = [p for p in q.parts.values() if p.quality != "good"]
    unexplained = sum(
        max(
            float(np.nan_to_num(p.scan_to_fit_p95_m, nan=LOST_SCAN_TO_FIT_M))
            - spread_allowance(p.scan_spread_m),
            0.0,
        )
        for p in weak
    )
    return (_RANK[q.quality], unexplained, len(weak), res.report.scan_to_fit_p95_m)


def _run(scan: Scan, markers: dict[str, np.ndarray], callback, options: dict) -> FitResult:
    for item in iter_fit(scan, markers, **options):
        if isinstance(item, FitResult):
            return item
        if callback is not None and callback(item) is False:
            raise FitCancelled(f"fit cancelled at stage {item.stage}, iteration {item.iteration}")
    raise RuntimeError("iter_fit ended without a result")  # pragma: no cover


@single_blas_thread
def fit(
    scan: Scan,
    markers: dict[str, np.ndarray],
    *,
    callback: Callable[[Progress], bool | None] | None = None,
    retry: bool = True,
    schedule: Schedule | None = None,
    template: Template | None = None,
    max_distance: float = 0.10,
    max_angle_deg: float = 90.0,
    confidence_full_at: float = CONFIDENCE_FULL_AT,
    marker_far_distance: float = 0.10,
    n_low: int = 2500,
    unit_scale: float = 1000.0,
    shape_prior: bool = True,
    marker_outlier_distance: float = 0.05,
    initial_similarity: Similarity | None = None,
    prior_options: PriorOptions | dict[str, Any] | None = None,
    marker_trust: float | None = None,
    part_weights: dict[str, float] | None = None,
    index: ScanIndex | None = None,
    assess: bool = True,
    retries: tuple[tuple[str, dict[str, Any]], ...] = RETRIES,
    prior_restart: PriorRestart | None = None,
    soft_markers: bool = False,
    absent_parts: tuple[str, ...] = (),
) -> FitResult:
    """Fit the template to ``scan`` guided by ``markers``; the options are :func:`iter_fit`'s.

    ``callback(progress)`` is called after every correspondence update; returning ``False``
    cancels the fit (:class:`FitCancelled`).

    With ``retry`` (default) a fit whose quality check (``core.registration.quality``) is not
    ``good`` is re-run with the body prior changed (:data:`RETRIES`: the upper arms of the sides
    whose arm or hand is not good started 10°, then 30° from the body's side — another
    initialisation, kept for the later retries when it was better; every marker trusted at full
    weight; the parts that are not good weighted ×4 with scan→body pairs), and the best result
    is kept (verdict, then parts not good, then their scan→fit p95, then the scan's: see
    :func:`attempt_score`): at most 1 + ``len(RETRIES)`` fits. The report's notes list the
    attempts; a part still lost stays in the verdict with its name. ``retries``: the retries
    to try (a subset of :data:`RETRIES`, in its order; the markerless fit keeps only those its
    own landmarks do not undo, :data:`core.matching.markerless.MARKERLESS_RETRIES`). Without
    ``assess`` (see :func:`iter_fit`) there is no quality check and so no retry; nor is there
    one for parts the scan cannot place (:attr:`core.registration.quality.FitQuality.unresolved`:
    a hand resting on the body), only for :meth:`~core.registration.quality.FitQuality.weak_parts`.
    """
    options: dict[str, Any] = {
        "schedule": schedule, "template": template, "max_distance": max_distance,
        "max_angle_deg": max_angle_deg, "confidence_full_at": confidence_full_at,
        "marker_far_distance": marker_far_distance, "n_low": n_low, "unit_scale": unit_scale,
        "shape_prior": shape_prior, "marker_outlier_distance": marker_outlier_distance,
        "initial_similarity": initial_similarity, "prior_options": prior_options,
        "marker_trust": marker_trust, "part_weights": part_weights, "assess": assess,
        "prior_restart": prior_restart, "soft_markers": soft_markers,
        "absent_parts": absent_parts,
    }  # fmt: skip
    options["index"] = scan_index(scan, index, confidence_full_at)  # shared by the retries
    res = _run(scan, markers, callback, options)
    q = res.report.quality
    if not retry or q is None or not q.weak_parts() or not shape_prior:
        return res
    attempts = [f"first fit: {q.quality}"]
    best = res
    start = PriorOptions.of(prior_options).initial_pose  # the best attempt's body-prior start
    for name, opt in retries:
        bq = best.report.quality
        assert bq is not None
        weak = bq.weak_parts()  # a hand resting on the body (unresolved) calls for no retry
        if not weak:
            break
        o = dict(options)
        # a retry runs the body prior from the usual start only (not the restart's second one,
        # ~0.45 s CPU per attempt: a retry changes the weights or the arms' start)
        o["prior_restart"] = None
        po = PriorOptions.of(o.get("prior_options"))
        opt = dict(opt)  # "iterations": the retry's body prior's own count, for any retry
        po = replace(po, initial_pose=start, iterations=int(opt.pop("iterations", po.iterations)))
        o["prior_options"] = po
        if "arm_abduction" in opt:
            sides = "".join(x for x in "LR" if f"arm_{x}" in weak or f"hand_{x}" in weak)
            if not sides:
                continue
            pose = {**(po.initial_pose or {}), **arm_pose(opt["arm_abduction"], sides)}
            o["prior_options"] = replace(po, initial_pose=pose)
        elif "part_weight" in opt:
            o["part_weights"] = {p: opt["part_weight"] for p in weak}
            o["prior_options"] = replace(po, bidirectional=bool(opt["bidirectional"]))
        else:
            o.update(opt)
        r = _run(scan, markers, callback, o)
        rq = r.report.quality
        attempts.append(f"{name}: {rq.quality if rq else 'n/a'}")
        if attempt_score(r) < attempt_score(best):
            best, start = r, PriorOptions.of(o["prior_options"]).initial_pose
    best.report.notes.append(
        "quality retries: " + "; ".join(attempts) + f" (kept: {best.report.quality.quality})"
    )
    return best
