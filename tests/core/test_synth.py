"""Synthetic bodies and simulated range scans: reproducible, plausible, realistic enough."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from core.synth import ScanConfig, random_body, simulate_scan
from core.synth.bodies import STATURE_RANGE
from core.template import load_template

TPL = load_template()
SMALL = ScanConfig.small()


@pytest.fixture(scope="module")
def body():
    return random_body(np.random.default_rng(7), sex="female")


@pytest.fixture(scope="module")
def scan(body):
    return simulate_scan(body.V, TPL.F, np.random.default_rng(11), config=SMALL)


def test_random_body_is_reproducible():
    a = random_body(np.random.default_rng(3))
    b = random_body(np.random.default_rng(3))
    assert a.sex == b.sex
    np.testing.assert_array_equal(a.V, b.V)
    assert a.V.shape == (13380, 3)
    assert abs(a.V[:, 1].min()) < 1e-9


def test_bodies_vary_in_stature_and_sex():
    st = {"female": [], "male": []}
    for seed in range(6):
        for sex in st:
            b = random_body(np.random.default_rng(seed), sex=sex, pose=False)
            assert b.sex == sex
            assert STATURE_RANGE[0] - 0.01 <= b.stature_m <= STATURE_RANGE[1] + 0.01
            assert b.stature_m == pytest.approx(b.params["stature_m"], abs=0.005)
            st[sex].append(b.stature_m)
    allst = st["female"] + st["male"]
    assert max(allst) - min(allst) > 0.1
    assert np.mean(st["male"]) > np.mean(st["female"])
    f = random_body(np.random.default_rng(0), sex="female", pose=False)
    m = random_body(np.random.default_rng(0), sex="male", pose=False)
    assert np.abs(f.V - m.V).max() > 0.02


def test_scan_is_reproducible(body, scan):
    again = simulate_scan(body.V, TPL.F, np.random.default_rng(11), config=SMALL)
    np.testing.assert_array_equal(scan.V_scan, again.V_scan)
    np.testing.assert_array_equal(scan.F_scan, again.F_scan)
    other = simulate_scan(body.V, TPL.F, np.random.default_rng(12), config=SMALL)
    assert len(other.V_scan) != len(scan.V_scan) or not np.array_equal(other.V_scan, scan.V_scan)


def test_scan_arrays_are_well_formed(scan):
    n = len(scan.V_scan)
    assert 5_000 < n < 100_000
    assert scan.F_scan.min() >= 0 and scan.F_scan.max() < n
    assert np.unique(scan.F_scan).size == n  # no isolated vertices
    assert scan.confidence.shape == (n,)
    assert scan.confidence.min() >= 0 and scan.confidence.max() <= 1
    assert scan.confidence.max() > 0.9
    np.testing.assert_allclose(np.linalg.norm(scan.normals, axis=1), 1.0, atol=1e-9)
    assert np.isfinite(scan.V_scan).all()
    assert scan.V_truth.shape == (13380, 3)


def test_scan_points_lie_on_the_truth_surface(body, scan):
    sigma = SMALL.noise_m
    pick = np.random.default_rng(0).choice(len(scan.V_scan), 3000, replace=False)
    mesh = trimesh.Trimesh(body.V, TPL.F, process=False)
    _, d, _ = trimesh.proximity.closest_point(mesh, scan.V_scan[pick])
    assert np.percentile(d, 99) < 3 * sigma
    assert d.max() < 5 * sigma
    assert np.median(d) < sigma
    # normals face outwards: agree with the truth normals at the nearest vertex
    from core.synth.scanner import vertex_normals

    N = vertex_normals(body.V, TPL.F)
    _, vi = cKDTree(body.V).query(scan.V_scan)
    assert np.median(np.einsum("ij,ij->i", N[vi], scan.normals)) > 0.9


def test_holes_where_no_sensor_sees(body, scan):
    d, _ = cKDTree(scan.V_scan).query(body.V)
    covered = d < 0.01
    assert covered.mean() > 0.8
    soles = body.V[:, 1] < 0.005
    assert covered[soles].mean() < 0.2
    crown = body.V[:, 1] > body.V[:, 1].max() - 0.008
    assert covered[crown].mean() < 0.2
    assert d[TPL.landmarks["Vertex"]] > 0.01
    assert scan.V_scan[:, 1].min() > SMALL.floor_cut_m - 3 * SMALL.noise_m


def test_markers_are_near_their_truth_vertices(body, scan):
    assert set(scan.markers) == set(TPL.landmarks)
    err = np.array([np.linalg.norm(p - body.V[TPL.landmarks[n]]) for n, p in scan.markers.items()])
    assert np.median(err) < 0.008
    assert err.max() < 0.018
    assert err.max() > 0  # noise is applied


@pytest.mark.parametrize(("units", "up"), [("mm", "+y"), ("m", "+z"), ("mm", "+z")])
def test_units_and_axes(body, units, up):
    cfg = ScanConfig.small(units=units, up=up, n_dropouts=(0, 0))
    sc = simulate_scan(body.V, TPL.F, np.random.default_rng(11), config=cfg)
    ref = simulate_scan(
        body.V, TPL.F, np.random.default_rng(11), config=ScanConfig.small(n_dropouts=(0, 0))
    )
    s = 1000.0 if units == "mm" else 1.0
    upi = 1 if up == "+y" else 2
    extent = np.ptp(sc.V_truth, axis=0)
    assert extent[upi] == pytest.approx(s * body.stature_m, rel=1e-9)
    assert sc.V_truth[:, upi].min() == pytest.approx(0.0, abs=1e-9)
    A = sc.meta["to_file"]
    np.testing.assert_allclose(sc.V_truth, body.V @ A[:3, :3].T + A[:3, 3], atol=1e-9)
    np.testing.assert_allclose(sc.V_scan, ref.V_scan @ A[:3, :3].T + A[:3, 3], atol=1e-9 * s)
    assert np.linalg.det(A[:3, :3]) > 0  # right-handed
    # the nose points to the front: +Z for +y up, -Y for +z up
    nose = sc.V_truth[TPL.landmarks["Pronasale"]] - sc.V_truth[TPL.landmarks["Opisthocranion"]]
    assert (nose[2] > 0) if up == "+y" else (nose[1] < 0)


def test_random_frame_is_rigid_and_keeps_up(body):
    cfg = ScanConfig.small(random_frame=True, units="mm")
    sc = simulate_scan(body.V, TPL.F, np.random.default_rng(5), config=cfg)
    R = sc.meta["to_file"][:3, :3] / 1000.0
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R[1], [0, 1, 0], atol=1e-12)  # rotation about vertical only
    d0 = np.linalg.norm(body.V[100] - body.V[9000])
    d1 = np.linalg.norm(sc.V_truth[100] - sc.V_truth[9000])
    assert d1 == pytest.approx(1000 * d0)
    mk = sc.markers["Vertex"]
    assert np.linalg.norm(mk - sc.V_truth[TPL.landmarks["Vertex"]]) < 18.0


def test_bad_config_is_rejected():
    with pytest.raises(ValueError, match="units"):
        ScanConfig(units="cm")
    with pytest.raises(ValueError, match="up"):
        ScanConfig(up="-x")
    with pytest.raises(ValueError, match="shape"):
        simulate_scan(np.zeros((5, 2)), TPL.F, np.random.default_rng(0))


def test_pose_is_small_and_keeps_the_surface_intact():
    posed = random_body(np.random.default_rng(4))
    rest = random_body(np.random.default_rng(4), pose=False)
    if not posed.params.get("pose_deg"):
        pytest.skip("core.rig not available")
    assert np.abs(posed.V - rest.V).max() > 0.01  # the pose moved something
    assert abs(posed.V[:, 1].min()) < 1e-9
    E = np.concatenate([TPL.F[:, [0, 1]], TPL.F[:, [1, 2]], TPL.F[:, [2, 0]]])
    ratio = np.linalg.norm(np.diff(posed.V[E], axis=1), axis=2) / np.linalg.norm(
        np.diff(rest.V[E], axis=1), axis=2
    )
    assert np.percentile(ratio, 99.9) < 1.3 and np.percentile(ratio, 0.1) > 0.7
