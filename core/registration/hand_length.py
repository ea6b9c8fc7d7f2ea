"""Hand length of the body prior: from the scanned hand where it is free, else a human's.

The template's fingers take no data (they scan badly: fused into mittens, bent, lost in holes),
so the body prior's hand length comes from its shape coefficients alone. On bodies off the
prior's space that is often wrong: on closed booth meshes the fitted hands were 4-19 % longer
than the truth (styloids → middle fingertip 0.117-0.128 of the stature, truth 0.108-0.115),
their fingertips 25-50 mm past the scanned mitten. The refinement keeps what the prior gave
(no data there), so the length is set here, on the prior's posed body, by a scale of the hand
about the wrist:

- a hand clear of the body (:func:`core.registration.quality.hand_body_gaps` above
  :data:`FREE_HAND_GAP_M`): the middle fingertip goes :func:`tip_allowance` past the scan's
  hand end along the hand's axis (:func:`scanned_hand_end`);
- a hand at the body (its end fused with the thigh or hip in a closed mesh, not measurable):
  its length is held in ANSUR II's band of hand length / stature (:data:`HAND_STATURE_BAND`).

A scale outside :data:`HAND_SCALE_LIMITS` is not applied (a fist, or a hand the prior put
elsewhere: the scan does not measure its length then), nor is a fitted fist's length changed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.registration.correspondence import ScanIndex
from core.registration.quality import hand_body_gaps
from core.template import Template, load_template
from core.threads import kd_workers

#: ANSUR II (development split, 1361 women and 2852 men) hand length / stature, 16th and 84th
#: percentiles over both sexes (mean 0.1104, sd 0.0044); hand length as ANSUR measures it: wrist
#: (stylion) to the tip of the middle finger. A hand at the body is held within this band (one
#: sd about the mean, not the 5-95 % band: there the prior's hands were 4-19 % long, and a
#: band edge at 0.1195 left closed_booth-307's 0.131 at 201 mm for a 185 mm hand).
HAND_STATURE_BAND = (0.1062, 0.1147)
#: hand_body_gap_m (metres) above which the hand's end is measured on the scan
FREE_HAND_GAP_M = 0.02
#: a hand is scaled only by a factor in this range (outside: a fist or a misplaced hand). An open
#: template hand over a scanned fist would need 0.60-0.66 (the truths of ``bench.realworld``'s
#: fists end 28-48 mm past a fist's own wrist → fingertip length, 71-105 mm, of open hands'
#: 164-215 mm); closed booth meshes' open hands fitted 1.17-1.19× long needed 0.77-0.8
HAND_SCALE_LIMITS = (0.75, 1.10)
#: the middle fingertip lies this many times the scan's detail (``ScanIndex.resolution_m``: its
#: sampling, but at most 3 mm on a decimated mesh) past
#: the scanned hand's end (:func:`tip_allowance`). On the truths of ``bench.realworld``'s open
#: hands clear of the body (diagnostic script, 39 hands) the scanned end fell short of the
#: fingertip by 2.1 mm on raw scans (sampling 1.7 mm), 1.9 on dense ones (2.4), 7.0 on closed
#: meshes of 14-20 k vertices (4.9-5.8) and 8.6 on booth meshes of 10-15 k (6.0-7.3): a coarse
#: mesh's smoothing rounds the mitten's tip off. Closed meshes of 60-100 k vertices (2.9):
#: -1.0 (their tips not rounded). It was 5 mm whatever the scan.
TIP_PER_SPACING = 1.2
#: the allowance's bounds, metres
TIP_ALLOWANCE_RANGE_M = (0.002, 0.010)
#: corrections of less than this (metres at the fingertip) are not made. It was 6 mm; from 2 mm
#: (as the feet's, ``foot_end.MIN_FOOT_CORRECTION_M``) the twin diagnostic of
#: ``bench.realworld``'s 8 closed_lowres/raw pairs read correspondence closed / raw 6.63 / 5.82
#: -> 6.63 / 5.73 mm (twins 3.63 both).
MIN_CORRECTION_M = 0.002
#: the scale ramps in over this distance past the wrist (metres): the wrist ring stays put
RAMP_M = 0.02
#: the scan's hand end is the n-th furthest hand point along the axis (not a lone outlier)
END_RANK = 5
#: fewest scan points a measured hand needs
MIN_HAND_POINTS = 20


@dataclass
class HandLength:
    """One hand's length correction.

    side : ``"L"`` or ``"R"``. source : ``"scan"`` (the scanned hand's end) or ``"stature"``
    (the ANSUR band). fit_m, target_m : wrist →
    middle fingertip before and after, metres. scale : the factor applied about the wrist.
    """

    side: str
    source: str
    fit_m: float
    target_m: float
    scale: float

    def note(self) -> str:
        how = {"scan": "to the scanned hand's end", "stature": "into ANSUR II's band"}[self.source]
        return (
            f"hand_{self.side} {self.fit_m * 1000:.0f} -> {self.target_m * 1000:.0f} mm "
            f"(×{self.scale:.2f}, {how})"
        )


def _wrist_axis(X: np.ndarray, side: str, tpl: Template) -> tuple[np.ndarray, np.ndarray, float]:
    """Wrist (3,) (the styloids' midpoint), unit hand axis (3,) to the middle fingertip and the
    hand's length (metres) of the body ``X`` (13380, 3)."""
    L = tpl.landmarks
    wrist = (X[L[f"Radial_styloid_{side}"]] + X[L[f"Ulnar_styloid_{side}"]]) / 2
    a = X[L[f"Dactylion_{side}"]] - wrist
    length = float(np.linalg.norm(a))
    return wrist, a / max(length, 1e-9), length


def tip_allowance(index: ScanIndex) -> float:
    """Metres the middle fingertip lies past the scanned hand's end on this scan:
    :data:`TIP_PER_SPACING` times its detail (``ScanIndex.resolution_m``), within
    :data:`TIP_ALLOWANCE_RANGE_M`."""
    lo, hi = TIP_ALLOWANCE_RANGE_M
    return float(np.clip(TIP_PER_SPACING * index.resolution_m, lo, hi))


@dataclass
class HandEnd:
    """Where a scanned hand ends: ``reach_m`` past the wrist along the hand's axis (metres),
    the scan point there (``point``, (3,), scan frame), the hand's unit axis (``axis``, (3,),
    wrist to middle fingertip of the fitted body) and its wrist (``wrist``, (3,), the styloids'
    midpoint)."""

    reach_m: float
    point: np.ndarray
    axis: np.ndarray
    wrist: np.ndarray

    def fingertip(self, allowance_m: float, on_axis: bool = False) -> np.ndarray:
        """(3,) where the middle fingertip lies: ``allowance_m`` past the scanned end along the
        hand's axis, from the end's scan point, or (``on_axis``) on the axis itself at that
        reach. A closed mesh's fused mitten ends in a tip rounded over all four fingers, its
        furthest points off the middle finger's line: a landmark there turned the hand (on
        ``bench.realworld --filled``, closed_filled-904's right hand 5° and 8 mm back)."""
        if on_axis:
            return self.wrist + (self.reach_m + allowance_m) * self.axis
        return self.point + allowance_m * self.axis


def _scanned_hand_points(
    index: ScanIndex, X: np.ndarray, side: str, tpl: Template
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The scan's points of hand ``side`` of the body ``X`` (13380, 3): scan points past the
    wrist within the hand's radius of its axis (plus 1 cm) whose nearest vertex of ``X`` is on
    this hand or forearm (a thigh next to the hand is not the hand). Returns their ids (p,),
    distances along the hand's axis past the wrist (p,), offsets from the axis (p, 3) and the
    fitted hand's length (metres)."""
    wrist, a, length = _wrist_axis(X, side, tpl)
    hand = tpl.part_mask(f"hand_{side}")
    rel = X[hand] - wrist
    radius = float(np.linalg.norm(rel - np.outer(rel @ a, a), axis=1).max()) + 0.01
    reach = 0.5 * length * HAND_SCALE_LIMITS[1] + 0.02
    ids = np.asarray(
        index.tree.query_ball_point(wrist + a * reach, reach + radius, workers=kd_workers()),
        dtype=np.int64,
    )
    t = (index.points[ids] - wrist) @ a
    off = (index.points[ids] - wrist) - np.outer(t, a)
    keep = (t > 0) & (np.linalg.norm(off, axis=1) < radius)
    own = hand | tpl.part_mask(f"forearm_{side}")
    _, nearest = cKDTree(X).query(index.points[ids[keep]], workers=kd_workers())
    keep[keep] = own[nearest]
    return ids[keep], t[keep], off[keep], length


def scanned_hand_end(
    index: ScanIndex, X: np.ndarray, side: str, template: Template | None = None
) -> HandEnd | None:
    """Where the scanned hand of the body ``X`` (13380, 3) ends along its hand's axis: the
    :data:`END_RANK`-th furthest of the hand's scan points (:func:`_scanned_hand_points`); None
    when the scan holds fewer than :data:`MIN_HAND_POINTS` of them."""
    tpl = template or load_template()
    ids, t, _, _ = _scanned_hand_points(index, X, side, tpl)
    if len(ids) < MIN_HAND_POINTS:
        return None
    k = np.argsort(t)[-END_RANK]
    wrist, axis, _ = _wrist_axis(X, side, tpl)
    return HandEnd(float(t[k]), index.points[ids[k]].copy(), axis, wrist)


#: share of the fitted hand's length (from the wrist) whose scan points make the hand's
#: section for :func:`scanned_hand_roundness`: the palm of an open hand, the body of a fist
SECTION_SHARE = (0.1, 0.5)


def scanned_hand_roundness(
    index: ScanIndex, X: np.ndarray, side: str, template: Template | None = None
) -> float | None:
    """How round the scanned hand of the body ``X`` (13380, 3) is across its axis: the square
    root of the ratio of the second to the first principal variance of its scan points'
    offsets from the axis, over :data:`SECTION_SHARE` of the hand. A flat open palm reads
    0.24-0.45 on raw scans and 0.46-0.61 as a closed mesh's mitten; a fist 0.60-0.82
    (``bench.realworld``'s varied, heavy and booth sets). None with fewer than
    :data:`MIN_HAND_POINTS` points there."""
    _, t, off, length = _scanned_hand_points(index, X, side, template or load_template())
    sel = (t > SECTION_SHARE[0] * length) & (t < SECTION_SHARE[1] * length)
    if sel.sum() < MIN_HAND_POINTS:
        return None
    ev = np.linalg.eigvalsh(np.cov(off[sel].T))  # ascending; the smallest ~0 (across the axis)
    return float(np.sqrt(ev[1] / max(ev[2], 1e-12)))


def free_hand_ends(
    index: ScanIndex,
    X: np.ndarray,
    skip: str = "",
    template: Template | None = None,
    gaps: dict[str, float] | None = None,
) -> dict[str, HandEnd]:
    """Side -> :func:`scanned_hand_end` of the hands of the body ``X`` (13380, 3) clear of it
    (:func:`core.registration.quality.hand_body_gaps` above :data:`FREE_HAND_GAP_M`; ``gaps``
    when already computed) and measurable; sides in ``skip`` left out."""
    tpl = template or load_template()
    gaps = hand_body_gaps(X, tpl) if gaps is None else gaps
    out = {}
    for side in "LR":
        if side in skip or gaps[side] <= FREE_HAND_GAP_M:
            continue
        end = scanned_hand_end(index, X, side, tpl)
        if end is not None:
            out[side] = end
    return out


def correct_hand_lengths(
    index: ScanIndex,
    X: np.ndarray,
    stature_m: float,
    fists: str = "",
    template: Template | None = None,
) -> tuple[np.ndarray, list[HandLength]]:
    """Both hands of the posed body ``X`` (13380, 3), metres, set to their length (module
    docstring); ``stature_m`` the body's stature; ``fists`` the sides fitted as fists (left
    alone). Returns the new body and the corrections made (a hand left alone is not listed)."""
    tpl = template or load_template()
    gaps = hand_body_gaps(X, tpl)
    ends = free_hand_ends(index, X, fists, tpl, gaps=gaps)
    out = X.copy()
    made: list[HandLength] = []
    lo, hi = HAND_STATURE_BAND
    for side in (x for x in "LR" if x not in fists):
        wrist, a, length = _wrist_axis(X, side, tpl)
        if gaps[side] > FREE_HAND_GAP_M:
            end = ends.get(side)
            source = "scan" if end is not None else ""
            target = end.reach_m + tip_allowance(index) if end is not None else length
        else:
            source, target = "stature", float(np.clip(length, lo * stature_m, hi * stature_m))
        scale = target / max(length, 1e-9)
        limits_ok = HAND_SCALE_LIMITS[0] <= scale <= HAND_SCALE_LIMITS[1]
        if not source or abs(target - length) < MIN_CORRECTION_M or not limits_ok:
            continue
        ids = np.flatnonzero(tpl.part_mask(f"hand_{side}") | tpl.part_mask(f"forearm_{side}"))
        rel = out[ids] - wrist
        ramp = np.clip((rel @ a) / RAMP_M, 0.0, 1.0)  # 0 at and before the wrist
        out[ids] = wrist + rel * (1.0 + (scale - 1.0) * ramp)[:, None]
        made.append(HandLength(side, source, length, target, scale))
    return out, made
