"""Checks before a marker fit, on the body prior fitted to the markers: markers placed by another
convention are set aside, and a point cloud's normals that point into the body are turned.

A marker fit trusts the markers to sit on our landmark definitions (``core/assets/landmarks.json``,
CAESAR names). Another team's habit can put every marker 2-5 cm from them, the same way on every
subject (``core.synth.scanner_outputs.other_convention_markers``); the body prior then bends the
body to meet them and the fit's correspondence is worse than without markers (``bench.realworld
--markers``, 40 off-model cases: 17.24 mm mean against 9.11 mm markerless on the same scans).

Such markers are told apart by how far they stay from the body they pulled: after the body prior
(``core.registration.shape_prior``, markers at their robust weights) markers on our definitions
(3 mm noise) sit a median 6.0-14.9 mm from their landmark vertices on 30 off-model bodies (12
heavy, 12 booth meshes with hair and touching arms, 6 T-poses; the worst closed_booth-307, BMI
49) and 3.8-4.4 mm on the prior's own (``bench.matching`` seeds 0-5); another convention's 24-36
mm (``bench.realworld --markers``, all 40). Above :data:`FOREIGN_MEDIAN_M` the scan is fitted
without markers (:func:`core.matching.markerless.fit_markerless`) and the report says so, with
the markers' distances from the landmarks of that fit. The check costs one body prior (0.4-0.9 s
CPU on the held-in cases).

Markers that are ours place the body prior well, so it also tells which of a point cloud's
estimated normals were oriented the wrong way (``core.registration.correspondence.
normals_against_body``; the markerless fit does the same with its first shape-space fit).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from core.matching.markerless import fit_markerless, predicted_landmarks
from core.registration.correspondence import (
    CONFIDENCE_FULL_AT,
    MIN_TURNED_NORMALS,
    turn_normals_against_body,
)
from core.registration.fit import FitResult, Progress, fit, scan_index
from core.registration.schedule import Schedule
from core.scan import Scan
from core.template import load_template

#: Median distance (metres) of the markers from their landmarks on the body prior fitted to them
#: above which they are taken as another convention's: between ours' worst (14.9 mm) and theirs'
#: best (24 mm), see the module docstring.
FOREIGN_MEDIAN_M = 0.020
#: Fewer markers than this are not judged (a median of a few says little): fitted as given.
MIN_JUDGED = 6
#: A point cloud's normals that point into the body prior fitted to markers of ours are turned
#: only where they are at least this share of its points (and :data:`MIN_TURNED_NORMALS`): a
#: limb turned over is 13-19 % (``bench.realworld --wide`` cloud_wide-505/511/517, whose marker
#: fits failed on it); elsewhere 0.4-2.8 % point into it, noisy normals at thin parts that the
#: data term already leaves out (turned, cloud-6 read 7.1 -> 8.0 mm from the truth).
MIN_TURNED_SHARE = 0.05


@dataclass(frozen=True)
class MarkerAgreement:
    """How the markers sit on the body prior fitted to them.

    median_m : median distance (metres) of the used markers from their landmark vertices.
    used : markers the fit used (after screening). foreign : ``median_m`` > the threshold.
    body : (13380, 3) the body prior's posed body, metres, the scan's frame.
    """

    median_m: float
    used: int
    foreign: bool
    body: np.ndarray


def marker_agreement(scan: Scan, markers: dict[str, np.ndarray], **options: Any) -> MarkerAgreement:
    """The body prior alone (no refinement, no quality check) fitted to ``scan`` and ``markers``
    (metres, the scan's frame), and the markers' median distance from their landmarks on it."""
    opts = {k: v for k, v in options.items() if k not in ("schedule", "callback", "retry")}
    res = fit(scan, markers, schedule=Schedule(()), retry=False, assess=False, **opts)
    r = np.array(list(res.report.marker_residuals_m.values()), dtype=np.float64)
    median = float(np.median(r)) if len(r) else float("nan")
    foreign = len(r) >= MIN_JUDGED and median > FOREIGN_MEDIAN_M
    return MarkerAgreement(median, len(r), foreign, res.vertices)


def fit_checking_markers(
    scan: Scan,
    markers: dict[str, np.ndarray],
    *,
    callback: Callable[[Progress], bool | None] | None = None,
    **options: Any,
) -> FitResult:
    """:func:`core.registration.fit.fit` with ``markers``, unless they follow another convention
    (:func:`marker_agreement`): then :func:`core.matching.markerless.fit_markerless` of the same
    scan, its report naming every marker as dropped, with their distances from the fitted body's
    landmarks (``marker_residuals_m``) and a warning. ``scan`` takes the state the kept fit left
    it in (the markerless fit may turn a point cloud's normals). With markers of ours, a point
    cloud's normals that point into the body prior fitted to them are turned first where they
    are a limb's worth (:data:`MIN_TURNED_SHARE`; the report's first note says how many).
    Without the body prior (``shape_prior=False``, the paper's method) the markers are used as
    given."""
    if not options.get("shape_prior", True):
        return fit(scan, markers, callback=callback, **options)
    # one KD-tree for the check and the fit (0.2-0.3 s CPU each on 150 k points)
    ramp = options.get("confidence_full_at", CONFIDENCE_FULL_AT)
    index = scan_index(scan, options.pop("index", None), ramp)
    agree = marker_agreement(scan, markers, index=index, **options)
    if not agree.foreign:
        note = ""
        if scan.F is None:  # a point cloud: normals that point into the markers' body turned
            note = turn_normals_against_body(
                scan, agree.body, load_template().F, "the body prior fitted to the markers",
                min_turned=max(MIN_TURNED_NORMALS, MIN_TURNED_SHARE * len(scan.V)),
            )  # fmt: skip
            if note:  # the index holds the normals: a new one
                index = scan_index(scan, None, ramp)
        res = fit(scan, markers, callback=callback, index=index, **options)
        if note:
            res.report.notes.insert(0, note)
        return res
    view = copy.deepcopy(scan)
    res = fit_markerless(view, callback=callback, **options)
    for f in fields(scan):
        setattr(scan, f.name, getattr(view, f.name))
    marks = predicted_landmarks(res.vertices)
    dist = {
        k: float(np.linalg.norm(np.asarray(p, dtype=np.float64) - marks[k]))
        for k, p in markers.items()
        if k in marks
    }
    rep = res.report
    rep.markers_used, rep.markers_dropped = [], sorted(markers)
    rep.marker_residuals_m, rep.marker_weights = dist, {k: 0.0 for k in dist}
    after = float(np.median(list(dist.values()))) if dist else float("nan")
    rep.warnings.append(
        f"markers not used: on the body fitted to them they lay a median "
        f"{agree.median_m * 1000:.0f} mm from their landmarks (over "
        f"{FOREIGN_MEDIAN_M * 1000:.0f} mm: placed by another convention than ours, "
        f"core/assets/landmarks.json?); the body was fitted without them, and on it they lie a "
        f"median {after * 1000:.0f} mm from our landmarks"
    )
    return res
