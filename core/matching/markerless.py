"""Matching without markers (paper §5.2 idea): fit shape-space weights, pose and a similarity.

Measured (``python -m bench.matching``, seeds 0–5, full-size scans): 3.0–5.2 mm mean error from
the shape space alone, 2.0–3.3 mm after the refinement rounds (with markers: 2.1–2.3 mm; ratio
0.93–1.46), identical when the scan is turned 90°/180°/270° about the vertical; small test
scans 4.0–6.3 mm.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from functools import cache, partial
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from core.errors import FitError
from core.geometry import area_samples
from core.io.frame import turn_over
from core.matching.body_check import check_body_shape
from core.matching.hair import FLAT_HAIR_NOTE, find_hair
from core.registration.correspondence import ScanIndex, turn_normals_against_body
from core.registration.fit import (
    HAND_LENGTH_NOTE,
    RETRIES,
    FitResult,
    PriorRestart,
    Progress,
    attempt_score,
    fit,
    template_operators,
)
from core.registration.foot_end import scanned_foot_ends, toe_allowance, toe_tip_marker
from core.registration.hand_length import (
    free_hand_ends,
    scanned_hand_roundness,
    tip_allowance,
)
from core.registration.initialization import Similarity
from core.registration.quality import (
    THRESHOLDS,
    arm_symmetry,
    feet_apart,
    hand_body_gaps,
    hand_tip_gap,
)
from core.registration.schedule import Schedule
from core.registration.shape_prior import (
    BONE_LENGTH_PRIOR,
    BONE_PRIOR,
    CLAVICLE_PRIOR,
    FOOT_PRIOR,
    HEAD_PRIOR,
    LEG_CENTRE_PRIOR,
    LEG_TWIST_PRIOR,
    LIMB_PRIOR,
    TRUNK_PRIOR,
    PriorFit,
    PriorOptions,
    arm_pose,
    fit_body_prior,
)
from core.rig import axis_angle, joint_positions, load_rig
from core.scan import Scan, scan_without
from core.template import load_template
from core.threads import kd_workers, map_in_threads, serialised, single_blas_thread

K_SCHEDULE = (6, 6, 12, 12, 24, 24, 40, 40, 60)

#: How far (metres) the body's soles may reach below the scan's lowest points: scanner software
#: cuts the floor contact band off a raw scan (``core.synth.scanner``: the lowest 1 cm), so the
#: soles may lie that far below the data; a closed mesh's flat-cut soles sit 3-8 mm above the
#: floor. Without a floor the shape-space fits of raw scans grew the feet down and forward along
#: the instep (heels 12-32 mm under the floor, feet 9-33 mm too long; ``bench.realworld``
#: raw-0..28), while the closed mesh of the same body kept them on its soles. The floor holds the
#: first shape-space fit only: the soft-marker rounds keep its feet by their landmarks (with the
#: floor in the rounds too, closed_lowres-28's last round ended 21.0 mm from the truth, not 17.8).
FLOOR_GAP_M = 0.01


def denser_template_rows(subsample: int) -> dict[str, Any]:
    """Body-prior options: every ``subsample``-th template vertex's body → scan row, each
    weighing its share of the default sampling's (the term as heavy as at
    :attr:`PriorOptions.subsample`)."""
    return {"subsample": subsample, "template_row_weight": subsample / PriorOptions.subsample}


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def facing_candidates(scan: Scan) -> tuple[float, ...]:
    """Rotations about +Y (degrees) that map the template's left–right axis (+X) onto the
    scan's: the torso's widest horizontal direction, either sign, and the perpendicular one
    (either sign) in case the widest direction is front–back."""
    V = np.asarray(scan.V)
    lo, hi = np.percentile(V[:, 1], [0.2, 99.8])
    torso = V[(V[:, 1] > lo + 0.45 * (hi - lo)) & (V[:, 1] < lo + 0.70 * (hi - lo))]
    if len(torso) < 10:
        return (0.0, 90.0, 180.0, 270.0)
    H = torso[:, [0, 2]] - torso[:, [0, 2]].mean(axis=0)
    _, vecs = np.linalg.eigh(H.T @ H)
    e1 = vecs[:, 1]  # (x, z) of the widest direction
    base = float(np.degrees(np.arctan2(-e1[1], e1[0])))  # rotation about y taking +X to e1
    return tuple((base + d) % 360.0 for d in (0.0, 180.0, 90.0, 270.0))


#: Feet cue (:func:`feet_forward`): share of the height of the foot band and of the shin band's
#: lower and upper edges, from the sole; the cue counts when the foot band's centre lies at least
#: FEET_CUE_MIN (share of the height) in front of the shin band's.
FOOT_BAND, SHIN_BAND, FEET_CUE_MIN = 0.035, (0.10, 0.16), 0.012
#: A facing candidate is kept when its toes point within this angle (degrees) of the feet cue.
FEET_CUE_ANGLE = 75.0


def _feet_offset(scan: Scan, *, top: bool = False) -> tuple[np.ndarray, float] | None:
    """The horizontal offset (x, z) (metres) from the shin band's centre to the foot band's
    (:data:`SHIN_BAND`, :data:`FOOT_BAND`) and the scan's height (metres); None when a band has
    too few points. ``top``: the feet are at the top (an upside-down hypothesis)."""
    V = np.asarray(scan.V)
    y = -V[:, 1] if top else V[:, 1]
    lo, hi = np.percentile(y, [0.2, 99.8])
    h = hi - lo
    foot = V[(y > lo) & (y < lo + FOOT_BAND * h)]
    shin = V[(y > lo + SHIN_BAND[0] * h) & (y < lo + SHIN_BAND[1] * h)]
    if len(foot) < 20 or len(shin) < 20:
        return None
    return foot[:, [0, 2]].mean(axis=0) - shin[:, [0, 2]].mean(axis=0), float(h)


def feet_forward(
    scan: Scan, *, top: bool = False, min_share: float = FEET_CUE_MIN
) -> np.ndarray | None:
    """Which way the feet point: unit (x, z) of the horizontal offset from the shins' centre to
    the feet's, or None when the offset is too small to tell (< ``min_share`` × height).

    Feet stick out in front of the ankles (toes 15–20 cm ahead, heel 5 cm behind), so a band
    just above the soles has its centre 4–10 cm in front of the shins' (measured on the 38
    scans of ``benchmark_cases(40)``: 40–102 mm, every one pointing the body's way). ``top``:
    the feet are at the top (an upside-down hypothesis). A scan that ends above the soles has
    its own cue (:func:`calves_behind`).
    """
    off = _feet_offset(scan, top=top)
    if off is None:
        return None
    d, h = off
    n = float(np.linalg.norm(d))
    return d / n if n > min_share * h else None


#: Feet check (:func:`feet_in_scan`): share of the height of the band above the scan's lowest
#: points, the reference band (shares of the height above them), the grid cell (metres) of the
#: bands' footprints seen from above, and the least ratio of the two footprints that is feet.
#: From above, feet show their whole top (2 x 25 x 9 cm) where legs show rings: the feet of
#: ``bench.realworld``'s scans read 1.24-6.4 (heavy bodies and booth meshes the least: thick
#: calves), scans that end 6-12 cm above the soles 0.57-0.86 (``--feetless``: ankle rings over
#: calf rings; both ankles together read as one foot's length, so the band's extent cannot tell).
FEET_BAND, FEET_REFERENCE_BAND, FEET_CELL_M, MIN_FEET_FOOTPRINT = 0.03, (0.10, 0.13), 0.01, 1.05
#: ... and the least offset of the foot band's centre in front of the shins' (:func:`feet_forward`;
#: share of the height) that is feet: a cut closed by scanner software (``capped_feetless``)
#: shows a filled disc per ankle, whose footprint reads as feet (1.01-1.89), but it lies under
#: the shins, not ahead of them: 0.003-0.010 on ``--feetless``'s capped scans, feet 0.024-0.057
#: on 143 scans (the varied set without its dense clouds, booth 40, heavy 20, filled 16,
#: tilted 12, read as the fit reads them). The threshold is about their geometric middle, a
#: little nearer the caps: a whole-body lean of 3° at the ankles moves the shins ~0.006 ahead.
MIN_FEET_AHEAD = 0.015
#: Share of the body's height taken as missing below a scan without feet (the ankle's height,
#: about 5 % of stature): the search's candidates stand that much taller than the scan, hung
#: from its head end.
FEETLESS_MISSING = 0.05
#: The facing cue of a scan without feet (:func:`calves_behind`): shares of the scan's height
#: (from its lowest point, the cut) of the band over the cut, the calves' band and the knees'.
ANKLE_BAND, CALF_BAND, KNEE_BAND = (0.0, 0.03), (0.08, 0.14), (0.20, 0.24)
#: ... its least size (share of the height) to tell: the calves' band centre lies 1.6-11.6 mm
#: behind the line from the band over the cut to the knees' (``--feetless``'s 16 scans, each
#: also leaned 3-5° forwards or backwards or 3° sideways: 0.002-0.007 of the height).
FEETLESS_CUE_MIN = 0.001
#: A scan without feet keeps the facing candidates whose toes point within this angle (degrees)
#: of :func:`calves_behind`'s cue: it points within 59° of the body's forward on those 112
#: scans, so the candidate facing the body's way (itself up to ~20° off) stays and the one
#: facing the other way goes.
FEETLESS_CUE_ANGLE = 90.0


#: A scan that ends above the soles may come closed there (scanner software caps the cut, flat
#: or domed): its points within :data:`CUT_CAP_BAND_M` of the lowest whose surface lies within
#: :data:`CUT_CAP_ANGLE` of horizontal (either sign: estimated or inward normals) are the cap, not
#: the body, and leave the fit (:func:`cut_caps`); the legs' walls just above a cut are near
#: vertical. Left in, the caps pulled the guessed feet onto them: ``closed_feetless`` cases
#: 1002/1005/1008/1011 capped flat fitted 27-52 mm from the truth (open: 7-11), feet 107-158 mm.
CUT_CAP_BAND_M, CUT_CAP_ANGLE, MIN_CAP_POINTS = 0.03, 45.0, 20

#: A cut through the head closed by scanner software (a tall subject in a short scan volume,
#: the hole capped flat or nearly): seen from above, the scan's points within
#: :data:`HEAD_CAP_BAND_M` of its head end whose surface lies within
#: :data:`HEAD_CAP_FLAT_ANGLE` of horizontal cover at least :data:`HEAD_CAP_MIN_CELLS`
#: :data:`FEET_CELL_M` cells: a skull's crown covers 0-53 (``bench.realworld``'s varied set
#: without its dense clouds, hair included, and booth 40: 77 scans), a closed mesh cut 3-9 cm
#: below the crown and capped flat or domed 5-11 mm 89-241 (domed 12-20 mm: 38-87, 10 of 11
#: under 80: as round as a crown, not caught). Left in, the fit took the cap for the crown:
#: `good`, the stature 37-42 mm short, no warning (closed_headcut-1108/-1111 so capped). Its
#: points within :data:`HEAD_CAP_DEPTH_M` of the head end within :data:`HEAD_CAP_ANGLE` of
#: horizontal then leave the fit (:func:`head_cap`), the cut reads as one (:func:`crown_gap`).
HEAD_CAP_BAND_M, HEAD_CAP_FLAT_ANGLE, HEAD_CAP_MIN_CELLS = 0.004, 20.0, 80
HEAD_CAP_DEPTH_M, HEAD_CAP_ANGLE = 0.02, 30.0

#: The feet parts (:func:`core.registration.quality.part_labels`).
FEET = ("foot_L", "foot_R")
#: The report's warning on a scan without feet (:func:`feet_in_scan`).
FEETLESS_WARNING = (
    "the scan ends above the soles (seen from above, its lowest part covers no more ground "
    "than the legs over it: ankles, not feet; a scanner that missed the feet, or a floor "
    "cropped with them): the feet are the body prior's guess, and the stature and every height "
    "measured from the soles include that guess"
)


def calves_behind(scan: Scan, *, top: bool = False) -> np.ndarray | None:
    """Which way a body without feet faces (:func:`feet_in_scan`): unit (x, z) opposite to the
    horizontal offset of the calves' band centre (:data:`CALF_BAND`) from the line joining the
    centres of the band over the cut (:data:`ANKLE_BAND`) and of the knees' (:data:`KNEE_BAND`);
    None where it is under :data:`FEETLESS_CUE_MIN` × the height or a band is empty. ``top``:
    the cut is at the top (an upside-down hypothesis).

    The calf bulges behind the shin. The bands' centres alone (ankles ahead of the calves,
    :func:`feet_forward`'s offset) read 3-17 mm, and a whole-body lean moves each band by its
    height × the lean: leaned 3° forwards, 5 of ``--feetless``' scans 1000-1007 read backwards
    and were fitted facing that way (233-551 mm off, `failed`). The line through the ankles'
    and knees' centres leans with the body, so the calves' offset from it does not."""
    V = np.asarray(scan.V)
    y = -V[:, 1] if top else V[:, 1]
    lo, hi = np.percentile(y, [0.2, 99.8])
    h = hi - lo
    centres, heights = [], []
    for a, b in (ANKLE_BAND, CALF_BAND, KNEE_BAND):
        sel = (y > lo + a * h) & (y < lo + b * h)
        if sel.sum() < 20 or h <= 0:
            return None
        centres.append(V[sel][:, [0, 2]].mean(axis=0))
        heights.append(0.5 * (a + b))
    t = (heights[1] - heights[0]) / (heights[2] - heights[0])
    d = centres[1] - (centres[0] + t * (centres[2] - centres[0]))
    n = float(np.linalg.norm(d))
    return -d / n if n > FEETLESS_CUE_MIN * h else None


def _footprint(P: np.ndarray) -> int:
    """The :data:`FEET_CELL_M` cells the points P (q, 3; +Y up) cover seen from above."""
    return len(np.unique(np.floor(P[:, [0, 2]] / FEET_CELL_M).astype(np.int64), axis=0))


def _near_horizontal(N: np.ndarray, angle_deg: float) -> np.ndarray:
    """(q,) bool: the normals N (q, 3) within ``angle_deg`` of ±Y (a surface near horizontal,
    either sign: estimated or inward normals)."""
    return np.abs(N[:, 1]) > np.cos(np.radians(angle_deg))


def feet_footprint_ratio(scan: Scan, *, top: bool = False) -> float:
    """The footprint seen from above (occupied :data:`FEET_CELL_M` cells) of the scan's lowest
    :data:`FEET_BAND` (``top``: its highest, for a body held upside down) over that of the legs'
    band :data:`FEET_REFERENCE_BAND` up; inf when there are too few points to tell."""
    V = np.asarray(scan.V)
    y = -V[:, 1] if top else V[:, 1]
    lo, hi = np.percentile(y, [0.2, 99.8])
    h = hi - lo

    def footprint(a: float, b: float) -> int:
        return _footprint(V[(y > lo + a * h) & (y < lo + b * h)])

    feet, legs = footprint(0.0, FEET_BAND), footprint(*FEET_REFERENCE_BAND)
    return float("inf") if h <= 0 or min(feet, legs) < 20 else feet / legs


def feet_in_scan(scan: Scan, *, top: bool = False) -> bool:
    """Whether the scan's lowest band (``top``: its highest) holds feet: its
    :func:`feet_footprint_ratio` at least :data:`MIN_FEET_FOOTPRINT`, its centre at least
    :data:`MIN_FEET_AHEAD` × height in front of the shins'. Asked of the end the search stood
    the body on: a head's ratio reads either way (a closed mesh's filled crown 1.1-1.9)."""
    if feet_footprint_ratio(scan, top=top) < MIN_FEET_FOOTPRINT:
        return False
    off = _feet_offset(scan, top=top)
    return off is None or float(np.linalg.norm(off[0])) >= MIN_FEET_AHEAD * off[1]


def cut_caps(scan: Scan) -> np.ndarray:
    """(n,) bool: the scan's points that close a cut above the soles (:data:`CUT_CAP_BAND_M`,
    :data:`CUT_CAP_ANGLE`); asked only of a scan upright (+Y) that :func:`feet_in_scan` says
    ends above them."""
    V, N = np.asarray(scan.V), np.asarray(scan.normals)
    lo = np.percentile(V[:, 1], 0.2)
    return (V[:, 1] < lo + CUT_CAP_BAND_M) & _near_horizontal(N, CUT_CAP_ANGLE)


def head_cap(scan: Scan, *, down: bool = False) -> np.ndarray:
    """(n,) bool: the scan's points that close a cut through the head (:data:`HEAD_CAP_BAND_M`
    and the rest); all False where its head end is a crown. ``down``: the head is at the scan's
    lowest end (the search stood the body head-down)."""
    V, N = np.asarray(scan.V), np.asarray(scan.normals)
    y = -V[:, 1] if down else V[:, 1]
    top = np.percentile(y, 99.95)
    flat = (y > top - HEAD_CAP_BAND_M) & _near_horizontal(N, HEAD_CAP_FLAT_ANGLE)
    if _footprint(V[flat]) < HEAD_CAP_MIN_CELLS:
        return np.zeros(len(V), dtype=bool)
    return (y > top - HEAD_CAP_DEPTH_M) & _near_horizontal(N, HEAD_CAP_ANGLE)


def candidate_alignments(
    scan: Scan, *, upside_down: bool = True, feetless: bool = False
) -> list[Similarity]:
    """Template → scan similarities to try: scale from height, floor and centroid, each facing.

    The scan is in the canonical frame (metres, +Y up as detected by the reader; the upside-down
    candidates cover a reader's wrong guess of the up direction's sign). Where the feet show
    which way the body faces (:func:`feet_forward`), only facings whose toes point within
    :data:`FEET_CUE_ANGLE` of that way are tried: a body's front and back match a scan almost
    equally well, the feet do not. ``feetless``: the scan ends above the soles
    (:func:`feet_in_scan`): the candidates are scaled 1 / (1 - :data:`FEETLESS_MISSING`) and
    hung from the scan's end their head is at (either way up: the scan's cut end may read
    like a head), the cue read off the calves (:func:`calves_behind`, facings within
    :data:`FEETLESS_CUE_ANGLE` of it).
    """
    tpl = load_template()
    V = np.asarray(scan.V)
    lo, hi = np.percentile(V[:, 1], [0.2, 99.8])
    height = hi - lo
    t_lo, t_hi = tpl.V[:, 1].min(), tpl.V[:, 1].max()
    if not 0.4 < height < 2.6:
        raise FitError(
            f"the scan is {height:.2f} m tall along +Y: not a standing body in metres "
            "(give units= and up= explicitly)",
            height_m=float(height),
        )
    s = height / (t_hi - t_lo)
    c_scan = np.median(V, axis=0)
    out = []
    flips = [np.eye(3)] + ([_rot_z(180.0)] if upside_down else [])
    toes = _template_toes()
    sf = s / (1.0 - FEETLESS_MISSING) if feetless else s
    for fi, flip in enumerate(flips):
        top = fi == 1
        cue = calves_behind(scan, top=top) if feetless else feet_forward(scan, top=top)
        within = np.cos(np.radians(FEETLESS_CUE_ANGLE if feetless else FEET_CUE_ANGLE))
        for deg in facing_candidates(scan):
            R = _rot_y(deg) @ flip
            if cue is not None and (R @ toes)[[0, 2]] @ cue < within:
                continue
            Y = sf * tpl.V @ R.T
            t = np.array([c_scan[0], 0.0, c_scan[2]]) - np.array(
                [np.median(Y[:, 0]), 0.0, np.median(Y[:, 2])]
            )
            # soles on the bottom of the scan's points (top, for the upside-down candidates);
            # without feet the head on its other end, the soles past the scan
            if (fi == 0) != feetless:
                t[1] = lo - Y[:, 1].min()
            else:
                t[1] = hi - Y[:, 1].max()
            out.append(Similarity(sf, R, t))
    return out


@cache
def _template_toes() -> np.ndarray:
    """Unit (3,) horizontal direction of the template's toes (heels → toe tips)."""
    tpl = load_template()
    L = tpl.landmarks
    d = tpl.V[[L["Toe_tip_L"], L["Toe_tip_R"]]].sum(0)
    d = d - tpl.V[[L["Calcaneus_posterior_L"], L["Calcaneus_posterior_R"]]].sum(0)
    d[1] = 0.0
    return d / np.linalg.norm(d)


#: Arm abductions (degrees from the body's side) the articulated search starts from: scanning
#: protocols put the arms anywhere from touching the torso to 60° out.
ARM_HYPOTHESES = (10.0, 30.0, 50.0)
#: Further arm abductions tried where the scan is wide (:func:`arm_hypotheses`): T-pose and
#: near-T-pose captures (arms 60-90° out). From 50° the articulated search reached 60-78° but
#: not 80-90°: 2 of 4 raw scans with the arms 80-90° out lost both arms (300-400 mm off).
WIDE_ARM_HYPOTHESES = (80.0,)
#: Width (principal horizontal extent) over height above which a scan's arms may be spread
#: 60-90°: the off-model bodies of ``core.synth.realworld`` read 0.78-0.95 with the arms 60°
#: out, 0.87-1.08 at 80-90°, 0.71-0.86 at 50° and 0.26-0.64 at 5-30° (30 bodies each).
WIDE_ARMS_RATIO = 0.8


def width_ratio(scan: Scan, n: int = 20000) -> float:
    """The scan's width over its height: robust (0.1-99.9 %) extents along its principal
    horizontal direction and along +Y, of an even subsample of ≤ ``n`` points."""
    V = np.asarray(scan.V)[np.linspace(0, len(scan.V) - 1, min(n, len(scan.V))).astype(np.int64)]
    H = V[:, [0, 2]] - V[:, [0, 2]].mean(axis=0)
    _, vecs = np.linalg.eigh(H.T @ H)
    w = np.ptp(np.percentile(H @ vecs[:, -1], [0.1, 99.9]))
    h = np.ptp(np.percentile(V[:, 1], [0.1, 99.9]))
    return float(w / max(h, 1e-9))


def arm_hypotheses(scan: Scan) -> tuple[float, ...]:
    """The arm abductions the articulated search starts from: :data:`ARM_HYPOTHESES`, and
    :data:`WIDE_ARM_HYPOTHESES` too where the scan is wider than :data:`WIDE_ARMS_RATIO` of
    its height (:func:`width_ratio`)."""
    wide = width_ratio(scan) > WIDE_ARMS_RATIO
    return ARM_HYPOTHESES + (WIDE_ARM_HYPOTHESES if wide else ())


#: Scale (metres) of the Geman–McClure weights of the search's two-way score.
SCORE_SIGMA = 0.02
#: The markerless search's pose prior: the arm bones', the head's and the thighs' twist.
SEARCH_BONE_PRIOR = BONE_PRIOR + HEAD_PRIOR + LEG_TWIST_PRIOR
#: The markerless body-prior fits keep the body standing on the levelled scan
#: (``fit_body_prior(upright=True)``: the similarity turns only about +Y). Free, the whole body
#: could roll and turn while the spine, hips and knees turned back against it: on heavy bodies'
#: hole-filled booth meshes (``closed_filled`` of ``core.synth.scanner_outputs``, 901: BMI 51)
#: the search's wide-girth start stood rolled 6° and turned 9°, the first fit 10° and 15°, the
#: spine twisted 16°, the knees 23° sideways, the pelvis and thighs 7-18° off the truth's (their
#: raw twins' 1-3°). Upright in the search and the fits (stop 51, ``bench/README.md``): filled 16
#: twins 5.15 -> 4.70 mm, correspondence 8.67 -> 8.58; booth 40 9.53 -> 9.46; varied 40 6.58 ->
#: 6.61 (twins 2.81 -> 2.89); held-in 3.27 (unchanged). Upright only in the fits left 901's thighs
#: 15° off. Its cost: raw-4's search now ends in a near tie, and a second first fit (+25-30 % CPU).
UPRIGHT = True
#: The shape-space fits' bone prior: the search's and the feet's (:data:`FOOT_PRIOR`; in the
#: search's short fits it changed which start won on heavy bodies: ``bench.realworld --heavy``
#: raw-63 and raw-102 lost both arms). A twist prior on the upper arms and shins as well (0.1,
#: as the thighs' :data:`LEG_TWIST_PRIOR`) gained the twin diagnostic 0.01 mm and cost the
#: turned palms (``bench.realworld --palms``, stop 42: correspondence 9.05 -> 9.32 mm, twins
#: 5.28 -> 6.16): not kept.
MARKERLESS_BONE_PRIOR = SEARCH_BONE_PRIOR + FOOT_PRIOR
#: The soft-marker round's bone prior: the shape-space fits' and the clavicles'
#: (:data:`~core.registration.shape_prior.CLAVICLE_PRIOR`).
ROUND_BONE_PRIOR = MARKERLESS_BONE_PRIOR + CLAVICLE_PRIOR
#: Gauss-Newton iterations of the soft-marker round's body prior from the landmarks' alignment
#: and rest pose. At 12 it stopped still moving the body 2-3 mm per iteration (mean over the
#: vertices; the report gives the figure), at 24 0.2-0.3 mm; ``bench.realworld`` (stop 35, 12 ->
#: 24) read correspondence means varied 40 8.21 -> 7.93 mm, booth 40 12.46 -> 12.03, palms 20
#: 10.40 -> 10.08, wide 24 8.44 -> 8.61, heavy 20 14.79 -> 14.83, twins 4.83 -> 4.66 (worst
#: 7.3 -> 5.9). It costs ~0.35 s CPU a fit, paid for by the refinement's factorisation
#: (``ResolutionLevel.fill_reducing_order``, ~0.25 s CPU a factorisation).
ROUND_ITERATIONS = 24
#: Weight of the shape prior ‖c/σ‖² in the round's body prior (``fit_body_prior(
#: shape_prior_weight=)``, in units of one data row, mm²; the search's fits keep 1). At 1 the
#: round's ~8 000 data rows left the 60 coefficients all but free: on bodies off the prior's space
#: the shape space bought a slightly closer surface with a slide of the skin, a different one for
#: each delivery of a body. Twin diagnostic (the 8 closed_lowres/raw pairs of ``bench.realworld``,
#: twins mean / closed and raw correspondence to the truth, mm): 1: 4.38 / 7.17 / 6.49, 30: 4.27 /
#: 7.02 / 6.30, 150: 4.06 / 6.82 / 6.13, 400: 3.93 / 6.85 / 6.15, 1000: 3.82 / 6.96 / 6.33, 3000:
#: 3.98 / 7.37 / 6.70; 400 in the search's first fit as well: 4.21 / 7.11 / 6.63. ``--heavy`` 20
#: at 400: correspondence 14.05 -> 13.21 mm, twins 7.40 -> 6.65 (worst 10.1 -> 8.9), fit→scan
#: 4.32 -> 4.11 mm. With :data:`ROUND_POINT_WEIGHT` (stop 40): 400: 3.92 / 6.78 / 6.01, 1000:
#: 3.77 / 6.87 / 6.17 — but on the varied 40 at 1000 correspondence 7.32 -> 7.45 mm and
#: landmarks 8.52 -> 8.77 (``bench/results/realworld-2026-12-02-pw01-sp1000``): 400 kept. Stop 43
#: (on 21f4c37): 400: 3.58 / 6.62 / 5.67, 1000: 3.44 / 6.71 / 5.78, 1000 on closed meshes only
#: (the coarse, smoothed deliveries): 3.66 / 6.71 / 5.67 (``bench/README.md``, stop 43).
ROUND_SHAPE_PRIOR = 400.0
#: Point-to-point share of the data rows in the round's body prior (as the search's,
#: :data:`SEARCH_POINT_WEIGHT`; it was 0: point-to-plane rows alone). Twin diagnostic (as for
#: :data:`ROUND_SHAPE_PRIOR`, shape prior 400): 0: 3.93 / 6.85 / 6.15, 0.05: 3.90 / 6.79 / 6.06,
#: 0.1: 3.92 / 6.78 / 6.01, 0.3: 4.07 / 6.75 / 5.99. Varied 40 (``bench.realworld``) 0 -> 0.1:
#: correspondence 7.40 -> 7.32 mm, landmarks 8.58 -> 8.52, scan→fit p95 2.12 -> 2.10, fit→scan
#: 1.89 -> 1.88, verdicts 32/8/0 both.
ROUND_POINT_WEIGHT = 0.1
#: Iterations of the round's second body prior, from the previous fit (it starts converged:
#: 24 iterations gave the same five sets to the last digit).
RESTART_ITERATIONS = 12
#: The first shape-space fit pairs this many times its 4000 scan → body rows' worth of scan points,
#: each weighing its share (``fit_body_prior(scan_oversample=)``): which points a fixed stride
#: picks of a raw multi-view scan (its views' overlaps) or of a closed mesh (its grid) averages
#: out, and the two deliveries of one body land closer. Twin diagnostic (``bench.realworld``'s 8
#: closed_lowres / raw pairs), 1 -> 3 everywhere (the search's short fits too): twins 3.58 -> 3.47
#: mm, body priors 3.32 -> 3.21, correspondence closed 6.62 -> 6.63, raw 5.68 -> 5.66, CPU median
#: 6.8 -> 6.7 s; (3x the points at full weight: 3.43; 6x: 3.57). In the search too it changed
#: raw-19's start of the varied 40 (its head's flexion lost, 50° turned, correspondence 5.7 -> 28.0
#: mm, ``failed``): the search keeps 1.
FIRST_FIT_SCAN_OVERSAMPLE = 3
#: ... and every second template vertex makes a body → scan data row (not every third), each at
#: 2/3 of the weight (the term as heavy as before). Twin diagnostic (as above, with the 3x scan
#: sample): every third: twins 3.46 mm (worst 4.18), body priors 3.20, correspondence closed 6.64
#: / raw 5.65, CPU median 7.4 s; every second 3.32 (3.97), 3.05, 6.58 / 5.54, 7.6 s; every
#: vertex at 1/3 3.36 (4.06), 3.09, 6.63 / 5.55, 8.5 s.
FIRST_FIT_SUBSAMPLE = 2
#: The same in the soft-marker round's body prior (its restart and retry too). Twin diagnostic
#: (on the above): every third vertex: twins 3.32 mm (worst 3.97), body priors 3.05,
#: correspondence closed 6.58 / raw 5.54, CPU median 7.7 s; every second at 2/3: 3.24 (4.17),
#: 2.95, 6.53 / 5.56, 8.4 s; every vertex at 1/3: 3.24 (3.95), 2.95, 6.57 / 5.53, 10.3 s.
ROUND_SUBSAMPLE = 2
#: Iterations of the body prior of the round's quality retry (:data:`MARKERLESS_RETRIES`; with
#: the round at 24, the retry at 24 too read palms 20 9.77 mm and booth 12.00 but took the retry
#: path 1.1 s CPU more).
RETRY_ITERATIONS = 12

#: The soles' downward faces take no data in the soft-marker round's body prior
#: (``fit_body_prior(sole_data=False)``): booth software cuts the soles flat 3-8 mm up, and
#: there the cut plane's rows lifted a closed mesh's feet (the twin diagnostic's 8
#: closed_lowres bodies: the feet's body prior 1.1 mm above the truth, their raw twins' 0.2).
#: Twins 3.17 -> 3.14 mm, correspondence closed 6.45 -> 6.44, raw 5.56 -> 5.55; the feet's
#: body prior 0.1 mm off the truth's height. Not in the first fit: without the soles' rows the
#: feet of a coarse closed mesh, shrunk by its grid, sank 1.5-2.6 mm (twins 3.10, but
#: closed_booth-322's hands 3 mm further forward and its correspondence 10.74 -> 11.55 mm;
#: in marker fits closed_hair-1's right hand 35 -> 52 mm off).
ROUND_SOLE_DATA = False
#: Point-to-point share of the data rows in the search's fits (``fit_body_prior(point_weight=)``):
#: with point-to-plane pairs alone the body slides along the scan (legs grew 9 cm below the soles
#: of a raw scan, raw-0 of ``core.synth.scanner_outputs``).
SEARCH_POINT_WEIGHT = 0.1

#: Rigid candidates scoring more than this (:func:`two_way_score`) behind the best are not tried
#: with the arm hypotheses. Measured on the 38 non-dense scans of ``benchmark_cases(40)``
#: (``core.synth.scanner_outputs``): the runner-up rigid candidate trailed by 0.074-0.62 and its
#: best articulated start by 0.245-0.67, never the search's choice; dropping its three
#: articulated fits saves ~1 s CPU per markerless fit, the chosen start unchanged.
RIGID_KEEP_MARGIN = 0.05
#: Where the best rigid candidate matches less than this share of the template within 1.5 cm,
#: the best rigid candidate standing the other way up goes on to the arm hypotheses too: the
#: rigid fits of a heavy body with its arms against it cannot tell up from down. It gets the
#: middle arm hypothesis, and the others where that start beats every start so far.
#: closed_booth-305 of ``bench.realworld --booth`` (BMI 38, ponytail, arms touching): its rigid
#: candidates read 7-9 % (head-down 1.546 and 1.586, upright 1.608, past the margin); its
#: articulated head-down starts 1.315-1.391, the upright ones 1.127-1.152 — without them the
#: body was fitted head-down (1.02 m from the truth, verdict failed), with them 20 mm.
RIGID_POOR_COVERAGE = 0.2


#: A markerless fit whose head fails its quality check is run again with the search's best
#: rigid candidate also tried this much taller, standing on the same soles (:func:`search_starts`
#: ``taller``), and the better attempt kept: the search scales the template to the scan's
#: height, and a scan's crown may be missing (dark hair returns no laser light; a tall subject's
#: head cut off by the scan volume). From a body as short as the scan the fit bends the head
#: down into it: raw-4 cut 5 / 8 cm below the crown fitted 28.3 / 31.8 mm from the truth, the
#: head 75-82 mm off and turned 56-59° (`failed`); from the taller start 5.4 / 5.7 mm, `good`.
#: Offered to every fit it helped raw scans a little (varied 40: correspondence 6.63 -> 6.60 mm)
#: but moved the raw twins from the closed ones (worst pair 3.5 -> 3.8 mm) and changed the
#: heavy and T-pose searches, which were not measured: so only where the head failed.
TALLER_START = 1.04


#: Band of heights (shares of the body's height from the soles) whose depth sets the search's
#: template girth (:func:`girth_scale`): belly, waist and chest.
GIRTH_BAND = (0.45, 0.70)
#: Half-width (share of the height) of the central strip whose depth :func:`band_depth` takes:
#: the trunk's middle, clear of arms and hands hanging or spread beside it.
GIRTH_STRIP = 0.06
#: The search's template is widened and deepened by at most this factor (:func:`girth_scale`).
GIRTH_MAX = 1.6
#: A widened template (:func:`girth_scale`) joins the search above this factor.
GIRTH_MIN = 1.15


def band_depth(P: np.ndarray, band: tuple[float, float] = GIRTH_BAND) -> float:
    """Front-to-back depth of the points ``P`` (q, 3; +Y up) in a band of heights, as a share
    of their height: the extent (2nd to 98th percentile) along the band's narrower horizontal
    principal axis, of the points within :data:`GIRTH_STRIP` of its middle along the wider one
    (arms spread along the wider axis and hang beside the trunk)."""
    y = P[:, 1]
    lo, hi = np.percentile(y, [0.2, 99.8])
    h = hi - lo
    S = P[(y > lo + band[0] * h) & (y < lo + band[1] * h)][:, [0, 2]]
    if len(S) < 10 or h <= 0:
        return float("nan")
    S = S - np.median(S, axis=0)
    _, vecs = np.linalg.eigh(S.T @ S)
    d = S[np.abs(S @ vecs[:, 1]) < GIRTH_STRIP * h] @ vecs[:, 0]
    if len(d) < 10:
        return float("nan")
    return float(np.percentile(d, 98) - np.percentile(d, 2)) / h


@cache
def _template_band_depth() -> float:
    """:func:`band_depth` of the template's surface (60 000 points by area, as a scan has)."""
    tpl = load_template()
    return band_depth(area_samples(tpl.V, np.asarray(tpl.F, np.int64), 60_000))


def girth_scale(scan: Scan) -> float:
    """Factor (1 to :data:`GIRTH_MAX`) by which the search widens and deepens the template
    about its vertical axis: the scan's trunk depth over the template's (:func:`band_depth`),
    where that is more than 1."""
    r = band_depth(np.asarray(scan.V))
    if not np.isfinite(r):
        return 1.0
    return float(np.clip(r / _template_band_depth(), 1.0, GIRTH_MAX))


@dataclass
class Start:
    """A starting point for the body prior: similarity, bone rotations, two-way score."""

    similarity: Similarity
    pose: dict[str, np.ndarray]
    coefficients: np.ndarray
    score: float
    coverage: float
    label: str


def scan_sample(index: ScanIndex, n: int = 3000) -> np.ndarray:
    """Indices (≤ n) of the scan's points for the search's scan→body terms
    (:meth:`~core.registration.correspondence.ScanIndex.spread_sample`: by area on a decimated
    mesh), leaving out isolated ones (low confidence: stray blobs)."""
    ok = np.flatnonzero(np.asarray(index.scan.confidence) > 0.25)
    if len(ok) < 100:
        ok = np.arange(len(index.points))
    return index.spread_sample(n, ok)


def two_way_score(
    index: ScanIndex, X: np.ndarray, body_ids: np.ndarray, scan_ids: np.ndarray
) -> float:
    """Robust two-way mismatch of a body ``X`` (n, 3) and the scan, in [0, 2], lower is better.

    Mean Geman–McClure ρ(d) = d² / (d² + σ²) (σ = :data:`SCORE_SIGMA`) of the distances from the
    body vertices ``body_ids`` to the nearest scan point, plus that from the scan points
    ``scan_ids`` to the nearest body vertex. Unsigned: no normals (they may point inward).
    Hair, a floor plate or a stray blob add the same to every hypothesis; a body facing the
    wrong way (toes behind the heels) or with its arms where the scan has none pays on both.
    """
    d_b, _ = index.tree.query(X[body_ids], k=1, workers=kd_workers())
    d_s, _ = cKDTree(X[body_ids]).query(index.points[scan_ids], k=1, workers=kd_workers())
    s2 = SCORE_SIGMA**2
    return float(np.mean(d_b**2 / (d_b**2 + s2)) + np.mean(d_s**2 / (d_s**2 + s2)))


def choose_alignment(
    scan: Scan, index: ScanIndex | None = None, *, keep: int = 2
) -> tuple[Start, list[dict[str, Any]]]:
    """Pick the body prior's start in two rounds, each scored by :func:`two_way_score`:

    1. rigid: a short two-way ICP of the template (shape and pose frozen, normals' sign not
       trusted) from each facing / up candidate (:func:`candidate_alignments`);
    2. articulated: from the ``keep`` best (within :data:`RIGID_KEEP_MARGIN` of the best), each
       arm hypothesis (:func:`arm_hypotheses`) with bone rotations, similarity and the first
       shape components free;
    3. the head of the best (:func:`_head_start`): its neck and head at rest, flexed 0/15/30°,
       when that matches the scan's head better than the search's own.

    Returns the best start and every trial's score (:func:`search_starts` for all the starts).
    """
    index = index or ScanIndex(scan)
    starts, scores = search_starts(scan, index, keep=keep)
    return _head_start(index, starts[0], scores), scores


def search_starts(
    scan: Scan, index: ScanIndex, *, keep: int = 2, feetless: bool = False, taller: bool = False
) -> tuple[list[Start], list[dict[str, Any]]]:
    """Rounds 1 and 2 of :func:`choose_alignment`: every articulated start, best score first,
    and every trial's score. The ``keep`` best rigid candidates go on to round 2, those within
    :data:`RIGID_KEEP_MARGIN` of the best. Where the scan's trunk is deeper than the
    template's (:func:`girth_scale` > :data:`GIRTH_MIN`), every rigid candidate is tried from
    the template widened and deepened about its vertical axis by that factor too, and goes on
    to round 2 with the middle arm hypothesis (the best of them with the others): from either
    template a heavy body's rigid scores read 1.5-1.6 whichever way up or round, and the best
    rigid candidate was the body upside down (closed_lowres-59/73 of
    ``core.synth.scanner_outputs``); the articulated round tells. ``feetless``: the scan ends
    above the soles (:func:`candidate_alignments`). ``taller``: the best rigid candidate also
    goes on :data:`TALLER_START` taller (the middle arm hypothesis, the others where it beats
    every start so far)."""
    tpl = load_template()
    ops = template_operators()
    F = np.asarray(tpl.F, dtype=np.int64)
    empty_i, empty_p = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    body_ids = np.flatnonzero(ops.full.data_mask)[::6]
    scan_ids = scan_sample(index)

    # the average template, and where the scan's trunk is deeper, one as wide and deep as it
    # (a heavy body's scan matched no start of the average template): each rigid candidate
    # from both, the best go on; a start keeps only similarity, pose and coefficients
    g = girth_scale(scan)
    templates = [(1.0, tpl.V)]
    if g > GIRTH_MIN:
        mid = np.median(tpl.V, axis=0)
        wide = tpl.V.copy()
        wide[:, [0, 2]] = mid[[0, 2]] + g * (wide[:, [0, 2]] - mid[[0, 2]])
        templates.append((g, wide))

    def run(
        V0: np.ndarray, sim: Similarity, pose: dict | None, iterations: int, articulated: bool
    ) -> Any:
        return fit_body_prior(
            index, V0, F, empty_i, empty_p, sim, data_mask=ops.full.data_mask,
            iterations=iterations, k_schedule=(0, 0, 6) if articulated else (0,),
            freeze_pose=1 if articulated else iterations + 1, bidirectional=True, subsample=6,
            scan_sample=3000, initial_pose=pose, max_angle_deg=180.0,
            point_weight=SEARCH_POINT_WEIGHT, limb_prior=LIMB_PRIOR,
            bone_prior=SEARCH_BONE_PRIOR, upright=UPRIGHT,
        )  # fmt: skip

    scores: list[dict[str, Any]] = []

    def rigid_fit(trial: tuple[int, Similarity, float, np.ndarray]) -> tuple:
        i, sim, gi, V0 = trial
        t = run(V0, sim, None, 3, False)
        return (two_way_score(index, t.X, body_ids, scan_ids), i, gi, V0, t)

    trials = [
        (i, s, gi, V0)
        for i, s in enumerate(candidate_alignments(scan, feetless=feetless))
        for gi, V0 in templates
    ]
    rigid = map_in_threads(rigid_fit, trials)
    for sc, i, gi, _, t in rigid:
        scores.append({"stage": "rigid", "candidate": i, "girth": gi, "score": sc,
                       "coverage": t.coverage})  # fmt: skip
    rigid.sort(key=lambda r: r[0])
    plain = [r for r in rigid if r[2] == 1.0]
    hypotheses = arm_hypotheses(scan)
    chosen = [r for r in plain[:keep] if r[0] <= plain[0][0] + RIGID_KEEP_MARGIN]
    flip = []  # rigid fits that cannot tell up from down: the best the other way up goes on
    if plain and plain[0][4].coverage < RIGID_POOR_COVERAGE:
        ways = {_stands_head_down(r[4].similarity) for r in chosen}
        flip = [r for r in plain if _stands_head_down(r[4].similarity) not in ways][:1]
    starts: list[Start] = []

    def arms_start(trial: tuple[tuple, float]) -> Start:
        (_, i, gi, V0, t), abd = trial
        a = run(V0, t.similarity, arm_pose(abd), 6, True)
        sc = two_way_score(index, a.X, body_ids, scan_ids)
        label = f"candidate {i}{f', girth ×{gi:.2f}' if gi != 1.0 else ''}, arms {abd:.0f}°"
        return Start(a.similarity, a.pose, a.coefficients, sc, a.coverage, label)

    def arms_starts(trials: list[tuple[tuple, float]]) -> list[Start]:
        """:func:`arms_start` of each (rigid fit, abduction) (on :func:`map_in_threads`),
        its score recorded in ``scores``, in order."""
        got = map_in_threads(arms_start, trials)
        for ((_, i, gi, _, _), abd), st in zip(trials, got, strict=True):
            scores.append({"stage": "articulated", "candidate": i, "girth": gi, "arms_deg": abd,
                           "score": st.score, "coverage": st.coverage})  # fmt: skip
        return got

    starts += arms_starts([(r, abd) for r in chosen for abd in hypotheses])
    mid_abd = ARM_HYPOTHESES[len(ARM_HYPOTHESES) // 2]
    if taller and plain and not feetless:  # the best one taller (the crown not in the scan)
        sc, i, gi, V0, t = plain[0]
        flip.append((sc, f"{i} ×{TALLER_START:.2f} taller", gi, V0, _taller(t)))
    for r in flip:  # the middle arm hypothesis; the others where it beats every start so far
        (st,) = arms_starts([(r, mid_abd)])
        if st.score < min(x.score for x in starts):
            starts += arms_starts([(r, abd) for abd in hypotheses if abd != mid_abd])
        starts.append(st)
    wide = [r for r in rigid if r[2] != 1.0]
    if wide:
        # a heavy body's rigid scores read 1.5-1.6 whichever way up or round: each candidate
        # of the widened template gets the middle arm hypothesis, the best one the others
        tried = list(zip(arms_starts([(r, mid_abd) for r in wide]), wide, strict=True))
        starts += [st for st, _ in tried]
        best = min(tried, key=lambda x: x[0].score)[1]
        starts += arms_starts([(best, abd) for abd in hypotheses if abd != mid_abd])
    starts.sort(key=lambda st: st.score)
    return starts, scores


#: Articulated starts scoring within this of the best (:func:`two_way_score`) are near-tied:
#: the markerless fit runs its first shape-space fit from the best two and keeps the better one.
#: The search's scores of arms 30° and 50° differ by 0.001–0.02 on most real-world-like scans
#: (``core.synth.scanner_outputs``); closed_lowres-4: 0.882 (a leg on the wrong foot, foot_L
#: 128 mm off after the fit) vs 0.889 (right).
TIE_MARGIN = 0.03
#: The near-tie margin where even the best start matches less than ``min_coverage`` of the
#: template (a body far from the template's shape: the search's scores are all poor and less
#: telling). raw-63 of ``bench.realworld --heavy`` (BMI 45, arms 55°): arms 10° scored 1.239
#: (both arms lost after the fit, 186 mm from the truth), the widened template's arms 30° 1.271
#: (right: 22 mm).
POOR_TIE_MARGIN = 0.06


#: A markerless fit whose crown stands more than this (metres) above the scan's highest point
#: over the head warns that the crown is a guess (:func:`crown_gap`); a raw scan's crown
#: dropout (hair) is 1-4 cm.
CROWN_GAP_M = 0.03
#: Horizontal radius (metres) about the fitted crown within which scan points count as the
#: head's (:func:`crown_gap`).
CROWN_RADIUS_M = 0.12


def crown_gap(scan: Scan, X: np.ndarray) -> float:
    """How far (metres) the crown of the fitted body X (13380, 3) stands above the scan's
    highest point within :data:`CROWN_RADIUS_M` of it horizontally (+Y up); inf without any."""
    head = X[load_template().part_mask("head")]
    crown = head[np.argmax(head[:, 1])]
    V = np.asarray(scan.V)
    near = np.hypot(V[:, 0] - crown[0], V[:, 2] - crown[2]) < CROWN_RADIUS_M
    return float(crown[1] - V[near, 1].max()) if near.any() else float("inf")


def _taller(fit: PriorFit) -> PriorFit:
    """``fit`` with its similarity :data:`TALLER_START` times larger about its body's soles (its
    lowest point; its highest where it stands head-down), centred as before."""
    sim, Y = fit.similarity, fit.X
    foot = Y[:, 1].max() if _stands_head_down(sim) else Y[:, 1].min()
    pivot = np.array([np.median(Y[:, 0]), foot, np.median(Y[:, 2])])
    k = TALLER_START
    return replace(fit, similarity=Similarity(k * sim.s, sim.R, pivot + k * (sim.t - pivot)))


def _stands_head_down(sim: Similarity) -> bool:
    """Whether the template → scan similarity ``sim`` stands the template head-down along the
    scan's up axis."""
    return bool(sim.R[1, 1] < 0)


def _head_down(start: Start) -> bool:
    """Whether ``start`` stands the template head-down along the scan's up axis."""
    return _stands_head_down(start.similarity)


def near_tied(starts: list[Start], min_coverage: float) -> list[Start]:
    """The best start and the second where it scores within the tie margin of it: within
    :data:`TIE_MARGIN`, or :data:`POOR_TIE_MARGIN` where the best matches less than
    ``min_coverage`` of the template; where both stand the same way up, also the best start
    standing the other way if it is within the margin. ``starts``: best score first
    (:func:`search_starts`).

    The other way up: closed_wide-501 of ``core.synth.scanner_outputs`` (BMI 57, arms 76° out,
    hair) — its best starts stood head-down (1.299, 1.303: 16 % of the template within 1.5 cm)
    and the best upright one scored 1.349; fitted from the head-down start the body was lost
    (1.26 m correspondence, verdict failed), from the upright one 19 mm."""
    best = starts[0]
    poor = not np.isfinite(best.coverage) or best.coverage < min_coverage
    margin = POOR_TIE_MARGIN if poor else TIE_MARGIN
    out = [st for st in starts[:2] if st.score <= best.score + margin]
    if all(_head_down(st) == _head_down(best) for st in out):
        flip = next((st for st in starts if _head_down(st) != _head_down(best)), None)
        if flip is not None and flip.score <= best.score + margin:
            out.append(flip)
    return out


#: Total neck flexions (degrees, + forward; head bone at rest) tried against the search's own head.
HEAD_FLEXIONS = (0.0, 15.0, 30.0)


def _head_start(index: ScanIndex, start: Start, scores: list[dict[str, Any]]) -> Start:
    """The start with its neck and head replaced by the rest pose flexed by one of
    :data:`HEAD_FLEXIONS` when that matches the scan's head better (two-way Geman–McClure score of
    the head and neck alone against the scan points within 25 cm of them); the rest stays.

    A nearly round head's data barely turn it, so the articulated search can leave the head bone
    tilted 45–60° while real necks and heads flex 7–40° together, and no later fit turns it back
    (raw-12 of ``core.synth.scanner_outputs``: head centroid 72 mm off the truth's at the start,
    66 mm after the fit). Measured (markerless, default options): raw-12 correspondence 35.8 ->
    7.6 mm, raw-31 63.7 -> 52.1, raw-0 17.4 -> 16.6, closed_lowres-2 16.4 -> 16.4; on 12 other
    realworld cases and bench.cases seeds 3, 5 the search's own head scores better (unchanged).
    """
    tpl = load_template()
    F = np.asarray(tpl.F, dtype=np.int64)
    none_i, none_p = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    head = np.flatnonzero(tpl.part_mask("head") | tpl.part_mask("neck"))[::3]

    def posed(pose: dict[str, np.ndarray]) -> np.ndarray:
        return fit_body_prior(
            index, tpl.V, F, none_i, none_p, start.similarity, iterations=0, initial_pose=pose,
            initial_coefficients=start.coefficients,
        ).X  # fmt: skip

    X0 = posed(start.pose)
    near = index.tree.query_ball_point(X0[head].mean(axis=0), r=0.25)
    P = index.points[np.asarray(near, dtype=np.int64)][:: max(1, len(near) // 2000)]
    s2 = SCORE_SIGMA**2

    def score(X: np.ndarray) -> float:
        d_b, _ = index.tree.query(X[head], k=1)
        d_s, _ = cKDTree(X[head]).query(P, k=1)
        return float(np.mean(d_b**2 / (d_b**2 + s2)) + np.mean(d_s**2 / (d_s**2 + s2)))

    best, best_sc, label = start.pose, score(X0), "search"
    for flex in HEAD_FLEXIONS:
        pose = dict(start.pose)
        pose["neck01"] = axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(flex))
        pose["head"] = np.eye(3)
        sc = score(posed(pose))
        scores.append({"stage": "head", "neck_deg": flex, "score": sc})
        if sc < best_sc:
            best, best_sc, label = pose, sc, f"neck {flex:.0f}°"
    if best is start.pose:
        return start
    return Start(
        start.similarity,
        best,
        start.coefficients,
        start.score,
        start.coverage,
        f"{start.label}, head {label}",
    )


#: Forearm twists (degrees about the forearm's axis, left side, + palm backwards; the right is
#: mirrored) from which :func:`fit_markerless` fits again a body whose open hand matches the scan
#: poorly (:func:`hand_mismatch` above :data:`POOR_HAND`): scanning protocols hold the palms
#: towards the thighs, backwards or forwards, and a hand's data barely turn the forearm in the
#: fits. A twisted pose of the fitted body cannot be scored as it stands (the elbow and wrist
#: were fitted around the wrong turn: every twist scored worse than the fit's own, the right one
#: too); each twist is a short shape-space fit (``quick``), ~1-2 s CPU.
HAND_TWISTS = (90.0, -90.0)
#: :func:`hand_mismatch` above which a hand is fitted again from :data:`HAND_TWISTS`.
POOR_HAND = 0.3
#: A twisted refit replaces the fit only where its hands' mismatch (summed over the refitted
#: sides) is lower by more than this than the fit's and than the other twist's.
HAND_TWIST_MARGIN = 0.05


def hand_mismatch(index: ScanIndex, X: np.ndarray, side: str) -> float:
    """Two-way Geman–McClure mismatch (σ = :data:`SCORE_SIGMA`, in [0, 2], lower is better) of the
    hand and forearm of ``side`` ("L"/"R") of a body ``X`` (13380, 3) against the scan points the
    body puts nearest them (within 3 cm); 0 where fewer than 50 such points."""
    tpl = load_template()
    arm = tpl.part_mask(f"hand_{side}") | tpl.part_mask(f"forearm_{side}")
    ids = np.flatnonzero(arm)
    lo, hi = X[ids].min(axis=0) - 0.05, X[ids].max(axis=0) + 0.05
    box = np.flatnonzero(np.all((index.points >= lo) & (index.points <= hi), axis=1))
    d, nearest = cKDTree(X).query(index.points[box], k=1)
    near = box[arm[nearest] & (d < 0.03)]
    if len(near) < 50:
        return 0.0
    P = index.points[near[:: max(1, len(near) // 2000)]]
    s2 = SCORE_SIGMA**2
    d_b, _ = cKDTree(P).query(X[ids[::2]], k=1)
    d_s, _ = cKDTree(X[ids]).query(P, k=1)
    return float(np.mean(d_b**2 / (d_b**2 + s2)) + np.mean(d_s**2 / (d_s**2 + s2)))


def twisted_pose(prior: PriorFit, sides: str, twist_deg: float) -> dict[str, np.ndarray]:
    """The body prior's pose with the forearm of each of ``sides`` twisted by ``twist_deg`` about
    its rest axis (the right side mirrored: the same turn of the palm)."""
    rig = load_rig()
    J = joint_positions(prior.rest, rig=rig)
    pose = dict(prior.pose)
    for side in sides:
        bone = f"lowerarm01.{side}"
        axis = J[rig.index(f"wrist.{side}")] - J[rig.index(bone)]
        axis = axis / np.linalg.norm(axis)
        sign = 1.0 if side == "L" else -1.0
        pose[bone] = pose.get(bone, np.eye(3)) @ axis_angle(axis, np.radians(sign * twist_deg))
    return pose


#: ``feet_apart_m`` (:func:`core.registration.quality.feet_apart`) below which the first fit's
#: legs are crossed and :func:`fit_markerless` fits again from straight legs.
CROSSED_FEET_M = 0.0
#: The rig's leg bones (without their ``.L``/``.R``) that the uncrossed refit starts at rest.
LEG_BONES = ("upperleg01", "upperleg02", "lowerleg01", "lowerleg02", "foot")


#: The rig's arm bones (without ``.L``/``.R``) that the mirrored-arm refit poses as the other
#: side's, and the reflection through the body's sagittal plane (the template's left is +x).
ARM_BONES = ("clavicle", "upperarm01", "lowerarm01", "wrist")
MIRROR_X = np.diag([-1.0, 1.0, 1.0])


def arm_reach(X: np.ndarray, side: str) -> float:
    """Length (metres) of arm ``side`` of the body ``X`` (13380, 3): Acromion -> Radiale ->
    Radial_styloid."""
    L = load_template().landmarks
    a, e, w = (X[L[f"{n}_{side}"]] for n in ("Acromion", "Radiale", "Radial_styloid"))
    return float(np.linalg.norm(e - a) + np.linalg.norm(w - e))


#: The quality retries (:data:`core.registration.fit.RETRIES`) of the last soft-marker round. Its
#: markers are the landmarks the previous round predicts, on every part: another arm start is
#: pulled back by the arm's and hand's landmarks, and trusting them fully pulls the body back to
#: the previous round's; only weighting the lost parts' data (with scan→body pairs) can move a
#: lost part. Measured on 10 realworld cases that retry (raw-9/16/24, raw_inward-22, cloud-6/18,
#: closed_plate-3, closed_touching-5, closed_lowres-4/16; each retry a full fit, ~1.8 s CPU): no
#: retry ever changed the verdict; only the lost-parts one changed the parts named (raw_inward-22:
#: hands L+R -> L); the arm starts' body priors ended 2-9 mm from the first fit's (raw-24: 151 mm,
#: failed). Dropping the other three changes the kept attempt of raw-9 (corr 18.55 -> 18.38 mm)
#: and closed_touching-5 (18.72 -> 21.26 mm), same verdicts and parts; −5.5 s CPU per such fit.
#: Its body prior runs :data:`RETRY_ITERATIONS`, whatever :data:`ROUND_ITERATIONS`: the retry
#: path is the markerless fit's slowest (raw-35, 190 k points: with both at 24, 9.5 s CPU
#: against 8.4 at 12).
MARKERLESS_RETRIES = tuple(
    (name, {**o, "iterations": RETRY_ITERATIONS}) for name, o in RETRIES if "part_weight" in o
)


def _take_over(scan: Scan, other: Scan) -> None:
    """The caller's ``scan`` becomes ``other`` (every field), in place."""
    for f in fields(scan):
        setattr(scan, f.name, getattr(other, f.name))


def _turned(start: Start, M: np.ndarray) -> Start:
    """``start`` for the scan rotated by ``M`` (3, 3): its similarity followed by ``M``."""
    sim = start.similarity
    return replace(start, similarity=Similarity(sim.s, M @ sim.R, M @ sim.t))


@single_blas_thread
def fit_markerless(
    scan: Scan,
    *,
    refine: bool = True,
    schedule: Schedule | None = None,
    callback: Callable[[Progress], bool | None] | None = None,
    min_coverage: float = 0.4,
    soft_marker_rounds: int = 1,
    taller_start: bool = False,
    **options: Any,
) -> FitResult:
    """Fit the template to a scan without markers.

    Parameters
    ----------
    scan : the scan (metres, canonical frame, see ``core.io.load_scan``).
    refine : follow the shape-space fit by the per-vertex affine refinement.
    schedule : the refinement schedule (default :meth:`Schedule.refine`); ignored without refine.
    min_coverage : if even the best start matches less than this share of the template within
        1.5 cm, the result carries a warning (the fit may be wrong); it is still returned.
    soft_marker_rounds : with ``refine``, refit the body prior this many times, each round with
        the landmarks the previous result predicts as markers (each restart brings pose and
        shape closer); the last round runs the refinement schedule (markers weak, γ = 0.1).
        Hair and fists are looked for before the rounds (0: neither; the shape-space result is
        refined directly). Default 1: on bodies off the prior's space (``bench.realworld``, 40
        cases) each further round moved the body away from the truth and the closed and raw
        deliveries of one body apart (1 vs 4 rounds: correspondence 10.8 vs 12.6 mm mean,
        closed-vs-raw twins 6.5 vs 7.8 mm mean, 7.8 vs 11.2 worst, verdicts good 36 vs 32,
        CPU median 4.6 vs 6.5 s); on the prior's own simulated bodies (``bench.matching``
        seeds 0-5) 4 rounds gained 0.06 mm (3.44 vs 3.38 mm mean).
    taller_start : the search also starts the body :data:`TALLER_START` taller; set by the fit
        itself when its head fails without it (and the better attempt kept).

    Returns
    -------
    FitResult as for :func:`core.registration.fit.fit`; the report notes the chosen alignment.

    Raises
    ------
    NotABodyError
        The scan's size or proportions rule out a standing body (``core.matching.body_check``):
        the only refusal; a body matched poorly is a result with warnings.
    """
    frame = "" if scan.frame is None else f"units {scan.frame.units}, up {scan.frame.up}"
    check_body_shape(scan.V, scan.F, frame=frame)
    callback = serialised(callback)  # near-tied first fits may report at once
    index = ScanIndex(scan)
    snapshot = replace(  # the scan as given, for a second attempt (the fit turns it in place)
        scan, notes=list(scan.notes), textured=copy.copy(scan.textured)
    )
    starts, scores = search_starts(scan, index, taller=taller_start)
    tied = [_head_start(index, st, scores) for st in near_tied(starts, min_coverage)]
    # each start is fitted with the scan held its way up: the best's way is the caller's scan
    # (turned over, in place, where it stands head-down), a contender standing the other way
    # (:func:`near_tied`) gets a copy held its way
    best_down = _head_down(tied[0])
    # a cut through the head closed flat by scanner software: the cap is not the crown (the
    # search's starts stand as they are: the cap's rim stays)
    caps = head_cap(scan, down=best_down)
    head_note = ""
    if caps.sum() >= MIN_CAP_POINTS:
        _take_over(scan, scan_without(scan, caps, "head_cap_points", rim=True))
        index = ScanIndex(scan)
        head_note = (
            f"{int(caps.sum())} points closing a cut through the head left out (a flat cap, "
            "not the crown: a scan volume too short for the subject?)"
        )
    # a scan that ends above the soles (ankles where the best start stands, not feet): searched
    # again held that way up, its body standing below the scan (``--feetless``: stood on the
    # cut and scaled to the scan's height, bodies 39 mm from the truth, feet 117-190 mm)
    feet = feet_in_scan(scan, top=best_down)
    cap_note = ""
    if not feet:
        if best_down:
            turn_over(scan)
            index = ScanIndex(scan)
        caps = cut_caps(scan)
        if caps.sum() >= MIN_CAP_POINTS:  # the caller's scan, in place (as turned over)
            _take_over(scan, scan_without(scan, caps, "cut_cap_points", rim=True))
            index = ScanIndex(scan)
            cap_note = (
                f"{int(caps.sum())} points closing the scan's cut above the soles left out "
                "(a cap, not the body)"
            )
        starts, scores = search_starts(scan, index, feetless=True, taller=taller_start)
        tied = [_head_start(index, st, scores) for st in near_tied(starts, min_coverage)]
        best_down = _head_down(tied[0])
    other = [st for st in tied if _head_down(st) != best_down]
    tied = [st for st in tied if _head_down(st) == best_down]
    alt_scan = copy.deepcopy(scan) if other else None
    if best_down:  # head-down along the up axis read: turn the scan over
        M = turn_over(scan)
        tied = [_turned(st, M) for st in tied]
        index = ScanIndex(scan)
    views = [(scan, index, tied)]
    if alt_scan is not None:
        if not best_down:
            M = turn_over(alt_scan)
            other = [_turned(st, M) for st in other]
        views.append((alt_scan, ScanIndex(alt_scan), other))
    if soft_marker_rounds < 0:
        raise ValueError(f"soft_marker_rounds must be ≥ 0, got {soft_marker_rounds}")
    rounds = soft_marker_rounds if refine else 0
    sched = (schedule or Schedule.refine()) if refine else Schedule(())
    user_prior = options.pop("prior_options", {}) or {}

    def first_fit(
        start: Start, view: Scan, view_index: ScanIndex, quick: bool = False
    ) -> FitResult:
        """The shape-space fit from ``start``; ``quick``: from a converged fit's body (all
        components at once, half the iterations, the pose free from the first)."""
        prior_options: dict[str, Any] = {
            "k_schedule": K_SCHEDULE[-1:] if quick else K_SCHEDULE,
            "iterations": 8 if quick else 16,
            "bidirectional": True,
            "scan_oversample": FIRST_FIT_SCAN_OVERSAMPLE,
            **denser_template_rows(FIRST_FIT_SUBSAMPLE),
            "freeze_pose": 0 if quick else 3,
            "initial_pose": start.pose,
            "initial_coefficients": start.coefficients,
            "limb_prior": LIMB_PRIOR,
            "bone_prior": MARKERLESS_BONE_PRIOR,
            "floor_y": scan_floor(view) if feet else None,
            "hand_length": True,
            "upright": UPRIGHT,
        }
        prior_options.update(user_prior)
        return fit(
            view, {}, initial_similarity=start.similarity,
            schedule=sched if rounds == 0 else Schedule(()), retry=rounds == 0,
            callback=callback if rounds == 0 else None, prior_options=prior_options,
            index=view_index, assess=rounds == 0, absent_parts=() if feet else FEET,
            **options,
        )  # fmt: skip

    # the body vertices that score whole fits against the scan (:func:`two_way_score`)
    body_ids = np.flatnonzero(template_operators().full.data_mask)[::2]

    def refit(
        prior: PriorFit, pose: dict[str, np.ndarray], what: str, quick: bool = False
    ) -> tuple[Start, FitResult]:
        """The shape-space fit again from the fit ``prior`` (its similarity and shape) posed
        ``pose``, and its start (``start``'s, labelled "refitted with ``what``")."""
        st = replace(
            start, similarity=prior.similarity, pose=pose, coefficients=prior.coefficients,
            label=f"{start.label}, refitted with {what}",
        )  # fmt: skip
        return st, first_fit(st, scan, index, quick=quick)

    def whole_score(X: np.ndarray) -> float:
        """:func:`two_way_score` of a body X (13380, 3) against the scan."""
        return two_way_score(index, X, body_ids, scan_sample(index, 12000))

    tie_note = ""
    if sum(len(v[2]) for v in views) == 1:
        start, res = tied[0], first_fit(tied[0], scan, index)
    else:
        # near-tied starts (often arms 30° vs 50°, one with a leg on the wrong foot; or the
        # body upright vs head-down): the shape-space fit from each tells them apart where the
        # search's short fits cannot. The scan sample is the same points in either view.
        scan_ids = scan_sample(index, 12000)
        trials = [(k, st, vs, vi) for k, (vs, vi, sts) in enumerate(views) for st in sts]

        def scored(trial: tuple[int, Start, Scan, ScanIndex]) -> tuple:
            k, st, vs, vi = trial
            r = first_fit(st, vs, vi)
            return (two_way_score(vi, r.vertices, body_ids, scan_ids), st, r, k)

        fits = map_in_threads(scored, trials)
        _, start, res, k = min(fits, key=lambda f: f[0])
        if k == 1:  # the other way up won: the caller's scan takes that view, in place
            assert alt_scan is not None
            _take_over(scan, alt_scan)
            index = views[1][1]
        tie_note = "; near-tied starts, the shape-space fit from each scored " + ", ".join(
            f"{f[1].label}{', head-down' if f[3] != int(best_down) else ''} {f[0]:.3f}"
            for f in fits
        )
        scores += [{"stage": "tie", "label": f[1].label, "score": f[0]} for f in fits]
    # a hand the fit left turned about its forearm (palms turned backwards, off-model bodies of
    # ``bench.realworld --palms``: the palm laid the wrong way round, its centroid 34-41 mm off):
    # fitted again from the fit's own body with those forearms twisted either way; the better
    # twist is kept where it matches the hands better than the fit and than the other twist
    # (a hand the refits cannot tell apart stays as fitted: closed_plate-3's fists matched
    # better after either refit, which put them 20 mm off). Fists are left out, and hands
    # resting on the body (fused in closed meshes: their scan points are the thigh's too).
    prior = res.body_prior
    poor, own = "", {}
    if rounds:
        own = {x: hand_mismatch(index, res.vertices, x) for x in "LR"}
        fisted = fisted_hands(index, res.vertices)
        gaps = hand_body_gaps(res.vertices)
        resting = THRESHOLDS["hand_body_gap_m"].suspect
        poor = "".join(
            x for x in "LR" if own[x] > POOR_HAND and x not in fisted and gaps[x] >= resting
        )
    if poor and prior is not None:
        body_prior = prior

        def twisted(tw: float) -> tuple[float, Start, FitResult]:
            what = f"forearm {'+'.join(poor)} twisted {tw:+.0f}°"
            st, r_tw = refit(body_prior, twisted_pose(body_prior, poor, tw), what, quick=True)
            return sum(hand_mismatch(index, r_tw.vertices, x) for x in poor), st, r_tw

        tried = map_in_threads(twisted, HAND_TWISTS)
        for tw, (got, _, _) in zip(HAND_TWISTS, tried, strict=True):
            scores.append({"stage": "hand", "twist_deg": tw, "own": own, "twisted": got})
        best = min(tried, key=lambda t: t[0])
        worst = max(t[0] for t in tried)
        base = sum(own[x] for x in poor)
        if best[0] < base - HAND_TWIST_MARGIN and best[0] < worst - HAND_TWIST_MARGIN:
            _, start, res = best
    # legs crossed (each foot on the other's data; closed_booth-328, feet 1 cm apart, a heavy
    # body's fused thighs: feet 97/105 mm off): fitted again from that fit with the legs'
    # bones at rest, kept where the legs come apart and it scores no worse than the tie margin.
    # A whole shape-space fit: a quick one from there left raw_palms-605's right foot 449 mm
    # off (its score better all the same: the left leg came right), and the round kept it
    prior = res.body_prior
    if rounds and prior is not None and feet_apart(res.vertices) < CROSSED_FEET_M:
        pose = {b: R for b, R in prior.pose.items() if b.split(".")[0] not in LEG_BONES}
        st, r_st = refit(prior, pose, "the legs uncrossed")
        before, after = whole_score(res.vertices), whole_score(r_st.vertices)
        apart = feet_apart(r_st.vertices)
        scores.append({"stage": "legs", "score": after, "crossed": before, "feet_apart_m": apart})
        if apart >= CROSSED_FEET_M and after < before + TIE_MARGIN:
            start, res = st, r_st
    # one arm stretched along its data (heavy raw-102: the left arm 1.28x the right's, its
    # hand on the thigh 146 mm off): fitted again from that fit with that arm posed as the other
    # one, mirrored; kept where the arms come closer in length within the tie margin
    prior = res.body_prior
    sym = arm_symmetry(res.vertices) if rounds and prior is not None else 1.0
    if prior is not None and sym > THRESHOLDS["arm_symmetry"].suspect:
        long, short = (
            ("L", "R")
            if arm_reach(res.vertices, "L") > arm_reach(res.vertices, "R")
            else ("R", "L")
        )
        pose = dict(prior.pose)
        for b in ARM_BONES:
            pose[f"{b}.{long}"] = MIRROR_X @ prior.pose.get(f"{b}.{short}", np.eye(3)) @ MIRROR_X
        st, r_st = refit(prior, pose, f"arm {long} posed as arm {short}")
        before, after = whole_score(res.vertices), whole_score(r_st.vertices)
        sym_after = arm_symmetry(r_st.vertices)
        scores.append({"stage": "arms", "score": after, "before": before, "symmetry": sym_after})
        if sym_after < sym and after < before + TIE_MARGIN:
            start, res = st, r_st
    best_cov = start.coverage
    low_coverage = not np.isfinite(best_cov) or best_cov < min_coverage
    notes = list(res.report.notes)
    if rounds and scan.F is None:
        note = turn_normals_against_body(
            scan, res.vertices, load_template().F, "the first fitted body"
        )
        if note:
            index = ScanIndex(scan)
            notes.append(note)
    # hair: what stands off the first body (fitted to all the data) over the scalp; not looked
    # for again around later bodies (a head fitted too low would call its own scalp hair)
    hair = find_hair(scan, res.vertices) if rounds else None
    # one KD-tree for every round (and its retry): the scan's, or that of the scan without hair
    round_index = index if hair is None or hair.scan is scan else ScanIndex(hair.scan)
    fists = fisted_hands(round_index, res.vertices) if rounds else ""
    # a hand resting on the torso or thigh (fused to it in a closed mesh): the scan cannot tell
    # hand from thigh, and the thigh's data and the first fit's hand landmarks (where its
    # stretched arm put them) pulled it 5-9 cm down the thigh. In the round it takes no data and
    # no landmarks: the arm's data and the body prior place it (``bench.realworld --booth`` 40:
    # correspondence 16.05 -> 15.57 mm, closed_booth-322's hands 35/24 -> 16/11 mm off, but
    # -311's 29/38 -> 46/52; without data alone 15.90, without landmarks alone 15.90 and two
    # fits failed; varied 40 9.07 -> 8.95, heavy 20 17.90 -> 17.70, raw-102's hand 95 -> 62 mm)
    resting = ""
    if rounds:
        gaps = hand_body_gaps(res.vertices)
        rest_gap = THRESHOLDS["hand_body_gap_m"].suspect
        resting = "".join(x for x in "LR" if gaps[x] < rest_gap and x not in fists)
    for r in range(rounds):
        last = r == rounds - 1
        assert hair is not None
        marks = predicted_landmarks(res.vertices)
        if r == 0:
            # a fist's fingertip is not where the first fit's open hand put it (7-9 cm off):
            # held there, it dragged the fisted arms (raw-24 and closed_lowres-24: 46-47 mm from
            # the truth after round 1, 20-22 mm before; their twins 15.6 -> 12.2 mm without it)
            for x in fists:
                marks.pop(f"Dactylion_{x}")
            for x in resting:
                for lm in ("Dactylion", "Ulnar_styloid", "Radial_styloid"):
                    marks.pop(f"{lm}_{x}", None)
            # an open hand clear of the body: its fingertip just past where the scanned hand
            # ends (the first fit's came from the shape coefficients: the fingers take no data;
            # a coarse mesh rounds the tip off: :func:`tip_allowance`)
            # (a closed mesh's mitten: on the hand's axis, :meth:`HandEnd.fingertip`; there the
            # fingertip's landmark set the hands 4-10 mm off the truth where their raw twins' were
            # 3-5: ``bench.realworld --filled`` correspondence 8.58 -> 8.36 mm, hands 8.3/9.0 ->
            # 7.7/7.9, twins 4.70 -> 4.38)
            skip = fists + resting
            tip = tip_allowance(round_index)
            mitten = round_index.closing_radius_m > 0
            for x, end in free_hand_ends(round_index, res.vertices, skip=skip).items():
                marks[f"Dactylion_{x}"] = end.fingertip(tip, on_axis=mitten)
            # the toe tips just past where the scanned feet end (the first fit's came from the
            # shape coefficients where the toes take no data: ``core.registration.foot_end``)
            toe = toe_allowance(round_index)
            # (none on a scan that ends above the soles: its ankles are no foot's end)
            ends = scanned_foot_ends(round_index, res.vertices) if feet else {}
            for x, foot in ends.items():
                marks[f"Toe_tip_{x}"] = toe_tip_marker(res.vertices, x, foot, toe)
        # the round's body prior from the landmarks' alignment and rest pose, and from where the
        # previous fit's ended; the latter is kept where it scores better (two-way) by more than
        # the search's near-tie margin: from the rest pose a head could settle turned
        # (closed_booth-303: 30°, 9 -> 39 mm off the truth; 0.512 vs 0.454), from the previous
        # fit a heavy body's lost feet or arm stayed lost (raw-59/63 of --heavy; raw-59 0.456
        # vs 0.535), and near ties went either way (without the margin: heavy 20 18.37 -> 19.50
        # mm, 4 good -> suspect, each within 0.005)
        prev = res.body_prior
        assert prev is not None
        score = partial(
            two_way_score, round_index, body_ids=body_ids, scan_ids=scan_sample(round_index, 12000)
        )
        restart = PriorRestart(prev, score, margin=TIE_MARGIN, iterations=RESTART_ITERATIONS)
        # the bone length prior (:data:`BONE_LENGTH_PRIOR`) in the round: an arm fused to the
        # flank of a closed mesh has data all down the thigh, and the first fit stretched its
        # forearm (or left it short); a resting hand's forearm is pulled to a real adult's mean
        # length (:data:`~core.registration.shape_prior.ARM_BONE_CENTRES`), the other bones held
        # in their bands (a heavy body's thigh, its skin slid by the shape space's fat, too short)
        # and the thighs pulled gently to the mean length (the shape space slides the upper
        # thigh's skin down the thigh to fit its surface a little closer: LEG_BONE_CENTRES);
        # the spine's joints held at their template shares of the trunk (TRUNK_PRIOR: a heavy
        # body's waist skin slid down the belly)
        res = fit(
            hair.scan, marks, schedule=sched if last else Schedule(()),
            callback=callback if last else None, retry=last, index=round_index, assess=last,
            retries=MARKERLESS_RETRIES, prior_restart=restart, soft_markers=True,
            part_weights={f"hand_{x}": 0.0 for x in resting} or None, prior_options={
                "limb_prior": LIMB_PRIOR, "fists": fists, "bone_prior": ROUND_BONE_PRIOR,
                "iterations": ROUND_ITERATIONS, "hand_length": True, "foot_length": feet,
                "bone_length_prior": BONE_LENGTH_PRIOR,
                "bone_length_centred": resting, "leg_length_centre": LEG_CENTRE_PRIOR,
                "trunk_prior": TRUNK_PRIOR, "shape_prior_weight": ROUND_SHAPE_PRIOR,
                "point_weight": ROUND_POINT_WEIGHT, "sole_data": ROUND_SOLE_DATA,
                "upright": UPRIGHT,
                **denser_template_rows(ROUND_SUBSAMPLE),
            },
            absent_parts=() if feet else FEET,
            **options,
        )  # fmt: skip
    if hair is not None and hair.count:
        res.report.warnings.append(hair.warning())
    if not feet:
        res.report.warnings.append(FEETLESS_WARNING)
    for note in (cap_note, head_note):
        if note:
            (notes if rounds else res.report.notes).append(note)
    if rounds:
        notes.append(FLAT_HAIR_NOTE)
    if resting:
        notes.append(
            f"hands resting on the body ({', '.join(resting)}): placed by the arms' data and the "
            "body prior (forearms of an adult's mean length), not by the scan around them "
            "(it cannot tell hand from thigh, nor where the forearm ends)"
        )
    if fists:
        notes.append(
            f"hands fitted as fists ({', '.join(fists)}): the open hand's fingertips of the "
            f"shape-space fit were > {FIST_TIP_GAP_M * 1000:.0f} mm from the scan"
        )
    if rounds:
        rep = res.report
        n_warn = sum(w.startswith("marker ") for w in rep.warnings)
        rep.warnings = [w for w in rep.warnings if not w.startswith("marker ")]
        later = [n for n in rep.notes if n not in notes and not n.startswith("body prior")]
        if any(n.startswith(HAND_LENGTH_NOTE) for n in later):  # the rounds' hands stand
            notes = [n for n in notes if not n.startswith(HAND_LENGTH_NOTE)]
        rep.notes = notes + later
        rep.notes.append(
            f"markerless refinement: {rounds} body-prior rounds with the landmarks predicted by "
            f"the previous round as soft markers ({n_warn} left out as far from the body)"
            + (
                ""
                if res.body_prior is None
                else f"; the last round's body prior moved the body "
                f"{res.body_prior.last_step_m * 1000:.2f} mm (mean) in its last iteration"
            )
        )
        rep.markers_used, rep.markers_dropped, rep.marker_residuals_m = [], [], {}
    res.report.notes.append(
        f"markerless: best of {len(scores)} starts ({start.label}; two-way score "
        f"{start.score:.3f}, {best_cov * 100:.0f} % of the template within 1.5 cm{tie_note})"
    )
    q = res.report.quality
    if feet and not taller_start and q is not None and q.parts["head"].quality == "failed":
        # a head bent down into a scan whose crown is missing (:data:`TALLER_START`)
        again = fit_markerless(
            snapshot, refine=refine, schedule=schedule, callback=callback,
            min_coverage=min_coverage, soft_marker_rounds=soft_marker_rounds,
            taller_start=True, prior_options=user_prior, **options,
        )  # fmt: skip
        kept = attempt_score(again) < attempt_score(res)
        note = (
            f"the head failed: fitted again with a start {TALLER_START:.2f}× taller (a crown not "
            f"in the scan?): {'kept' if kept else 'not kept'} ({q.quality} -> "
            f"{again.report.quality.quality if again.report.quality else 'n/a'})"
        )
        if kept:  # the caller's scan as that attempt held it
            _take_over(scan, snapshot)
            again.report.notes.append(note)
            return again
        res.report.notes.append(note)
    gap = crown_gap(scan, res.vertices)
    if gap > CROWN_GAP_M:
        res.report.warnings.append(
            f"the scan ends {gap * 1000:.0f} mm below the fitted crown (the top of the head not "
            "scanned: hair that returned no light, or a scan volume too short for the subject): "
            "the crown is the body prior's guess, and the stature includes it"
        )
    if low_coverage:
        res.report.warnings.append(
            f"the starting alignment matched only {best_cov * 100:.0f} % of the template within "
            "1.5 cm of the scan: the body may be misplaced or misposed; check the fit (scan→fit "
            f"{res.report.scan_to_fit_mean_m * 1000:.1f} mm mean)"
        )
    return res


#: A hand of the first shape-space fit whose fingertips (quality figure ``hand_tip_gap_m``) are
#: further than this from the scan is fitted as a fist in the soft-marker rounds.
FIST_TIP_GAP_M = 0.042
#: least :func:`core.registration.hand_length.scanned_hand_roundness` of a fist: the 46 fists of
#: ``bench.realworld``'s varied, heavy and booth sets read 0.60-0.82 (one at the thigh, tip gap
#: 3 mm, 0.42); their open hands with fingertips past :data:`FIST_TIP_GAP_M` 0.32-0.55, but
#: for two resting on the thigh in closed booth meshes (0.59, 0.61)
FIST_ROUNDNESS = 0.575


def fisted_hands(index: ScanIndex, X: np.ndarray) -> str:
    """Sides (``"L"``, ``"R"``) whose hand the soft-marker rounds fit as a fist: the template's
    open hand of the body ``X`` (13380, 3) leaves its fingertips
    (:func:`core.registration.quality.hand_tip_gap`) more than :data:`FIST_TIP_GAP_M` from the
    scan.

    Scanned fists (and closed meshes' fused fists) end 4-5 cm short of an open hand; the data
    term does not reach the fingers, so the open template hand kept its fingers straight out in
    the air and its centroid 44-63 mm off the fist's. Fingertip gaps of the first shape-space fit
    on the 40 scans of ``core.synth.scanner_outputs.benchmark_cases(40)`` (since scan points
    nearest the fingers no longer pull the palm over them, ``shape_prior._scan_to_template``):
    21 of the 22 fists 49-91 mm (closed_plate-3's left hand 49, raw_inward-11's 54 and 54, the
    rest 55 and up; closed_plate-27's left fist, against the thigh, reads 6), the 58 open hands
    1-36 mm (closed_lowres-28 33/36, raw_clutter-10 28/32): the limit lies halfway. (Before, the
    palm pulled over the fingers' data read open hands up to 44 mm and the limit was 55 mm.)

    A hand past the tip gap must also be round in section (:func:`scanned_hand_roundness` at
    least :data:`FIST_ROUNDNESS`, or not measurable): heavy bodies' first fits put the arm
    2-5 cm out along itself, and their open hands' fingertips 43-78 mm past the scan (27 of
    the 58 open hands of the heavy and booth sets past 42 mm) — flat palms all the same.
    """
    fists = ""
    for x in "LR":
        if hand_tip_gap(index, X, x) <= FIST_TIP_GAP_M:
            continue
        roundness = scanned_hand_roundness(index, X, x)
        if roundness is None or roundness >= FIST_ROUNDNESS:
            fists += x
    return fists


def scan_floor(scan: Scan) -> float:
    """Height (metres, +Y up) the fitted body may not go below: the scan's lowest points (0.05th
    percentile of the heights) less :data:`FLOOR_GAP_M`."""
    return float(np.percentile(np.asarray(scan.V)[:, 1], 0.05)) - FLOOR_GAP_M


def predicted_landmarks(V: np.ndarray) -> dict[str, np.ndarray]:
    """Landmark name -> (3,) position on a fitted body ``V`` (13380, 3), template order."""
    tpl = load_template()
    return {k: np.asarray(V[i], dtype=np.float64) for k, i in tpl.landmarks.items()}
