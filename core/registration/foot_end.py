"""Where the scanned feet end: the toe tips' soft markers of the markerless round.

The template's toes take no data on coarsely sampled scans (``core.registration.fit``:
:data:`~core.registration.fit.TOE_DATA_MAX_SPACING_M`: booth meshes fuse and round them off),
so there the foot's length comes from the shape coefficients alone, and on bodies off the
prior's space that is often wrong: on the closed booth meshes of ``bench.realworld`` (seeds
16 and 28, BMI 36 and 39) the fitted toe tips stood 13-19 mm past the truth's after the
soft-marker round and 17-26 mm after the refinement, 16-29 mm past the end of the scanned foot,
while the raw scans of the same bodies (toes with data) put them within 5 mm. The scan says
where the foot ends: the round's toe-tip markers go there (:func:`toe_tip_marker`), and after
the round's body prior each forefoot is set to that length (:func:`correct_foot_lengths`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.registration.correspondence import ScanIndex
from core.template import Template, load_template
from core.threads import kd_workers

#: the scan's foot end is the n-th furthest foot point along the foot's axis (not a lone outlier)
END_RANK = 5
#: fewest scan points a measured foot needs
MIN_FOOT_POINTS = 30
#: scan points further than this (metres) from the fitted body are not the foot's
FOOT_POINT_GAP_M = 0.02
#: corrections of less than this (metres at the toe tip) are not made
#: (:func:`correct_foot_lengths`). Since the refinement leaves the feet's lower part to the
#: body prior (:func:`core.registration.fit.sole_band`) a few millimetres stay: 6 mm -> 2 mm put
#: the twin diagnostic's feet 4.68 / 3.07 -> 4.44 / 2.95 mm off the truth (closed / raw)
MIN_FOOT_CORRECTION_M = 0.002
#: a foot is stretched or shortened only within this share of its length (beyond it the scan's
#: foot end is not this foot's: a foot on the other one, lost in a hole)
FOOT_CORRECTION_LIMITS = (-0.12, 0.08)
#: share of the foot's length from the heel where its stretch begins: the ankle's ring (the foot's
#: border with the shin) reaches 0.42 of the template's foot, and stays put
FOREFOOT_FROM = 0.45
#: the toe tip lies ``TOE_TIP_PER_SPACING × (spacing − TOE_TIP_SPACING_OFFSET_M)`` past the
#: scanned foot's end (:func:`toe_allowance`; ``ScanIndex.resolution_m``: the sampling, but at
#: most 3 mm on a decimated mesh). On the truths of
#: ``bench.realworld``'s cases (diagnostic, 31 cases, both feet) the scanned end fell short of the
#: toe tip by 1.0 mm on raw scans and clouds (sampling 1.6-1.7 mm), 1.4 on a dense one (2.4),
#: 3.6 on closed meshes of 50-85 k vertices (2.7-3.0), 8.5 on closed meshes of 14-25 k
#: (4.5-6.1; 3-13 case to case) and 11.6 on booth meshes of 10-11 k (6.0-7.2): the toes are
#: thin, a coarse mesh rounds them off by about twice its sampling, more than a mitten's tip
#: (:func:`~core.registration.hand_length.tip_allowance`, 1.2 × the sampling, which the feet
#: used before: closed_lowres twins' closed feet 6-11 mm short of the raw twins')
TOE_TIP_PER_SPACING = 2.2
TOE_TIP_SPACING_OFFSET_M = 0.00125
#: the toe allowance's bounds, metres
TOE_ALLOWANCE_RANGE_M = (0.0005, 0.015)


@dataclass
class FootLength:
    """One foot's length correction: ``side`` ``"L"``/``"R"``; ``fit_m``, ``target_m`` heel →
    toe tip along the foot before and after (metres)."""

    side: str
    fit_m: float
    target_m: float

    def note(self) -> str:
        return (
            f"foot_{self.side} {self.fit_m * 1000:.0f} -> {self.target_m * 1000:.0f} mm "
            "(to the scanned foot's end)"
        )


@dataclass
class FootEnd:
    """Where a scanned foot ends: ``reach_m`` past the fitted heel (Calcaneus_posterior) along
    the foot's horizontal axis (metres), and that unit axis (``axis``, (3,), heel to toe tip of
    the fitted body, y = 0)."""

    reach_m: float
    axis: np.ndarray


def toe_allowance(index: ScanIndex) -> float:
    """Metres the toe tip lies past the scanned foot's end on this scan
    (:data:`TOE_TIP_PER_SPACING`), within :data:`TOE_ALLOWANCE_RANGE_M`."""
    lo, hi = TOE_ALLOWANCE_RANGE_M
    excess = index.resolution_m - TOE_TIP_SPACING_OFFSET_M
    return float(np.clip(TOE_TIP_PER_SPACING * excess, lo, hi))


def _heel_axis(X: np.ndarray, side: str, tpl: Template) -> tuple[np.ndarray, np.ndarray, float]:
    """Heel (3,), unit horizontal foot axis (3,) to the toe tip and the foot's length along
    it (metres) of the body ``X`` (13380, 3), +Y up."""
    L = tpl.landmarks
    heel = X[L[f"Calcaneus_posterior_{side}"]]
    a = X[L[f"Toe_tip_{side}"]] - heel
    a = np.array([a[0], 0.0, a[2]])
    length = float(np.linalg.norm(a))
    return heel, a / max(length, 1e-9), length


def scanned_foot_end(
    index: ScanIndex,
    X: np.ndarray,
    side: str,
    template: Template | None = None,
    body_tree: cKDTree | None = None,
) -> FootEnd | None:
    """Where the scanned foot ``side`` of the body ``X`` (13380, 3) ends along its axis: the
    :data:`END_RANK`-th furthest of the scan points whose nearest vertex of ``X`` lies on that
    foot or shin within :data:`FOOT_POINT_GAP_M`; None with fewer than :data:`MIN_FOOT_POINTS`
    of them. ``body_tree``: a KD-tree of ``X`` already built."""
    tpl = template or load_template()
    heel, a, length = _heel_axis(X, side, tpl)
    if length <= 0:
        return None
    centre = heel + 0.5 * length * a
    ids = np.asarray(
        index.tree.query_ball_point(centre, 0.65 * length + FOOT_POINT_GAP_M, workers=kd_workers()),
        dtype=np.int64,
    )
    if len(ids) < MIN_FOOT_POINTS:
        return None
    P = index.points[ids]
    tree = cKDTree(X) if body_tree is None else body_tree
    d, nearest = tree.query(P, distance_upper_bound=FOOT_POINT_GAP_M, workers=kd_workers())
    near = np.isfinite(d)
    own = tpl.part_mask(f"foot_{side}") | tpl.part_mask(f"shin_{side}")
    keep = near & own[np.where(near, nearest, 0)]
    if keep.sum() < MIN_FOOT_POINTS:
        return None
    t = np.sort((P[keep] - heel) @ a)
    return FootEnd(float(t[-END_RANK]), a)


def scanned_foot_ends(
    index: ScanIndex, X: np.ndarray, template: Template | None = None
) -> dict[str, FootEnd]:
    """Side -> :func:`scanned_foot_end` of both feet of the body ``X`` (13380, 3), where
    measurable."""
    tpl = template or load_template()
    tree = cKDTree(X)
    out = {}
    for side in "LR":
        end = scanned_foot_end(index, X, side, tpl, tree)
        if end is not None:
            out[side] = end
    return out


def correct_foot_lengths(
    index: ScanIndex, X: np.ndarray, allowance_m: float, template: Template | None = None
) -> tuple[np.ndarray, list[FootLength]]:
    """Both feet of the posed body ``X`` (13380, 3), metres, set to their scanned length: the
    forefoot (from :data:`FOREFOOT_FROM` of the foot's length on) stretched along the foot's
    axis so that the toe tip lies ``allowance_m`` past the scanned foot's end
    (:func:`scanned_foot_end`; the toes take no data on coarse scans and the refinement keeps
    what the body prior gave). Corrections under :data:`MIN_FOOT_CORRECTION_M` or outside
    :data:`FOOT_CORRECTION_LIMITS` are not made. Returns the new body and the corrections."""
    tpl = template or load_template()
    out = X.copy()
    made: list[FootLength] = []
    for side, end in scanned_foot_ends(index, X, tpl).items():
        heel, a, length = _heel_axis(X, side, tpl)
        change = end.reach_m + allowance_m - length
        lo, hi = FOOT_CORRECTION_LIMITS
        if abs(change) < MIN_FOOT_CORRECTION_M or not lo * length <= change <= hi * length:
            continue
        ids = np.flatnonzero(tpl.part_mask(f"foot_{side}"))
        t = (X[ids] - heel) @ a / length
        ramp = np.clip((t - FOREFOOT_FROM) / (1.0 - FOREFOOT_FROM), 0.0, None)
        out[ids] += np.outer(change * ramp, a)
        made.append(FootLength(side, length, length + change))
    return out, made


def toe_tip_marker(X: np.ndarray, side: str, end: FootEnd, allowance_m: float) -> np.ndarray:
    """(3,) soft marker of the toe tip ``side``: the fitted body ``X``'s toe tip moved along the
    foot's axis to ``allowance_m`` past the scanned foot's end (the other two coordinates
    stay the fit's: the scan's furthest point need not be the landmark's toe)."""
    tpl = load_template()
    length = _heel_axis(X, side, tpl)[2]
    tip = X[tpl.landmarks[f"Toe_tip_{side}"]]
    return tip + (end.reach_m + allowance_m - length) * end.axis
