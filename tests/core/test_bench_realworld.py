"""bench.realworld's measurements: area sampling and the surface metrics on known geometry."""

from __future__ import annotations

import numpy as np

from bench.realworld import area_samples, surface_metrics
from core.scan import Scan
from core.template import load_template


def test_area_samples_follow_area():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [3, 0, 0], [0, 1, 0.0]])
    V[3:, 2] = 1.0  # second triangle (area 1.5) on z = 1, first (0.5) on z = 0
    F = np.array([[0, 1, 2], [3, 4, 5]])
    P = area_samples(V, F, 20_000)
    assert abs(np.mean(P[:, 2] > 0.5) - 0.75) < 0.02


def test_surface_metrics_zero_on_itself_and_shift_seen():
    tpl = load_template()
    F = np.asarray(tpl.F, np.int64)
    V = np.asarray(tpl.V, float)
    N = tpl.vertex_normals()
    scan = Scan(V=V, F=F, normals=N, confidence=np.ones(len(V)), boundary=np.zeros(len(V), bool))
    m = surface_metrics(scan, V, F)
    assert m["scan_to_fit_p95_mm"] < 1e-6 and m["fit_to_scan_mean_mm"] < 0.01  # MeshDistance: k=4
    moved = Scan(
        V=V + N * 0.004, F=F, normals=N, confidence=scan.confidence, boundary=scan.boundary
    )
    m = surface_metrics(moved, V, F)
    assert 3.0 < m["scan_to_fit_median_mm"] <= 4.01
    assert 2.5 < m["fit_to_scan_mean_mm"] <= 4.01
    assert m["part_scan_to_fit_p95_mm"]["head"] <= 4.01
