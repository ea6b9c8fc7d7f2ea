"""What is not the body is removed during scan preparation (``core.io.clean``): floor plates,
floor points and stray blobs go; soles, toes and body parts that are separate components stay.

Labels come from the generators' truth (``bench.realworld.non_body_labels``): *body* points lie
within 10 mm of the true body surface and more than 5 mm above its soles (a foot standing on a
floor cannot be told from the floor in its lowest millimetres; those points are judged neither
way); *plate* points lie below the soles' level or more than 20 mm from the body (a plate's top
beside the feet is within 10 mm of them).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bench.cases import make_case as sim_case
from bench.realworld import non_body_labels
from core.io import detect_frame, prepare_scan
from core.io.clean import non_body_points
from core.io.frame import apply_frame
from core.registration.fit import fit
from core.registration.schedule import Schedule
from core.scan import RawMesh
from core.synth.realworld import off_model_body
from core.synth.scanner_outputs import closed_mesh, make_case
from core.template import load_template


def _canonical(case) -> tuple[RawMesh, np.ndarray]:
    frame = detect_frame(case.V)
    return apply_frame(RawMesh(case.V, case.F, case.normals), frame), frame.to_canonical(case.truth)


@pytest.mark.parametrize(("seed", "kind"), [(15, "closed_plate"), (10, "raw_clutter")])
def test_plate_and_clutter_of_real_world_cases_are_removed(seed, kind):
    """closed_plate-15 (cm, Z up): a 10+ mm floor plate under a closed mesh; raw_clutter-10
    (a -Y-up file read +Y up, so the floor ring is at the top): floor ring and 4 blobs."""
    c = make_case(seed, kind)
    m, truth = _canonical(c)
    nb = non_body_points(m.V)
    body, junk = non_body_labels(m.V, truth)
    removed = ~nb.keep
    assert junk.sum() > 3000
    assert removed[junk].mean() >= 0.95, removed[junk].mean()
    assert removed[body].mean() < 0.005, removed[body].mean()
    if kind == "raw_clutter":
        assert nb.floor_end == "top" and nb.stray_clusters == c.params["output"]["blobs"]
        blob = junk & (np.abs(m.V[:, 1] - nb.floor_level_m) > 0.05)  # off the floor ring
        assert nb.stray[blob].mean() >= 0.95
    else:
        assert nb.floor_end == "bottom" and nb.stray.sum() == 0
    # the prepared scan (welded first, and a mesh's vertices left without a triangle go with
    # the floor) says what went
    scan = prepare_scan(RawMesh(c.V, c.F, c.normals), detect_frame(c.V))
    for k, v in nb.counts.items():
        assert v <= scan.removed[k] <= 1.01 * v, (k, scan.removed)
    assert len(scan.V) <= nb.keep.sum()
    assert any("floor points" in n for n in scan.notes)


def _disc_under(case, reach: float = 0.12, thickness: float = 0.01, step: float = 0.008):
    """The simulated scan ``case`` (canonical) as a point cloud standing on a plate: a disc
    ``thickness`` thick, top at the soles, reaching ``reach`` beyond the feet. Returns the
    cloud's points and the plate's mask."""
    frame = detect_frame(case.raw.V, markers=case.raw_markers)
    body = frame.to_canonical(case.raw.V)
    sole = case.truth[:, 1].min()
    feet = case.truth[case.truth[:, 1] < sole + 0.03][:, [0, 2]]
    c = feet.mean(axis=0)
    r = np.linalg.norm(feet - c, axis=1).max() + reach
    g = np.arange(-r, r + step, step)
    X, Z = (a.ravel() for a in np.meshgrid(g, g))
    inside = np.hypot(X, Z) <= r
    top = np.c_[X[inside] + c[0], np.full(inside.sum(), sole), Z[inside] + c[1]]
    bottom = top - [0.0, thickness, 0.0]
    a = np.arange(0.0, 2 * np.pi, step / r)
    rim = [
        np.c_[c[0] + r * np.cos(a), np.full(len(a), sole - t), c[1] + r * np.sin(a)]
        for t in np.arange(step, thickness, step)
    ]
    plate = np.vstack([top, bottom, *rim])
    V = np.vstack([body, plate])
    return V, np.r_[np.zeros(len(body), bool), np.ones(len(plate), bool)]


@pytest.fixture(scope="module")
def small():
    return sim_case(101, small=True)


def test_a_disc_under_a_simulated_body_is_removed_and_reported(small):
    V, plate = _disc_under(small)
    frame = detect_frame(V, units="m", up="+y")
    nb = non_body_points(V)
    body, _ = non_body_labels(V, small.truth)
    body &= ~plate
    assert nb.floor[plate].mean() >= 0.95, nb.floor[plate].mean()
    assert (~nb.keep)[body].mean() < 0.005
    scan = prepare_scan(RawMesh(V, None), frame)  # a point cloud: no connectivity
    assert scan.removed["floor_points"] == nb.floor.sum() and scan.removed["stray_points"] == 0
    # the fit's report says what was removed; its scan→fit figures are over the kept points
    res = fit(scan, small.markers, schedule=Schedule.fast())
    rep = res.report.to_dict()
    assert rep["removed"] == scan.removed and rep["scan_vertices"] == len(scan.V)
    assert any(w.startswith("removed from the scan as not the body") for w in rep["warnings"])
    assert rep["scan_to_fit_p95_m"] < 0.01
    assert "foot" not in " ".join(res.report.quality.reasons)
    from service.cli import summary_lines

    info = {
        "timing_s": {"total": 1.0, "load": 0.1, "fit": 0.8, "write": 0.1},
        "schedule": "fast",
        "frame": {"units": "m", "up": "+y"},
        "inputs": {"scan": "s.ply"},
        "outputs": [],
    }
    text = "\n".join(summary_lines(res, info))
    assert f"{len(scan.V):,} points, 0 triangles (kept; {nb.floor.sum():,} removed as not" in text
    assert "warning: removed from the scan as not the body" in text


def test_flat_cut_soles_without_a_plate_lose_nothing():
    """A closed mesh with flat-cut soles (booth software without a plate): soles, toes and
    feet are the body; nothing is removed. Also the plate-less real-world cases."""
    b = off_model_body(np.random.default_rng(2))
    V, _, info = closed_mesh(b.V, load_template().F, np.random.default_rng(0), voxel_m=0.012)
    assert info["sole_cut_m"] > 0.0
    nb = non_body_points(V)
    assert nb.counts == {"floor_points": 0, "stray_points": 0}
    for seed, kind in [(0, "closed_lowres"), (4, "raw")]:
        m, _ = _canonical(make_case(seed, kind))
        assert non_body_points(m.V).counts == {"floor_points": 0, "stray_points": 0}, kind


def test_a_hand_that_is_a_separate_component_is_kept(small):
    """A raw scan whose right hand is its own component, 1.5 cm of wrist data missing (point
    clouds have no connectivity and raw scans' parts come apart): the hand stays."""
    tpl = load_template()
    V = small.scan.V
    part = tpl.part[cKDTree(small.truth).query(V)[1]]
    hand = part == tpl.part_names.index("hand_R")
    d, _ = cKDTree(V[hand]).query(V)
    keep = hand | (d > 0.015)  # the forearm's points within 1.5 cm of the hand are missing
    F = small.scan.F[keep[small.scan.F].all(axis=1)]
    F = (np.cumsum(keep) - 1)[F]
    m = RawMesh(V[keep], F)
    h = hand[keep]
    assert h.sum() > 100
    nb = non_body_points(m.V)
    assert nb.counts == {"floor_points": 0, "stray_points": 0}
    assert nb.keep[h].all()


def test_a_body_on_a_large_floor_is_cleaned_a_floor_alone_is_left_alone(small):
    """A floor of more points than the body's under it goes; a floor with nothing (or a 30 cm box)
    standing on it is not a scan to clean (``core.matching.body_check`` refuses it): nothing is
    removed."""
    g = np.arange(-1.0, 1.0, 0.01)
    X, Z = (a.ravel() for a in np.meshgrid(g, g))
    sole = small.scan.V[:, 1].min()
    floor = np.c_[X, np.full(len(X), sole - 0.002), Z]
    assert len(floor) > 1.5 * len(small.scan.V)
    nb = non_body_points(np.vstack([small.scan.V, floor]))
    assert nb.floor[len(small.scan.V) :].all()
    body, _ = non_body_labels(small.scan.V, small.truth)
    assert (~nb.keep[: len(small.scan.V)])[body].mean() < 0.005
    assert non_body_points(floor).counts == {"floor_points": 0, "stray_points": 0}
    u = np.linspace(-0.15, 0.15, 31)
    A, B = (a.ravel() for a in np.meshgrid(u, u))
    box = np.vstack([np.c_[A, B + 0.15, np.full_like(A, z)] for z in (-0.15, 0.15)]
                    + [np.c_[np.full_like(A, x), B + 0.15, A] for x in (-0.15, 0.15)]
                    + [np.c_[A, np.full_like(A, 0.3), B]])  # fmt: skip
    box[:, 1] += sole - 0.002  # a 30 cm box on the floor: no body
    assert non_body_points(np.vstack([floor, box])).counts == {"floor_points": 0, "stray_points": 0}
