"""Marker-only fitting recovers known bodies; bad marker sets get clear errors.

Bounds measured on small simulated cases (seeds 1–4): 62 markers 5.3–6.1 mm mean, p95 13–17 mm;
20 markers 7.5–10.9 mm mean.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.cases import make_case
from core.errors import MarkerError
from core.matching.markers_only import fit_markers_only

TWENTY = [
    "Vertex", "Sellion", "Menton", "Cervicale", "Suprasternale", "Omphalion", "Crotch",
    "Acromion_L", "Acromion_R", "Radiale_L", "Radiale_R", "Radial_styloid_L", "Radial_styloid_R",
    "Patella_L", "Patella_R", "Lateral_malleolus_L", "Lateral_malleolus_R", "Trochanterion_L",
    "Trochanterion_R", "Toe_tip_L",
]  # fmt: skip


@pytest.fixture(scope="module")
def case():
    return make_case(3, small=True)


def test_markers_only_all_landmarks(case):
    res = fit_markers_only(case.markers)
    e = np.linalg.norm(res.vertices - case.truth, axis=1) * 1000
    assert res.vertices.shape == (13380, 3)
    assert e.mean() < 9.0
    assert len(res.report.markers_used) == 62


def test_markers_only_twenty(case):
    res = fit_markers_only({k: case.markers[k] for k in TWENTY})
    e = np.linalg.norm(res.vertices - case.truth, axis=1) * 1000
    assert e.mean() < 14.0


def test_markers_only_more_markers_is_better(case):
    e62 = np.linalg.norm(fit_markers_only(case.markers).vertices - case.truth, axis=1).mean()
    few = {k: case.markers[k] for k in TWENTY[:8]}
    e8 = np.linalg.norm(fit_markers_only(few).vertices - case.truth, axis=1).mean()
    assert e62 < e8


def test_markers_only_errors(case):
    with pytest.raises(MarkerError, match="at least 3"):
        fit_markers_only({k: case.markers[k] for k in TWENTY[:2]})
    with pytest.raises(MarkerError, match="unknown"):
        fit_markers_only({"Elbow_tip": np.zeros(3), **case.markers})
