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
  them (a part shifted along its data);
- ``data_beyond_m`` (hands only, else NaN): how far unexplained scan data reaches beyond the fitted
  hand's tip along the forearm axis (:func:`data_beyond_hand`). A hand that slid up the forearm
  sits on the forearm's data (coverage, fit→scan and area look fine) but leaves the real hand's
  scan points beyond it; mitten and fist hands end where the fitted hand ends or before;
- ``hand_bend_deg`` (hands only): angle between the forearm axis and the direction from the wrist
  to the centroid of the hand without its fingers (the template's ``bad_scan`` vertices; a hand
  folded back or off the arm's end; 12-14° on the truths of open and fisted hands alike, 12-21°
  on good fits — scanning postures keep the wrists straight);
- ``hand_proportion`` (hands only): ``max(r, 1/r)``, ``r`` = the reach of the hand without its
  fingers beyond the wrist (along the forearm axis) per forearm length, over the template's
  (0.43); a hand slid up a shortened forearm or stretched along it (1.00-1.10 on the truths of
  open and fisted hands, 1.01-1.19 on good fits). Without the fingers both figures read a fist
  as they read an open hand (with them, true fists read 27-30° and 1.56-1.66).
- ``hand_tip_gap_m`` (hands only): median distance to the scan surface of the fitted hand's
  furthest tenth of vertices along the forearm axis (the fingertips, which the data term does not
  pull): an open template hand fitted to a fist leaves its fingers 4-9 cm out in the air while
  the wrist and the back of the hand sit on the data (``core.synth.scanner_outputs`` fist cases
  closed_lowres-16/24/26, raw-16/24: 46-86 mm, hand centroids 44-63 mm off the truth's); good
  fits of open and mitten hands read 2-16 mm, the truths 1-11 mm.
- ``hand_body_gap_m`` (hands only): the 5th percentile of the distances from the fitted hand
  (without its fingers) to the fitted torso and thighs (:func:`hand_body_gaps`). A hand resting on
  the thigh or hip is fused with it in a closed mesh (and half hidden in a raw scan): the data
  cannot tell where the hand ends, and every other hand figure reads fine wherever the fit put
  it. ``bench.realworld --booth`` (40 booth meshes, 10-15 k vertices, a8370f8): the 13 hands
  45-136 mm off the truth's all read < 15 mm; of the hands reading ≥ 30 mm none is more than
  40 mm off (arms 7-57° out: 16-500 mm). Suspect below 15 mm, never failed (a hand can rest
  there): the hand is then still fitted, and the report says its place is a guess.
- ``head_turn_deg`` (head only, else NaN): the angle of the head's rotation against the torso's,
  each the rotation of the least-squares similarity taking the template's part onto the body's
  (all its vertices, weighted by their area on the template; :func:`head_figures`). A head fitted
  flexed, turned or tilted on the skull's data keeps its scan→fit, fit→scan and coverage (the
  skull is nearly round): markerless raw-19 of ``core.synth.scanner_outputs`` (before the head
  prior, :data:`core.registration.shape_prior.HEAD_PRIOR`) turned 58° off the truth's, 72 mm off,
  scan→fit p95 5 mm. Scanning protocols keep the head facing forward: the truths of
  ``core.synth.realworld`` postures (neck flexion ≤ 20°, yaw ±15°, roll ±5°; seeds 0-199, free
  and touching arms) read 1.6-24.6°, ``bench.cases`` truths and fits (seeds 0-3, 101) 4-14°,
  ``bench.realworld`` fits (17 marker, 15 markerless, f96b149) with the head ≤ 20 mm off the
  truth's 8-27.5°, heads 39-59 mm off 36.4-37.8° (marker closed_plate-3, cloud-6; a retry of
  markerless closed_plate-27); a head turned 40° on a good fit reads 26-54° (its own posture
  adds or takes off). All the head's vertices, not three landmarks: a marker fit's
  tragion/sellion vertices follow the user's markers, whose conventions move them by
  centimetres (a landmark-frame figure read 32-174° on correct marker fits), so marker fits are
  judged too.
- ``head_distortion_m`` (head only): the area-weighted RMS distance of the head's vertices from
  the template's head taken onto them by that similarity (:func:`head_figures`): how far the
  head's shape is from a head's. A face slid down along the skull's data keeps the part on its
  data: marker closed_touching-17 (sellion 59 mm, menton 66 mm, crown 14 mm below the truth's,
  head 53 mm off; scan→fit p95 7 mm, fit→scan p95 12 mm, coverage 0.80) read `good` before this
  figure and reads 19.8 mm; markerless dense-23 (head 45 mm off) 25.2 mm, closed_plate-27 (29
  mm off) 17.1 mm. Truths (seeds 0-199)
  read 5.7-9.2 mm, ``bench.cases`` 6-8.6 mm, ``bench.realworld`` fits with the head ≤ 20 mm off
  6.0-12.7 mm (hair volumes and marker conventions bend the head: closed_hair-1 11.8 mm).
- ``leg_proportion`` (legs only): ``max(r, 1/r)``, ``r`` = the inseam (crotch landmark → the
  ankle's shin/foot ring) per trunk (crotch → the neck/torso ring) over the template's
  (:func:`leg_proportion`). Legs that touch hide the crotch from the data: markerless raw-31
  (feet 1 cm apart) slid the pelvis down over the thighs (crotch 208 mm, hip rings 114 mm below
  the truth's, ankles in place; legs 70 mm off, every other figure in range) and reads 1.59.
  Truths (seeds 0-199) read ≤ 1.21, ``bench.realworld`` fits with the leg ≤ 20 mm off ≤ 1.17.
- ``arm_symmetry`` (arms only, the same on both): ``max(r, 1/r)``, ``r`` = the left arm's length
  over the right's, each shoulder ring → elbow ring → wrist ring (:func:`arm_symmetry`; the
  elbow's bend does not change it). An arm along a heavy body's side stretches down the flank's
  data: markerless ``bench.realworld --heavy`` raw-102 (BMI 51, arms 12°) put the left hand
  124 mm, the forearm 54 mm below the truth's with every arm and hand figure in range; it reads
  1.18. Real people's arms differ by ~1-2 %; the generator's truths read 1.00, the 40
  ``bench.realworld`` markerless fits (96d164e) 1.000-1.080 (arms and hands ≤ 34 mm off), the
  20 heavy ones 1.001-1.038 where arms and hands are ≤ 39 mm off and 1.14-1.18 where a hand is
  66-124 mm off (raw-63, closed_lowres-102, raw-102).
- ``foot_turn_deg`` (feet only): the angle about the torso's vertical axis between the foot's
  heel → toe direction and the template's, in the torso's frame (:func:`foot_turn`). A foot
  turned about the ankle keeps its leg in place: markerless closed_lowres-4 of
  ``core.synth.scanner_outputs`` meshed on a 17 mm grid (8 k vertices, feet 2 cm apart) turned
  its left foot 100° inwards (135 mm off the truth's) and read `suspect` only from the feet's
  unexplained data. Standing people point their feet forward, each turned out by up to ~30°;
  the generator's truths read ≤ 7°, the 40 ``bench.realworld`` markerless fits (4cf7dbc) ≤ 3°.
- ``feet_apart_m`` (feet only, the same on both): how far the left foot's centroid lies to the
  body's left of the right foot's, in the torso's frame (:func:`feet_apart`). Legs crossed, each
  foot fitted on the other's data, keep every foot figure in range: markerless ``bench.realworld
  --heavy`` raw-59 (BMI 47; feet 139-162 mm off the truth's, pointing forward) read `suspect`
  from the legs' unexplained data only, -0.15 m here (the truth +0.15). Nobody is scanned with
  crossed legs; feet together read about a foot's width.
- ``sternum_proportion`` (torso only): ``max(r, 1/r)``, ``r`` = where the sternum's lower end
  (Substernale) lies on the way navel (Omphalion) → Suprasternale, as a share of it, over the
  template's (0.49; :func:`sternum_proportion`). A torso whose skin slid along the trunk keeps it
  on its data: markerless ``bench.realworld --palms`` raw_palms-605 (BMI 45) put the Substernale
  137 mm up, the nipples 28 cm up, above the Suprasternale (torso centroid 47 mm off the truth's,
  every figure `good`); it reads 1.83. The truths of the five ``bench.realworld`` sets (144
  bodies, BMI 15-57) read ≤ 1.21, their fits ≤ 1.36 but for two heavy ones (1.46: closed_lowres-63,
  breasts outside the shape space; 1.83).

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
data beyond the hand    > 25 mm      > 40 mm
hand bend               > 30°        > 45°
hand proportion         > 1.25       > 1.40
hand tip gap            > 30 mm      never
hand–body gap           < 15 mm      never
head turn               > 32°        > 36°
head distortion         > 14 mm      > 18 mm
leg proportion          > 1.30       > 1.45
arm symmetry            > 1.10       > 1.13
foot turn               > 45°        > 60°
feet apart              < 30 mm      < 0 mm
sternum proportion      > 1.40       > 1.60
======================  ===========  ==========

and a part is also ``failed`` when scan data around it is unexplained (scan→fit p95 > 25 mm)
*and* its own surface is off its data or shrunk/grown by the refinement (coverage < 0.70,
fit→scan p95 > 30 mm, or area change against the given reference > 1.25): a head collapsed into
the neck keeps its vertices on the neck's data (fit→scan and coverage look fine) but shrinks and
leaves the skull's scan points unexplained. A hand that slid along its data onto the forearm's
shows as scan data beyond its tip, a bent wrist or a wrong hand/forearm proportion (the
hand-specific limits above are not scaled by the extremity factor). Calibration (fits of
``bench.cases`` seeds 0-3 and 101 and of good ``bench.realworld`` marker cases all read 0 mm,
14-18°, 0.87-1.13; lost hands — closed_hair seed 1, cloud seed 6, hands 15-40 cm off the truth —
read 97 mm, 55° and 148°; closed_touching seed 5's forearms shortened by 22-29 % read 1.49/1.74).

Scan→fit alone never fails a part: scan points the body does not explain may be hair, clothing,
clutter or the floor as well as a misplaced part; a part off its data also loses coverage and
fit→scan, and those fail it. (Measured on ``core.synth.scanner_outputs`` cases: hair, mitten or
fist hands and floor clutter give hand/head/foot scan→fit p95 of 15-350 mm with the part in place.)

A scan whose surfaces disagree with themselves (a subject who moved between a sequential
scan's views, or views misregistered: the same skin recorded twice, millimetres apart) leaves
data no body can explain. ``scan_spread_m`` (per part, the scan's own, not the fit's) is the
median, over the scan points within ``NEAR_DISTANCE_M`` of the part, of the standard deviation
of the offsets along the fitted surface's normal of their :data:`SPREAD_NEIGHBOURS` nearest
sampled neighbours, found where the points fall on the fitted surface (:func:`scan_spread`): a
layer's noise reads its sigma, two layers half their distance.
The hands and feet take their arm's and leg's (fingers and toes fitted apart from the scan's
read as spread there). Where it exceeds :data:`SPREAD_NOISE_M`, a part's scan→fit p95 limits
rise by :data:`SPREAD_P95_FACTOR` × the excess; a part suspect only by scan→fit p95 within
that allowance stays ``suspect`` with the spread as its reason, and is *unresolved* (another
fit cannot explain the scan better: no quality retry). Measured (``bench.realworld``, fits and
truths read within 0.3 mm of each other): raw scans 0.8-1.1 mm, point clouds 0.8-1.0, closed
meshes 0.3-0.6, dense clouds 0.5-0.8, hair 1.0-1.2; ``--swayed`` scans (crown 3-12 mm RMS
between views, arms drifting 0.5-2°) head 1.9-3.3, arms 1.7-3.9, torso 1.6-2.0, legs 1.2-1.5
mm. A retry that weighted such a head ×4 bent the body to cover both layers: raw_swayed-1202
9.5 -> 20.5 mm from the truth.

A part with fewer than ``MIN_POINTS`` scan points assigned has no scan→fit figures (reported as
NaN); it is judged by its fit→scan and coverage only. Hands and feet are held to thresholds 1.5×
looser (scanners capture them worst; they are small, so a few stray points move the p95).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from core.geometry import MeshDistance, umeyama, vertex_areas
from core.registration.correspondence import ScanIndex
from core.registration.operators import vertex_normals
from core.scan import Scan
from core.template import Template, load_template
from core.threads import kd_workers

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
#: The fingertip-gap reason's hint (a scanned fist under an open hand), left out where the part
#: has no scan data at all
FIST_HINT = "(an open hand fitted to a fist?)"
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
    "data_beyond_m": Threshold(0.025, 0.040),
    "hand_bend_deg": Threshold(30.0, 45.0),
    "hand_proportion": Threshold(1.25, 1.40),
    "hand_tip_gap_m": Threshold(0.030, float("inf")),
    "hand_body_gap_m": Threshold(0.015, -float("inf"), higher_is_worse=False),
    "head_turn_deg": Threshold(32.0, 36.0),
    "head_distortion_m": Threshold(0.014, 0.018),
    "leg_proportion": Threshold(1.30, 1.45),
    "arm_symmetry": Threshold(1.10, 1.13),
    "foot_turn_deg": Threshold(45.0, 60.0),
    "feet_apart_m": Threshold(0.03, 0.0, higher_is_worse=False),
    "sternum_proportion": Threshold(1.40, 1.60),
}
#: figures whose limits already are the hands' own (not scaled by ``EXTREMITY_FACTOR``)
HAND_FIGURES = (
    "data_beyond_m", "hand_bend_deg", "hand_proportion", "hand_tip_gap_m", "hand_body_gap_m",
)  # fmt: skip
#: a hand suspect by the first (resting on the body) and at most the second (the mitten fused
#: with the thigh leaves data the template hand cannot explain) is :attr:`FitQuality.unresolved`:
#: the scan cannot place it, another fit would not either
AMBIGUOUS_FIGURES = ("hand_body_gap_m", "scan_to_fit_p95_m")
#: figures read off the part's scan data (not judged on a part the scan does not hold)
DATA_FIGURES = ("scan_to_fit_p95_m", "fit_to_scan_p95_m", "coverage", "displacement_m")
#: figures of one part only (NaN on the others)
PART_FIGURES = {
    **dict.fromkeys(HAND_FIGURES, ("hand_L", "hand_R")),
    "head_turn_deg": ("head",),
    "head_distortion_m": ("head",),
    "leg_proportion": ("leg_L", "leg_R"),
    "arm_symmetry": ("arm_L", "arm_R"),
    "foot_turn_deg": ("foot_L", "foot_R"),
    "feet_apart_m": ("foot_L", "foot_R"),
    "sternum_proportion": ("torso",),
}
UNSCALED = tuple(PART_FIGURES)
BEYOND_MIN_POINTS = 20
BEYOND_RADIUS_M = 0.10
BEYOND_UNEXPLAINED_M = 0.010
LOST_SCAN_TO_FIT_M = 0.025
#: Largest share of a part's vertices the scan may show no skin over (``assess_fit(unseen=)``:
#: the refinement kept the body prior's there) for them to be left out of its fit→scan p95:
#: thighs pressed together hide their inner skin, and the truth's own fit→scan p95 there reads
#: 30-40 mm (``bench.realworld`` raw-31: legs 39.7 / 38.8 mm). A part mostly without skin over
#: it is misplaced, not hidden: its figure counts every vertex.
MAX_UNSEEN_SHARE = 0.25
LOST_AREA_CHANGE = 1.25
#: Sampled neighbours (``assess_fit``'s scan sample) whose offsets along the fitted surface's
#: normal give a scan point's local spread (:func:`scan_spread`): ~2 cm about it on a body.
SPREAD_NEIGHBOURS = 12
#: A scan's own spread (metres) up to which it is scanner noise: raw scans read 0.8-1.1 mm.
SPREAD_NOISE_M = 0.0015
#: Scan→fit p95 allowance per metre of spread beyond :data:`SPREAD_NOISE_M` (a Gaussian's p95
#: of the absolute value is 1.96 sigma).
SPREAD_P95_FACTOR = 2.0
#: A scan whose own spread exceeds this (metres) on a part of the body's (not a hand or foot:
#: they take their limb's) gets a warning (:func:`spread_warning`): still scans read ≤ 1.2 mm
#: (hair 1.0-1.2), ``--swayed`` scans 1.2-3.9, a raw scan with 2.5 mm noise (a consumer
#: handheld scanner's) 1.8-2.2.
SPREAD_WARN_M = 0.002
#: The part whose spread a hand or foot takes (:func:`scan_spread`).
SPREAD_FROM = {"hand_L": "arm_L", "hand_R": "arm_R", "foot_L": "leg_L", "foot_R": "leg_R"}


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
    data_beyond_m: float = float("nan")
    hand_bend_deg: float = float("nan")
    hand_proportion: float = float("nan")
    hand_tip_gap_m: float = float("nan")
    hand_body_gap_m: float = float("nan")
    head_turn_deg: float = float("nan")
    head_distortion_m: float = float("nan")
    leg_proportion: float = float("nan")
    arm_symmetry: float = float("nan")
    foot_turn_deg: float = float("nan")
    feet_apart_m: float = float("nan")
    sternum_proportion: float = float("nan")
    scan_spread_m: float = float("nan")


@dataclass
class FitQuality:
    """A fit's verdict, the reasons for it (each naming the part) and per-part figures."""

    quality: Verdict
    reasons: list[str] = field(default_factory=list)
    parts: dict[str, PartQuality] = field(default_factory=dict)
    thresholds: dict[str, dict[str, float | None]] = field(default_factory=dict)  # None: never
    #: hands that are suspect only by :data:`AMBIGUOUS_FIGURES`: the scan cannot place them
    #: better (another fit would not either), so they call for no retry
    unresolved: list[str] = field(default_factory=list)

    def weak_parts(self) -> list[str]:
        """Parts not good that another fit could improve (not only :attr:`unresolved`)."""
        return [
            n for n, p in self.parts.items() if p.quality != "good" and n not in self.unresolved
        ]

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
        k: t
        if k in UNSCALED
        else Threshold(t.suspect * f, t.failed * f)
        if t.higher_is_worse
        else Threshold(t.suspect / f, t.failed / f, higher_is_worse=False)
        for k, t in THRESHOLDS.items()
    }


def _judge(
    part: str, figures: dict[str, float], allowance: dict[str, float] | None = None
) -> tuple[Verdict, list[str], set[str]]:
    """The part's verdict, the reasons and the figures beyond a limit (``allowance``: figure ->
    metres added to both its limits)."""
    verdict: Verdict = "good"
    reasons: list[str] = []
    keys: set[str] = set()
    rank = {"good": 0, "suspect": 1, "failed": 2}
    for key, lim in _limits(part).items():
        if allowance and key in allowance:
            a = allowance[key]
            lim = Threshold(lim.suspect + a, lim.failed + a, lim.higher_is_worse)
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
        keys.add(key)
        if rank[level] > rank[verdict]:
            verdict = level
        if key == "coverage":
            reasons.append(f"{part}: only {v * 100:.0f} % of its surface has scan data nearby")
        elif key == "displacement_m":
            reasons.append(f"{part}: {v * 1000:.0f} mm away from its scan data")
        elif key == "data_beyond_m":
            reasons.append(
                f"{part}: scan data reaches {v * 1000:.0f} mm beyond it along the forearm "
                "(the hand slid up the arm?)"
            )
        elif key == "hand_bend_deg":
            reasons.append(f"{part}: bent {v:.0f}° off the forearm axis (misplaced hand?)")
        elif key == "hand_proportion":
            reasons.append(
                f"{part}: hand/forearm proportion {v:.2f}× the template's "
                "(hand slid along a shortened forearm?)"
            )
        elif key == "hand_tip_gap_m":
            reasons.append(
                f"{part}: its fingertips are {v * 1000:.0f} mm from the scan {FIST_HINT}"
            )
        elif key == "hand_body_gap_m":
            reasons.append(
                f"{part}: rests on the torso or thigh ({v * 1000:.0f} mm from it): where the "
                "hand ends and the body begins is not in the scan (fused in a closed mesh), so "
                "its place may be off by centimetres"
            )
        elif key == "head_turn_deg":
            reasons.append(
                f"{part}: turned {v:.0f}° against the torso (a scanning posture faces forward; "
                "head fitted tilted or turned on its data?)"
            )
        elif key == "head_distortion_m":
            reasons.append(
                f"{part}: its shape is {v * 1000:.0f} mm (RMS) from a head's (face slid down "
                "or round the skull?)"
            )
        elif key == "leg_proportion":
            reasons.append(
                f"{part}: crotch-to-ankle/crotch-to-neck proportion {v:.2f}× the template's "
                "(legs slid along their data, the crotch misplaced?)"
            )
        elif key == "arm_symmetry":
            reasons.append(
                f"{part}: the arms' lengths differ {v:.2f}× (an arm stretched or shortened "
                "along its data, its hand misplaced?)"
            )
        elif key == "foot_turn_deg":
            reasons.append(
                f"{part}: turned {v:.0f}° from the body's forward direction (a standing person's "
                "feet point forward; foot fitted on the other foot's or the floor's data?)"
            )
        elif key == "feet_apart_m":
            reasons.append(
                f"{part}: the left foot's centre is {v * 1000:.0f} mm left of the right foot's "
                "(legs crossed: each foot fitted on the other's data?)"
            )
        elif key == "sternum_proportion":
            reasons.append(
                f"{part}: the sternum's end (navel to suprasternal notch) {v:.2f}× off the "
                "template's share (the torso's skin slid along the trunk: chest or belly "
                "misplaced?)"
            )
        elif key == "scan_to_fit_p95_m":
            reasons.append(f"{part}: scan→fit p95 {v * 1000:.0f} mm")
        else:
            reasons.append(f"{part}: fit→scan p95 {v * 1000:.0f} mm")
    return verdict, reasons, keys


def _ring_centre(X: np.ndarray, own: np.ndarray, other: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Centroid (3,) of the vertices of mask ``own`` sharing an edge (E (m, 2)) with ``other``."""
    a, b = own[E[:, 0]] & other[E[:, 1]], own[E[:, 1]] & other[E[:, 0]]
    return X[np.unique(np.concatenate([E[a, 0], E[b, 1]]))].mean(axis=0)


def _forearm_frame(X: np.ndarray, side: str, tpl: Template) -> tuple[np.ndarray, np.ndarray, float]:
    """Wrist (3,), unit forearm axis (3,) (elbow ring → wrist ring, forearm vertices only, so a
    displaced hand does not move them) and the hand's reach beyond the wrist along it, metres."""
    fore, upper = tpl.part_mask(f"forearm_{side}"), tpl.part_mask(f"upper_arm_{side}")
    hand = tpl.part_mask(f"hand_{side}")
    E = np.asarray(tpl.edges, dtype=np.int64)
    elbow, wrist = _ring_centre(X, fore, upper, E), _ring_centre(X, fore, hand, E)
    a = wrist - elbow
    length = max(float(np.linalg.norm(a)), 1e-9)
    return wrist, a / length, length


def _hand_tips(X: np.ndarray, side: str, tpl: Template) -> np.ndarray:
    """Vertex ids of the furthest tenth of the hand's vertices along the forearm axis."""
    ids = np.flatnonzero(tpl.part_mask(f"hand_{side}"))
    wrist, a, _ = _forearm_frame(X, side, tpl)
    along = (X[ids] - wrist) @ a
    return ids[along >= np.percentile(along, 90)]


def hand_tip_gap(index: ScanIndex, X: np.ndarray, side: str) -> float:
    """``hand_tip_gap_m`` of hand ``side`` (``"L"``/``"R"``) of the body ``X`` (13380, 3): the
    median distance of its fingertips to the scan surface, metres (module docstring)."""
    tpl = load_template()
    tips = _hand_tips(X, side, tpl)
    return float(np.median(fit_to_scan_distance(index, X[tips])))


def hand_figures(
    X: np.ndarray,
    P: np.ndarray,
    scan_to_fit: np.ndarray,
    side: str,
    template: Template | None = None,
    p_part16: np.ndarray | None = None,
    fit_to_scan: np.ndarray | None = None,
    body_gap: float | None = None,
) -> dict[str, float]:
    """Where the fitted hand sits on its arm: data beyond it, bend, proportion, tip gap.

    ``X`` (13380, 3) fitted body; ``P`` (q, 3) scan points with distances ``scan_to_fit`` (q,) to
    the fitted surface; ``p_part16`` (q,) the template part of each point's nearest fitted vertex
    (computed when omitted); ``side`` ``"L"`` or ``"R"``; ``fit_to_scan`` (13380,) each fitted
    vertex's distance to the scan surface (:func:`fit_to_scan_distance`; without it the tip
    gap is NaN); ``body_gap`` this hand's :func:`hand_body_gaps` when already computed.
    ``data_beyond_m``: the points of this
    side's forearm or hand within ``BEYOND_RADIUS_M`` of the forearm axis line and further than
    ``BEYOND_UNEXPLAINED_M`` from the fit are projected on the axis; the ``BEYOND_MIN_POINTS``-th
    largest projection minus the fitted hand's furthest (0 when fewer points lie beyond).
    Definitions of the other two: module docstring.
    """
    tpl = template or load_template()
    hand = tpl.part_mask(f"hand_{side}")
    palm = hand & ~np.asarray(tpl.bad_scan_mask, dtype=bool)  # the hand without its fingers
    wrist, a, fore_len = _forearm_frame(X, side, tpl)
    reach = float(((X[hand] - wrist) @ a).max())
    c = X[palm].mean(axis=0) - wrist
    cos = float(c @ a) / max(float(np.linalg.norm(c)), 1e-12)
    bend = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    t_wrist, t_a, t_len = _forearm_frame(tpl.V, side, tpl)
    t_ratio = float(((tpl.V[palm] - t_wrist) @ t_a).max()) / t_len
    r = max(float(((X[palm] - wrist) @ a).max()) / fore_len / t_ratio, 1e-9)
    if p_part16 is None:
        from scipy.spatial import cKDTree

        p_part16 = np.asarray(tpl.part)[cKDTree(X).query(P, k=1, workers=kd_workers())[1]]
    names = tpl.part_names
    mine = (p_part16 == names.index(f"forearm_{side}")) | (p_part16 == names.index(f"hand_{side}"))
    D = P - wrist
    s = D @ a
    rad = np.linalg.norm(D - s[:, None] * a, axis=1)
    sel = mine & (rad < BEYOND_RADIUS_M) & (scan_to_fit > BEYOND_UNEXPLAINED_M) & (s > reach)
    beyond = 0.0
    if sel.sum() >= BEYOND_MIN_POINTS:
        beyond = float(np.sort(s[sel])[-BEYOND_MIN_POINTS] - reach)
    gap = float("nan")
    if fit_to_scan is not None:
        gap = float(np.median(fit_to_scan[_hand_tips(X, side, tpl)]))
    return {
        "data_beyond_m": beyond,
        "hand_bend_deg": bend,
        "hand_proportion": max(r, 1.0 / r),
        "hand_tip_gap_m": gap,
        "hand_body_gap_m": hand_body_gaps(X, tpl)[side] if body_gap is None else body_gap,
    }


#: template parts a hand hanging at the side meets (torso and thighs)
HAND_REST_PARTS = ("torso", "pelvis", "thigh_L", "thigh_R")


def hand_body_gaps(X: np.ndarray, template: Template | None = None) -> dict[str, float]:
    """``hand_body_gap_m`` of both hands of the body ``X`` (13380, 3), metres, by side
    (``"L"``, ``"R"``): the 5th percentile of the distances from the hand's vertices without
    its fingers to the fitted torso and thighs (:data:`HAND_REST_PARTS`; the triangles of those
    parts only)."""
    tpl = template or load_template()
    X = np.asarray(X, dtype=np.float64)
    rest = np.zeros(tpl.n_vertices, dtype=bool)
    for p in HAND_REST_PARTS:
        rest |= tpl.part_mask(p)
    F = np.asarray(tpl.F, dtype=np.int64)
    new = np.cumsum(rest) - 1  # the rest parts' vertices renumbered
    md = MeshDistance(X[rest], new[F[rest[F].all(axis=1)]], k=4)
    fingers = np.asarray(tpl.bad_scan_mask, dtype=bool)
    return {
        side: float(np.percentile(md.distances(X[tpl.part_mask(f"hand_{side}") & ~fingers]), 5))
        for side in "LR"
    }


def head_figures(X: np.ndarray, template: Template | None = None) -> tuple[float, float]:
    """``(head_turn_deg, head_distortion_m)`` of the body ``X`` (13380, 3), from the
    least-squares similarities taking the template's head and torso onto the body's (all their
    vertices, each weighted by its area on the template, so the dense face does not dominate).

    head_turn_deg : the angle of the head's rotation against the torso's, degrees.
    head_distortion_m : the area-weighted RMS distance of the head's vertices from the template's
        head taken onto them, metres — how far the head's shape is from a head's.
    """
    tpl = template or load_template()
    X = np.asarray(X, dtype=np.float64)
    areas = vertex_areas(tpl.V, np.asarray(tpl.F, dtype=np.int64))
    head = tpl.part_mask("head")
    head_sim = umeyama(tpl.V[head], X[head], areas[head])
    turn = float(
        np.degrees(Rotation.from_matrix(_torso_rotation(X, tpl).T @ head_sim.R).magnitude())
    )
    r = X[head] - head_sim.apply(tpl.V[head])
    return turn, float(np.sqrt(np.average(np.sum(r**2, axis=1), weights=areas[head])))


def head_turn(X: np.ndarray, template: Template | None = None) -> float:
    """``head_turn_deg`` of the body ``X`` (13380, 3), degrees (:func:`head_figures`)."""
    return head_figures(X, template)[0]


#: Share of the template foot's length (heel → toe, along its axis) whose vertices make the heel
#: and the toe ends of :func:`foot_turn`.
FOOT_END_SHARE = 0.2


def _torso_rotation(X: np.ndarray, tpl: Template) -> np.ndarray:
    """(3, 3) rotation of the least-squares similarity taking the template's torso onto the
    body ``X``'s (area-weighted, as in :func:`head_figures`)."""
    areas = vertex_areas(tpl.V, np.asarray(tpl.F, dtype=np.int64))
    torso = tpl.part_mask("torso")
    return umeyama(tpl.V[torso], X[torso], areas[torso]).R


def feet_apart(
    X: np.ndarray, template: Template | None = None, torso_R: np.ndarray | None = None
) -> float:
    """``feet_apart_m`` of the body ``X`` (13380, 3): how far (metres) the left foot's centroid
    lies to the body's left of the right foot's, in the torso's frame (negative: the legs are
    crossed). The template's (legs apart in its rest pose) read 0.46 m. ``torso_R``: the
    torso's rotation (:func:`_torso_rotation`) if already known."""
    tpl = template or load_template()
    X = np.asarray(X, dtype=np.float64)
    X = X @ (_torso_rotation(X, tpl) if torso_R is None else torso_R)  # the torso's frame
    d = X[tpl.part_mask("foot_L")].mean(axis=0) - X[tpl.part_mask("foot_R")].mean(axis=0)
    return float(d[0])  # the template's left is +x


def foot_turn(
    X: np.ndarray,
    side: str,
    template: Template | None = None,
    torso_R: np.ndarray | None = None,
) -> float:
    """``foot_turn_deg`` of foot ``side`` (``"L"``/``"R"``) of the body ``X`` (13380, 3): the
    angle, degrees in [0, 180], about the torso's vertical axis between the foot's heel → toe
    direction and the template's own, in the torso's frame (the least-squares similarity taking
    the template's torso onto the body's, area-weighted as in :func:`head_figures`). Heel and toe
    are the centroids of the back and front :data:`FOOT_END_SHARE` of the template foot's
    vertices (a marker convention moving one landmark vertex does not move them). ``torso_R``:
    as for :func:`feet_apart`."""
    tpl = template or load_template()
    X = np.asarray(X, dtype=np.float64)
    R = _torso_rotation(X, tpl) if torso_R is None else torso_R
    foot = np.flatnonzero(tpl.part_mask(f"foot_{side}"))
    L = tpl.landmarks
    axis = tpl.V[L[f"Toe_tip_{side}"]] - tpl.V[L[f"Calcaneus_posterior_{side}"]]
    axis[1] = 0.0
    t = tpl.V[foot] @ (axis / np.linalg.norm(axis))
    lo, hi = np.quantile(t, [FOOT_END_SHARE, 1.0 - FOOT_END_SHARE])
    heel, toe = foot[t <= lo], foot[t >= hi]

    def yaw(V: np.ndarray) -> float:
        d = V[toe].mean(axis=0) - V[heel].mean(axis=0)
        return float(np.degrees(np.arctan2(d[0], d[2])))

    a = yaw(X @ R) - yaw(tpl.V)  # X @ R: the body in the torso's frame (rotation undone)
    return float(abs((a + 180.0) % 360.0 - 180.0))


def arm_symmetry(X: np.ndarray, template: Template | None = None) -> float:
    """``arm_symmetry`` of the body ``X`` (13380, 3): ``max(r, 1/r)``, ``r`` = the left arm's
    length over the right's, each the shoulder ring → elbow ring → wrist ring path (ring
    centres: the elbow's bend does not change it)."""
    tpl = template or load_template()
    E = np.asarray(tpl.edges, dtype=np.int64)
    X = np.asarray(X, dtype=np.float64)
    torso = tpl.part_mask("torso")

    def length(side: str) -> float:
        up, fore = tpl.part_mask(f"upper_arm_{side}"), tpl.part_mask(f"forearm_{side}")
        hand = tpl.part_mask(f"hand_{side}")
        shoulder, elbow = _ring_centre(X, up, torso, E), _ring_centre(X, fore, up, E)
        wrist = _ring_centre(X, fore, hand, E)
        return float(np.linalg.norm(elbow - shoulder) + np.linalg.norm(wrist - elbow))

    r = max(length("L") / max(length("R"), 1e-9), 1e-9)
    return max(r, 1.0 / r)


def leg_proportion(X: np.ndarray, side: str, template: Template | None = None) -> float:
    """``leg_proportion`` of leg ``side`` (``"L"``/``"R"``) of the body ``X`` (13380, 3):
    ``max(r, 1/r)``, ``r`` = the inseam (crotch landmark → the shin/foot ring's centre) per trunk
    length (crotch → the neck/torso ring's centre) over the template's."""
    tpl = template or load_template()
    E = np.asarray(tpl.edges, dtype=np.int64)

    def ratio(V: np.ndarray) -> float:
        crotch = V[tpl.landmarks["Crotch"]]
        ankle = _ring_centre(V, tpl.part_mask(f"shin_{side}"), tpl.part_mask(f"foot_{side}"), E)
        neck = _ring_centre(V, tpl.part_mask("neck"), tpl.part_mask("torso"), E)
        return float(np.linalg.norm(ankle - crotch) / max(np.linalg.norm(neck - crotch), 1e-9))

    r = max(ratio(np.asarray(X, dtype=np.float64)) / ratio(tpl.V), 1e-9)
    return max(r, 1.0 / r)


def sternum_proportion(X: np.ndarray, template: Template | None = None) -> float:
    """``sternum_proportion`` of the body ``X`` (13380, 3): ``max(r, 1/r)``, ``r`` = the
    Substernale's share of the way Omphalion → Suprasternale (projected on that line) over the
    template's."""
    tpl = template or load_template()
    L = tpl.landmarks

    def share(V: np.ndarray) -> float:
        navel, notch = V[L["Omphalion"]], V[L["Suprasternale"]]
        a = notch - navel
        return float((V[L["Substernale"]] - navel) @ a / max(float(a @ a), 1e-12))

    r = share(np.asarray(X, dtype=np.float64)) / share(tpl.V)
    return max(r, 1.0 / r) if r > 0 else float("inf")


def _triangle_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m,) areas of triangles F (m, 3) of vertices V (n, 3)."""
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def scan_spacing(index: ScanIndex, n: int = 2000) -> float:
    """Typical distance between neighbouring scan points (median over a subsample), metres."""
    ids = np.linspace(0, len(index.points) - 1, min(n, len(index.points))).astype(np.int64)
    d, _ = index.tree.query(index.points[ids], k=2, workers=kd_workers())
    return float(np.median(d[:, 1]))


def fit_to_scan_distance(index: ScanIndex, X: np.ndarray) -> np.ndarray:
    """Distance (n,) from points X (n, 3) to the scan surface, metres.

    The nearest scan point's tangent plane stands in for the surface within one point spacing
    ``h`` of it: ``sqrt(d_n² + max(0, d_t - h)²)`` with ``d_n`` the distance along that point's
    normal and ``d_t`` the tangential distance (so sampling density does not count as error, but a
    vertex over a hole or off the body does).
    """
    d, j = index.tree.query(X, k=1, workers=kd_workers())
    h = scan_spacing(index)
    dn = np.abs(np.einsum("nc,nc->n", X - index.points[j], index.normals[j]))
    dt = np.sqrt(np.maximum(d**2 - dn**2, 0.0))
    return np.sqrt(dn**2 + np.maximum(dt - h, 0.0) ** 2)


def spread_allowance(spread_m: float) -> float:
    """Metres a part's scan→fit p95 limits rise for the scan's own spread there
    (:data:`SPREAD_P95_FACTOR` × its excess over :data:`SPREAD_NOISE_M`; 0 for NaN)."""
    return SPREAD_P95_FACTOR * max(float(np.nan_to_num(spread_m)) - SPREAD_NOISE_M, 0.0)


def spread_warning(quality: FitQuality) -> str | None:
    """The report's warning where the scan's own spread (:attr:`PartQuality.scan_spread_m`)
    exceeds :data:`SPREAD_WARN_M` on a part of the body's; None where it does not."""
    wide = {
        n: p.scan_spread_m
        for n, p in quality.parts.items()
        if n not in SPREAD_FROM and p.scan_spread_m > SPREAD_WARN_M
    }
    if not wide:
        return None
    order = sorted(wide.items(), key=lambda x: -x[1])
    parts = ", ".join(f"{n} {v * 1000:.1f} mm" for n, v in order)
    return (
        f"the scan's surface is thick: its points spread {parts} about the fitted surface (a "
        "good scanner's noise reads about 1 mm): a noisy scanner, a subject who moved between "
        "the scanner's views, or views misaligned. Scan→fit distances up to about twice the "
        "spread are the scan's own, not the fit's; where the subject moved, the body's shape "
        "and measurements may be off by as much (rescan holding still)"
    )


def scan_spread(
    P: np.ndarray,
    X: np.ndarray,
    normals: np.ndarray,
    nearest: np.ndarray,
    near: np.ndarray,
    part_of_point: np.ndarray,
    names: tuple[str, ...] | list[str],
) -> dict[str, float]:
    """Per part, the scan's own spread about its surface (metres; module docstring).

    P (q, 3) sampled scan points; X (13380, 3) the fitted body and ``normals`` its vertex
    normals; ``nearest`` (q,) each point's nearest fitted vertex, ``near`` (q,) bool the points
    counted (within ``NEAR_DISTANCE_M`` of the fit), ``part_of_point`` (q,) their part indices
    into ``names``. NaN for a part with fewer than ``MIN_POINTS`` points; hands and feet take
    :data:`SPREAD_FROM`'s."""
    from scipy.spatial import cKDTree

    out = dict.fromkeys(names, float("nan"))
    idx = np.flatnonzero(near)
    if len(idx) <= SPREAD_NEIGHBOURS:
        return out
    n = normals[nearest[idx]]
    t = np.einsum("ij,ij->i", P[idx] - X[nearest[idx]], n)
    Q = P[idx] - t[:, None] * n  # on the fitted surface: layers of one skin fall together
    _, nb = cKDTree(Q).query(Q, k=SPREAD_NEIGHBOURS, workers=kd_workers())
    local = t[nb].std(axis=1)
    part = part_of_point[idx]
    for i, name in enumerate(names):
        sel = part == i
        if sel.sum() >= MIN_POINTS:
            out[name] = float(np.median(local[sel]))
    for name, src in SPREAD_FROM.items():
        if name in out:
            out[name] = out.get(src, float("nan"))
    return out


def assess_fit(
    scan: Scan | ScanIndex,
    X: np.ndarray,
    *,
    template: Template | None = None,
    sample: int = SAMPLE_POINTS,
    scan_to_fit: np.ndarray | None = None,
    sample_ids: np.ndarray | None = None,
    reference: np.ndarray | None = None,
    unseen: np.ndarray | None = None,
    mittens: str = "",
    mitten_m: float = 0.0,
    absent: tuple[str, ...] = (),
) -> FitQuality:
    """Judge the fitted body ``X`` (13380, 3), metres, against ``scan`` (same frame).

    ``scan_to_fit`` (q,) with ``sample_ids`` (q,) may pass already computed distances of scan
    points ``sample_ids`` to the fitted surface; otherwise an evenly spaced subsample of at most
    ``sample`` scan points is measured. ``reference`` (13380, 3): the body the fit started from
    (for ``area_change``; default the template). ``unseen`` (13380,) bool: vertices the scan
    shows no skin over (the refinement kept the body prior's there), left out of a part's
    ``fit_to_scan_p95_m`` where they are at most :data:`MAX_UNSEEN_SHARE` of its vertices.
    ``mittens`` (sides "L", "R"): hands that keep the body prior's skin inside a closed mesh's
    fused mitten (:func:`core.registration.closed_concavities.mitten_hands`), whose
    ``scan_to_fit_p95_m`` limits rise by ``mitten_m`` (metres: the mesh's closing radius, as far
    as its webbing between thumb and fingers reaches from the skin).
    ``absent`` (part names): parts the scan does not hold (a scan that ends above the soles):
    each is ``suspect`` as the body prior's guess and unresolved (no other fit can place it),
    ``failed`` only for its shape and place (figures not read off its data).
    Returns a :class:`FitQuality` (thresholds: module docstring).
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

    _, nearest = cKDTree(X).query(P, k=1, workers=kd_workers())
    p_part = labels[nearest]
    p_part16 = np.asarray(tpl.part)[nearest]
    # fitted vertices -> the scan surface, and compatible data within the coverage distance
    f2s = fit_to_scan_distance(index, X)
    normals = vertex_normals(X, F)
    corr = index.closest_compatible(
        X,
        normals,
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
    # figures of the whole body, the same on both sides: once
    unresolved: list[str] = []  # parts suspect only where the scan cannot tell
    torso_R = _torso_rotation(X, tpl)
    arm_sym, apart = arm_symmetry(X, tpl), feet_apart(X, tpl, torso_R)
    body_gaps = hand_body_gaps(X, tpl)
    spread = scan_spread(P, X, normals, nearest, scan_to_fit <= NEAR_DISTANCE_M, p_part, names)
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
        seen = own
        if unseen is not None and (own & unseen).sum() <= MAX_UNSEEN_SHARE * own.sum():
            seen = own & ~unseen
        figures = {
            "scan_to_fit_p95_m": s2f_p95,
            "fit_to_scan_p95_m": float(np.percentile(f2s[seen], 95)),
            "coverage": float(covered[own].mean()),
            "area_change": float(area_change[i]),
            "displacement_m": disp,
            **dict.fromkeys(PART_FIGURES, float("nan")),
        }
        if name.startswith("hand_"):
            figures.update(
                hand_figures(X, P, scan_to_fit, name[-1], tpl, p_part16, f2s, body_gaps[name[-1]])
            )
        elif name == "head":
            figures["head_turn_deg"], figures["head_distortion_m"] = head_figures(X, tpl)
        elif name.startswith("leg_"):
            figures["leg_proportion"] = leg_proportion(X, name[-1], tpl)
        elif name.startswith("arm_"):
            figures["arm_symmetry"] = arm_sym
        elif name.startswith("foot_"):
            figures["foot_turn_deg"] = foot_turn(X, name[-1], tpl, torso_R)
            figures["feet_apart_m"] = apart
        elif name == "torso":
            figures["sternum_proportion"] = sternum_proportion(X, tpl)
        judged = figures  # a part the scan does not hold: judged on its shape and place only
        if name in absent:
            judged = {**figures, **dict.fromkeys(DATA_FIGURES, float("nan"))}
        mitten = name.startswith("hand_") and name[-1] in mittens
        base = mitten_m if mitten else 0.0
        pv, pr, flagged = _judge(name, judged, {"scan_to_fit_p95_m": base})
        allow = spread_allowance(spread[name])
        layered = False
        if flagged == {"scan_to_fit_p95_m"} and allow > 0 and pv == "suspect":
            # the scan's own layers explain it: suspect, said why, and no retry
            pv_l, _, _ = _judge(name, judged, {"scan_to_fit_p95_m": base + allow})
            if pv_l == "good":
                layered = True
                pr = [
                    f"{name}: scan→fit p95 {s2f_p95 * 1000:.0f} mm, as far as the scan's own "
                    f"spread reaches ({spread[name] * 1000:.1f} mm about its surface, a good "
                    "scanner's noise about 1: the subject moved between views, views "
                    "misaligned or a noisy scanner); no fit explains it better"
                ]
        # suspect only where the scan cannot tell (checked again below: lost or without data)
        scan_cannot_tell = AMBIGUOUS_FIGURES[0] in flagged and flagged <= set(AMBIGUOUS_FIGURES)
        f = EXTREMITY_FACTOR if name in EXTREMITIES else 1.0
        off = (
            (reference is not None and figures["area_change"] > LOST_AREA_CHANGE)
            or figures["coverage"] < THRESHOLDS["coverage"].suspect / f
            or figures["fit_to_scan_p95_m"] > THRESHOLDS["fit_to_scan_p95_m"].suspect * f
        )
        if name in absent:  # the body prior's guess, said so; failed only for its shape
            pr.insert(
                0,
                f"{name}: not in the scan (it ends above the soles); its shape and place are "
                "the body prior's guess",
            )
            pv = "failed" if pv == "failed" else "suspect"
            scan_cannot_tell = pv == "suspect"
        elif s2f_p95 > LOST_SCAN_TO_FIT_M * f and off and pv != "failed":
            pv = "failed"
            pr.insert(
                0,
                f"{name}: lost (scan data around it unexplained, its surface "
                f"{ratio[i] * 100:.0f} % of its proportion)",
            )
        if n_pts < MIN_POINTS and name not in absent:  # data for a whole part missing: lost?
            pv = "failed" if figures["coverage"] < THRESHOLDS["coverage"].failed else pv
            scan_cannot_tell = False
            # the hand-shape hints presuppose a scanned hand: with none, they mislead
            pr = [r for r in pr if FIST_HINT not in r]
            pr.insert(
                0,
                f"{name}: only {n_pts} scan points near it (missing from the scan: cut off, "
                "held out of the scanner's view or not there); its shape and place are the body "
                "prior's guess",
            )
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
            data_beyond_m=figures["data_beyond_m"],
            hand_bend_deg=figures["hand_bend_deg"],
            hand_proportion=figures["hand_proportion"],
            hand_tip_gap_m=figures["hand_tip_gap_m"],
            hand_body_gap_m=figures["hand_body_gap_m"],
            head_turn_deg=figures["head_turn_deg"],
            head_distortion_m=figures["head_distortion_m"],
            leg_proportion=figures["leg_proportion"],
            arm_symmetry=figures["arm_symmetry"],
            foot_turn_deg=figures["foot_turn_deg"],
            feet_apart_m=figures["feet_apart_m"],
            sternum_proportion=figures["sternum_proportion"],
            scan_spread_m=spread[name],
        )
        if (scan_cannot_tell or layered) and pv == "suspect":
            unresolved.append(name)
        reasons.extend(pr)
        if rank[pv] > rank[verdict]:
            verdict = pv
    thresholds = {
        k: {"suspect": t.suspect, "failed": t.failed if np.isfinite(t.failed) else None}
        for k, t in THRESHOLDS.items()
    }
    return FitQuality(verdict, reasons, parts, thresholds, unresolved)
