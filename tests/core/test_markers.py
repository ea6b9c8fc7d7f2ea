"""Markers are evidence: dropped only when both the scan surface and their neighbours contradict
them; a body whose head is flexed ~15 cm from the prior's keeps its head markers and its head."""

from __future__ import annotations

import numpy as np
import pytest

from core.io import detect_frame, prepare_scan
from core.registration.correspondence import ScanIndex
from core.registration.fit import fit
from core.registration.initialization import Similarity
from core.registration.markers import NEIGHBOUR_DISTANCE_M, neighbour_residuals, screen_markers
from core.registration.schedule import Schedule
from core.registration.shape_prior import marker_weights
from core.rig import axis_angle, joint_positions, load_rig, pose_body
from core.scan import RawMesh
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template

# 33 CAESAR markers as another team places them (issue 13)
CAESAR33 = (
    "Vertex", "Sellion", "Tragion_L", "Tragion_R", "Menton", "Cervicale", "Suprasternale",
    "Substernale", "Acromion_L", "Acromion_R", "Radiale_L", "Radiale_R", "Olecranon_L",
    "Olecranon_R", "Radial_styloid_L", "Radial_styloid_R", "Ulnar_styloid_L", "Ulnar_styloid_R",
    "Thelion_L", "Thelion_R", "ASIS_L", "ASIS_R", "PSIS_L", "PSIS_R", "Trochanterion_L",
    "Trochanterion_R", "Femoral_lateral_epicondyle_L", "Femoral_lateral_epicondyle_R",
    "Lateral_malleolus_L", "Lateral_malleolus_R", "Calcaneus_posterior_L",
    "Calcaneus_posterior_R", "Crotch",
)  # fmt: skip
HEAD_MARKERS = ("Sellion", "Tragion_L", "Tragion_R", "Menton", "Vertex")


def _template_landmarks() -> dict[str, np.ndarray]:
    tpl = load_template()
    return {k: tpl.V[i] for k, i in tpl.landmarks.items()}


def test_neighbours_agree_under_a_similarity_and_catch_a_swap():
    tl = _template_landmarks()
    R = axis_angle(np.array([0.0, 1.0, 0.0]), 0.7)
    sim = Similarity(1.07, R, np.array([0.3, 0.0, -1.0]))
    m = {k: sim.apply(tl[k][None])[0] for k in CAESAR33}
    r = neighbour_residuals(tl, m)
    assert max(r.values()) < 1e-6
    m["Tragion_L"], m["Tragion_R"] = m["Tragion_R"], m["Tragion_L"]
    r = neighbour_residuals(tl, m)
    assert r["Tragion_L"] > NEIGHBOUR_DISTANCE_M and r["Tragion_R"] > NEIGHBOUR_DISTANCE_M
    assert r["Sellion"] < 0.03  # one bad neighbour does not condemn the others


def test_annealed_weights_decrease_with_iterations_and_respect_the_floor():
    r = np.array([0.0, 0.05, 0.15, 0.5])
    floor = np.array([0.0, 0.0, 0.5, 0.0])
    w0 = marker_weights(r, 0, 12, 0.3, 0.03, floor)
    w6 = marker_weights(r, 6, 12, 0.3, 0.03, floor)
    assert w0[0] == 1.0 and w0[2] > 0.7  # early on a 15 cm residual still pulls
    assert np.all(w6 <= w0) and w6[3] < 0.01
    assert w6[2] == 0.5  # consistent with its neighbours: keeps half its weight
    assert np.array_equal(w6, marker_weights(r, 11, 12, 0.3, 0.03, floor))


def _head_flexed_case(seed: int, flex_deg: float = 40.0):
    """A body whose neck and head are flexed ``flex_deg`` (+40 %) forward, its simulated scan, and
    33 markers 2-5 cm off our definitions (moved along the skin), canonical frame."""
    rng = np.random.default_rng(seed)
    tpl = load_template()
    V = random_body(rng).V
    rig = load_rig()
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    rot = {
        "neck01": axis_angle(x, np.radians(flex_deg)),
        "head": axis_angle(x, np.radians(0.4 * flex_deg)) @ axis_angle(y, 0.2),
    }
    P = pose_body(V, rot, rig=rig, joints=joint_positions(V, rig=rig))
    P[:, 1] -= P[:, 1].min()
    cfg = ScanConfig(n_views=4, pitch_m=0.005, noise_m=0.001)
    sim = simulate_scan(P, tpl.F, rng, config=cfg, landmarks=tpl.landmarks)
    raw = RawMesh(V=sim.V_scan, F=sim.F_scan, normals=sim.normals, confidence=sim.confidence)
    frame = detect_frame(raw.V, markers=sim.markers)
    scan = prepare_scan(raw, frame)
    truth = frame.to_canonical(sim.V_truth)
    N = tpl.vertex_normals(truth)
    markers = {}
    for k in CAESAR33:
        i = tpl.landmarks[k]
        d = rng.normal(size=3)
        d -= d.dot(N[i]) * N[i]
        p = truth[i] + d / np.linalg.norm(d) * rng.uniform(0.02, 0.05)
        markers[k] = truth[np.argmin(np.linalg.norm(truth - p, axis=1))]
    moved = float(np.linalg.norm(P[tpl.landmarks["Sellion"]] - V[tpl.landmarks["Sellion"]]))
    return scan, markers, truth, moved


@pytest.fixture(scope="module")
def head_case():
    return _head_flexed_case(2)


def test_screening_keeps_markers_on_the_surface_and_drops_only_doubly_wrong_ones(head_case):
    scan, markers, _, _ = head_case
    index = ScanIndex(scan)
    tl = _template_landmarks()
    s = screen_markers(index, tl, markers)
    assert s.dropped == [] and set(s.kept) == set(markers)
    bad = dict(markers)
    bad["Sellion"] = bad["Sellion"] + np.array([0.0, 0.0, 0.15])  # off the face, not a neighbour
    bad["Vertex"] = bad["Vertex"] + np.array([0.0, 0.05, 0.0])  # 5 cm off the skin, still agrees
    s = screen_markers(index, tl, bad)
    assert s.dropped == ["Sellion"]
    assert s.surface_distance["Vertex"] > 0.03 and s.consistent["Vertex"]
    assert "Vertex" in s.kept and any("Vertex" in w and "kept" in w for w in s.warnings)


def test_head_flexed_15_cm_keeps_head_markers_and_head(head_case):
    scan, markers, truth, moved = head_case
    assert moved > 0.12  # the head is far from the prior's posture
    res = fit(scan, markers, schedule=Schedule.fast())
    rep = res.report
    assert not set(HEAD_MARKERS) & set(rep.markers_dropped), rep.markers_dropped
    assert all(rep.marker_weights[k] >= 0.5 for k in HEAD_MARKERS), rep.marker_weights
    q = rep.quality
    head = load_template().part_mask("head")
    err_head = np.linalg.norm(res.vertices[head] - truth[head], axis=1)
    # the head is kept (fit→truth bounded by the 2-5 cm marker convention), or the fit says so
    assert np.percentile(err_head, 95) < 0.06 or (
        q.quality != "good" and any(r.startswith("head") for r in q.reasons)
    )
    assert q.parts["head"].scan_to_fit_p95_m < 0.006, q.reasons


def test_prior_options_mirror_fit_body_prior_defaults():
    import inspect

    from core.registration.shape_prior import PriorOptions, fit_body_prior

    sig = inspect.signature(fit_body_prior).parameters
    for name, value in PriorOptions().kwargs().items():
        assert sig[name].default == value, name
    assert PriorOptions.of({"k_schedule": [5, 10]}).k_schedule == (5, 10)
    with pytest.raises(TypeError, match="iteratons"):
        PriorOptions.of({"iteratons": 3})
    with pytest.raises(AttributeError):
        PriorOptions().iterations = 3  # frozen
