"""Scan preparation: frame mapping, cleaning, normals, boundary and confidence."""

from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh

from bench.machine import reference_cpu
from core.errors import UnitsError
from core.io._geometry import edge_use_counts
from core.io.frame import detect_frame, rotation_for_up
from core.io.markers import write_markers_csv
from core.io.prepare import load_scan, prepare_scan
from core.io.writers import write_ply
from core.scan import RawMesh
from core.template import load_template

#: Preparation of the 300 k-vertex mesh over :func:`bench.machine.reference_cpu`, bound (was an
#: absolute 1 s, which CI failed once at 1.006 s when the machine had slowed ~2x). Read 3.1-3.3x
#: on the idle development machine (0.60-0.62 s against 0.18-0.20 s): the bound is ~1 s there.
PREPARE_OVER_REFERENCE = 5.0

TPL = load_template()
V0 = np.array(TPL.V)
F0 = np.array(TPL.F, dtype=np.int64)
GT_N = trimesh.Trimesh(V0, F0, process=False).vertex_normals


def prep(raw):
    return prepare_scan(raw, detect_frame(raw.V))


def test_load_scan_mm_zup_with_markers(tmp_path):
    R = rotation_for_up("+z")
    Vf = (V0 @ R) * 1000.0  # millimetres, Z up
    write_ply(tmp_path / "scan.ply", Vf, F0)
    names = ["Vertex", "Sellion", "Toe_tip_L", "Calcaneus_posterior_R", "Crotch"]
    write_markers_csv(tmp_path / "m.csv", {k: Vf[TPL.landmarks[k]] for k in names})
    scan, marks = load_scan(tmp_path / "scan.ply", markers_path=tmp_path / "m.csv")
    assert scan.frame.units == "mm" and scan.frame.up == "+z"
    np.testing.assert_allclose(scan.V, V0, atol=1e-9)
    np.testing.assert_array_equal(scan.F, F0)
    for k in names:
        np.testing.assert_allclose(marks[k], V0[TPL.landmarks[k]], atol=1e-9)
    assert scan.notes[0].startswith("units mm (detected), up axis +z (detected)")
    assert "confidence estimated" in scan.notes
    # explicit options give the same result
    scan2, none = load_scan(tmp_path / "scan.ply", units="mm", up="+z")
    assert none is None and "given" in scan2.notes[0]
    np.testing.assert_allclose(scan2.V, scan.V)


def test_unreferenced_vertices_do_not_decide_the_frame(tmp_path):
    """An exporter's leftover vertices (no triangle uses them) spread 3x the body's size around
    it: the units and up axis are still the body's, and the leftovers are dropped and said."""
    R = rotation_for_up("+z")
    Vf = (V0 @ R) * 1000.0  # millimetres, Z up
    rng = np.random.default_rng(0)
    lo, hi = Vf.min(0), Vf.max(0)
    junk = lo - (hi - lo) + 3 * (hi - lo) * rng.random((5000, 3))
    write_ply(tmp_path / "scan.ply", np.vstack([junk, Vf]), F0 + len(junk))
    with pytest.raises(UnitsError, match="cannot tell the units"):  # the junk would decide
        detect_frame(np.vstack([junk, Vf]))
    scan, _ = load_scan(tmp_path / "scan.ply")
    assert scan.frame.units == "mm" and scan.frame.up == "+z"
    np.testing.assert_allclose(scan.V, V0, atol=1e-9)
    assert "dropped 5,000 vertices not used by any triangle" in scan.notes
    V, F = RawMesh(V=np.vstack([junk, Vf]), F=F0 + len(junk)).surface()
    np.testing.assert_array_equal(V, Vf)
    np.testing.assert_array_equal(F, F0)


def test_mesh_normals_outward_and_inward_winding_flipped():
    s = prep(RawMesh(V=V0, F=F0))
    assert np.mean(np.sum(s.normals * GT_N, axis=1) > 0.9) > 0.99
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0)
    assert not s.boundary.any()  # the template is closed
    assert np.all(s.confidence == 1.0)
    inward = prep(RawMesh(V=V0, F=F0[:, ::-1]))
    assert any("flipped" in n for n in inward.notes)
    np.testing.assert_allclose(inward.normals, s.normals, atol=1e-12)


def test_file_normals_inward_flipped_and_file_confidence_kept():
    c = np.full(len(V0), 0.7)
    s = prep(RawMesh(V=V0, F=F0, normals=-GT_N, confidence=c))
    assert "normals from file" in s.notes and "confidence from file" in s.notes
    assert any("pointed inward" in n for n in s.notes)
    np.testing.assert_allclose(s.normals, GT_N, atol=1e-9)
    assert np.all(s.confidence == 0.7)


def hole_mesh(center_vertex: int, radius: float):
    """The template with the triangles within ``radius`` of a vertex removed."""
    c = V0[center_vertex]
    far = np.linalg.norm(V0[F0].mean(axis=1) - c, axis=1) > radius
    return F0[far]


def test_mesh_hole_boundary_and_confidence_ramp():
    vi = TPL.landmarks["Omphalion"]
    F = hole_mesh(vi, 0.04)
    s = prep(RawMesh(V=V0, F=F))
    # the unreferenced vertices inside the hole are dropped
    assert len(s.V) < len(V0) and any("not used" in n for n in s.notes)
    assert s.boundary.any()
    d = np.linalg.norm(s.V - V0[vi], axis=1)
    assert np.all(d[s.boundary] < 0.06) and np.all(d[s.boundary] > 0.03)
    assert np.all(s.confidence[s.boundary] == pytest.approx(0.2))
    far = d > 0.2
    assert np.all(s.confidence[far] == 1.0)
    near = (~s.boundary) & (d < 0.05)
    assert np.mean(s.confidence[near]) < 1.0
    assert s.confidence.min() >= 0.2 and s.confidence.max() <= 1.0


def test_non_manifold_rim_is_boundary_and_duplicates_welded():
    # split the mesh: every triangle gets its own three vertices (like an STL or UV seams)
    Vs = V0[F0].reshape(-1, 3)
    Fs = np.arange(len(Vs)).reshape(-1, 3)
    s = prep(RawMesh(V=Vs, F=Fs))
    assert len(s.V) == len(V0) and not s.boundary.any()
    assert any("welded" in n for n in s.notes)
    # a fin: an extra triangle on an existing edge makes that edge non-manifold
    e0, e1 = F0[0, 0], F0[0, 1]
    V2 = np.vstack([V0, V0[e0] + [0, 0, 0.01]])
    F2 = np.vstack([F0, [e0, e1, len(V0)]])
    s2 = prep(RawMesh(V=V2, F=F2))
    assert s2.boundary[e0] and s2.boundary[e1]


def test_degenerate_and_duplicate_triangles_dropped():
    F = np.vstack([F0, F0[:5], [[0, 0, 1]]])
    s = prep(RawMesh(V=V0, F=F))
    assert len(s.F) == len(F0)
    assert any("degenerate" in n for n in s.notes) and any("duplicate" in n for n in s.notes)


@pytest.fixture(scope="module")
def cloud():
    m = trimesh.Trimesh(V0, F0, process=False)
    P, fi = trimesh.sample.sample_surface(m, 30000, seed=1)
    return np.asarray(P), m.face_normals[fi]


def test_point_cloud_normals_oriented_outward(cloud):
    P, gt = cloud
    s = prep(RawMesh(V=P * 1000.0))  # millimetres
    assert s.F is None and s.frame.units == "mm"
    agree = np.sum(s.normals * gt, axis=1)
    assert np.mean(agree > 0) > 0.95
    assert np.median(agree) > 0.95
    assert s.boundary.mean() < 0.05  # a closed surface has (almost) no boundary
    assert "normals estimated (PCA)" in s.notes and "confidence estimated" in s.notes


def test_point_cloud_hole_boundary_and_lower_confidence(cloud):
    P, _ = cloud
    c = V0[TPL.landmarks["Omphalion"]]
    d = np.linalg.norm(P - c, axis=1)
    s = prep(RawMesh(V=P[d > 0.05]))
    d = np.linalg.norm(s.V - c, axis=1)
    rim = d < 0.06
    assert s.boundary[rim].mean() > 0.3
    assert s.boundary[rim].mean() > 10 * s.boundary[d > 0.15].mean()
    assert s.confidence[rim].mean() < 0.6 < s.confidence[d > 0.15].mean()


def test_far_stray_points_are_removed_and_counted(cloud):
    P, _ = cloud
    stray = np.array([[0.0, 3.0, 0.0], [1.5, 1.0, 1.5]])
    s = prep(RawMesh(V=np.vstack([P, stray])))
    assert s.removed == {"floor_points": 0, "stray_points": 2}
    assert len(s.V) == len(P) and np.abs(s.V[:, 1]).max() < 2.5
    assert any("removed 2 stray points" in n for n in s.notes)


def test_isolated_fragments_near_the_body_are_kept_with_low_confidence():
    """A scanner fragment (a lone triangle 1 cm off the belly) is no stray blob: kept, at the
    isolated points' confidence."""
    p = V0[TPL.landmarks["Omphalion"]] + [0.0, 0.0, 0.01]
    tri = p + np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.0], [0.0, 0.004, 0.0]])
    n = len(V0)
    s = prep(RawMesh(V=np.vstack([V0, tri]), F=np.vstack([F0, [[n, n + 1, n + 2]]])))
    assert s.removed == {"floor_points": 0, "stray_points": 0}
    assert np.all(s.confidence[-3:] == pytest.approx(0.2))


def test_prepare_300k_mesh_in_bounded_cpu_time():
    V, F = trimesh.remesh.subdivide(V0, F0)
    V, F = trimesh.remesh.subdivide(V, F)
    shift = np.array([0.0, 0.0, 2.0])
    V = np.vstack([V, V[: 300_000 - len(V)] + shift])  # pad to 300k vertices
    F = np.vstack([F, F[F.max(axis=1) < 300_000 - 214_050] + 214_050])
    raw = RawMesh(V=V * 1000.0, F=F)
    frame = detect_frame(raw.V, units="mm", up="+y")
    best = min(_timed(raw, frame) for _ in range(3))  # best of 3: CPU time still varies under load
    ref = reference_cpu()
    assert best / ref < PREPARE_OVER_REFERENCE, (
        f"preparing 300 k vertices took {best:.2f} s CPU, {best / ref:.1f}x the reference "
        f"workload's {ref:.2f} s (bound {PREPARE_OVER_REFERENCE}x)"
    )


def _timed(raw, frame):
    """CPU seconds (all threads) of one preparation: wall time fails under a loaded machine."""
    t0 = time.process_time()
    prepare_scan(raw, frame)
    return time.process_time() - t0


def _arm_faces(V, F, beyond=0.3):
    """Triangles of the arms (beyond the shoulders) of a template-like body."""
    x = V[F].mean(axis=1)[:, 0]
    return np.abs(x - np.median(V[:, 0])) > beyond


def test_inconsistent_winding_within_a_component_repaired():
    F = F0.copy()
    arms = _arm_faces(V0, F0)
    F[arms] = F[arms][:, ::-1]  # both arms wound inward, same connected mesh
    s = prep(RawMesh(V=V0, F=F))
    assert any("winding made consistent in 1 of 1 components" in n for n in s.notes), s.notes
    assert np.mean(np.sum(s.normals * GT_N, axis=1) > 0.9) > 0.99


def test_components_wound_inward_repaired_per_component():
    arms = _arm_faces(V0, F0)
    # split the arms off: their own vertices (open tubes), then wind them inward
    Fa = F0[arms]
    used = np.unique(Fa)
    Va = V0[used] + [0.0, 0.0, 1e-6]  # not welded back to the body
    Fa = np.searchsorted(used, Fa)
    V = np.vstack([V0, Va])
    F_out = np.vstack([F0[~arms], Fa + len(V0)])
    F_in = np.vstack([F0[~arms], Fa[:, ::-1] + len(V0)])
    ok, bad = prep(RawMesh(V=V, F=F_out)), prep(RawMesh(V=V, F=F_in))
    assert not any("inward" in n for n in ok.notes), ok.notes
    assert any("normals of 2 of 3 components pointed inward" in n for n in bad.notes), bad.notes
    np.testing.assert_allclose(bad.normals, ok.normals, atol=1e-12)


def _split_arms(V, F, beyond=0.3):
    """The body with its arms as separate components (own vertices, not welded back)."""
    arms = _arm_faces(V, F, beyond)
    Fa = F[arms]
    used = np.unique(Fa)
    V2 = np.vstack([V, V[used] + [0.0, 0.0, 1e-6]])
    return V2, F[~arms], np.searchsorted(used, Fa) + len(V)


def test_scan_with_components_wound_inward_fits_as_its_repaired_twin():
    from core.matching.markerless import fit_markerless
    from core.synth import random_body

    body = random_body(np.random.default_rng(7))
    V, F_body, F_arms = _split_arms(body.V, F0)
    mm = V * 1000.0  # as a scanner's software writes it: millimetres
    twin = prep(RawMesh(V=mm, F=np.vstack([F_body, F_arms])))
    raw = prep(RawMesh(V=mm, F=np.vstack([F_body, F_arms[:, ::-1]])))  # both arms inward
    assert any("normals of 2 of 3 components pointed inward" in n for n in raw.notes), raw.notes
    np.testing.assert_allclose(raw.normals, twin.normals, atol=1e-12)
    errs = []
    for scan in (raw, twin):
        res = fit_markerless(scan, refine=False)
        errs.append(np.linalg.norm(res.vertices - body.V, axis=1).mean() * 1000)
    assert errs[1] < 25.0 and abs(errs[0] - errs[1]) < 0.5, errs  # measured 17.4 (unrefined)


def test_mixed_winding_in_a_raw_multiview_scan_repaired():
    from bench.cases import make_case

    c = make_case(105, small=True)
    frame = detect_frame(c.raw.V, markers=c.raw_markers)
    F = np.array(c.raw.F, dtype=np.int64)
    x = frame.to_canonical(c.raw.V)[F].mean(axis=1)[:, 0]
    arms = np.abs(x - np.median(x)) > 0.22
    F[arms] = F[arms][:, ::-1]  # every triangle of both arms wound inward, inside view patches
    flipped = prepare_scan(RawMesh(V=c.raw.V, F=F), frame)
    assert any("winding made consistent" in n for n in flipped.notes), flipped.notes
    agree = np.sum(flipped.normals * c.scan.normals, axis=1) > 0.9
    # measured 0.987: small fragments made only of arm triangles keep their (inward) side
    assert np.mean(agree) > 0.98


def test_dense_scan_decimated_on_a_voxel_grid():
    """A dense scan (the template subdivided twice, ~4x4 the vertices) is vertex-clustered on
    the 4 mm grid before preparation: far fewer vertices, the same surface, borders only where
    the surface is open, outward normals, and the notes say so."""
    from core.io.prepare import DECIMATE_VOXEL_M, decimate_voxel_grid

    V, F = trimesh.remesh.subdivide(V0, F0)
    V, F = trimesh.remesh.subdivide(V, F)
    raw = RawMesh(V=V, F=F)
    dense = prepare_scan(raw, detect_frame(V), decimate_above=len(V) + 1)
    s = prepare_scan(raw, detect_frame(V), decimate_above=100_000)
    assert any("decimated" in n and f"{len(V):,}" in n for n in s.notes)
    assert len(s.V) < len(V) / 3
    # every decimated vertex lies on the dense surface (cluster means: within a voxel)
    from scipy.spatial import cKDTree

    d, near = cKDTree(V).query(s.V)
    assert d.max() < DECIMATE_VOXEL_M * np.sqrt(3)
    # the template is closed but for its mouth/eyes openings: borders stay few
    assert s.boundary.mean() < 3 * max(dense.boundary.mean(), 0.01)
    nn = dense.normals[near]
    assert np.median(np.einsum("ij,ij->i", s.normals, nn)) > 0.95
    # attributes are averaged per cell
    m = decimate_voxel_grid(RawMesh(V=V, F=F, confidence=np.full(len(V), 0.5)), 0.004)
    assert np.allclose(m.confidence, 0.5) and len(m.V) == len(m.confidence) >= len(s.V)


def _t_junctions(V, F, count, rng, off=0.0):
    """``count`` T-junctions: a vertex inserted at the midpoint of an edge shared by two
    triangles, splitting one of them in two and leaving the other whole (a crack of zero
    width); ``off`` moves each new vertex off the edge by that fraction of its length (as the
    rounding of written coordinates does). Returns V, F and the new vertices' indices."""
    E, counts = edge_use_counts(F, len(V))
    interior = set((E[counts == 2, 0] * len(V) + E[counts == 2, 1]).tolist())
    fi = rng.permutation(len(F))
    j = rng.integers(0, 3, len(F))
    a, b, c = F[fi, j], F[fi, (j + 1) % 3], F[fi, (j + 2) % 3]
    key = np.minimum(a, b) * len(V) + np.maximum(a, b)
    ok = np.array([k in interior for k in key.tolist()])
    _, first = np.unique(key[ok], return_index=True)  # one split per edge
    sel = np.flatnonzero(ok)[first[:count]]
    fi, a, b, c = fi[sel], a[sel], b[sel], c[sel]
    d = V[b] - V[a]
    u = np.cross(d, rng.normal(size=d.shape))
    u *= (off * np.linalg.norm(d, axis=1) / np.linalg.norm(u, axis=1))[:, None]
    m = len(V) + np.arange(len(fi))
    keep = np.ones(len(F), bool)
    keep[fi] = False
    F2 = np.vstack([F[keep], np.stack([a, m, c], 1), np.stack([m, b, c], 1)])
    return np.vstack([V, (V[a] + V[b]) / 2 + u]), F2, m


def test_t_junction_cracks_are_no_boundary_and_keep_confidence():
    """T-junctions (a vertex on a neighbour's edge: zero-width cracks, as merged scans and
    remesh exports have) and an unwelded seam do not lower the estimated confidence: the
    crack-free template has confidence 1 everywhere, and so does the cracked one."""
    rng = np.random.default_rng(3)
    V, F, m = _t_junctions(V0, F0, 1500, rng, off=1e-3)  # off the edge by rounding (0.1 %)
    s = prep(RawMesh(V=V, F=F))
    assert len(m) == 1500 and len(s.V) == len(V)  # nothing welded or dropped
    assert not s.boundary.any()
    np.testing.assert_allclose(s.confidence, 1.0)
    assert any("cracks of zero width" in n for n in s.notes), s.notes
    assert np.mean(np.sum(s.normals[: len(V0)] * GT_N, axis=1) > 0.9) > 0.99
    # a seam: the front half's vertices not welded to the back half's (1 nm apart)
    front = V0[F0].mean(axis=1)[:, 2] > np.median(V0[:, 2])
    used = np.unique(F0[front])
    Fs = F0.copy()
    Fs[front] = np.searchsorted(used, F0[front]) + len(V0)
    Vs = np.vstack([V0, V0[used] + 1e-9])
    seam = prep(RawMesh(V=Vs, F=Fs))
    assert not seam.boundary.any()
    assert seam.confidence.min() == 1.0
    # a vertex moved off the edge it splits by 5 % of its length opens a (thin) real gap
    V5, F5, m5 = _t_junctions(V0, F0, 20, rng, off=0.05)
    gap = prep(RawMesh(V=V5, F=F5))
    assert gap.boundary[m5].all() and np.all(gap.confidence[m5] == pytest.approx(0.2))


def test_real_hole_lowers_confidence_as_before_among_t_junction_cracks():
    """A real hole keeps its rim and confidence ramp when T-junction cracks surround it."""
    vi = TPL.landmarks["Omphalion"]
    F = hole_mesh(vi, 0.04)
    used = np.unique(F)
    Vh, Fh = V0[used], np.searchsorted(used, F)
    hole = prep(RawMesh(V=Vh, F=Fh))
    V, F2, _ = _t_junctions(Vh, Fh, 1500, np.random.default_rng(5), off=1e-3)
    s = prep(RawMesh(V=V, F=F2))
    n = len(Vh)  # the hole mesh's vertices come first, in order, in both scans
    np.testing.assert_array_equal(s.V[:n], hole.V)
    assert hole.boundary.any()
    np.testing.assert_array_equal(s.boundary[:n], hole.boundary)
    assert not s.boundary[n:].any() or np.all(
        np.linalg.norm(s.V[n:][s.boundary[n:]] - V0[vi], axis=1) < 0.06
    )  # a split rim edge puts its new vertex on the rim
    d = np.linalg.norm(s.V - V0[vi], axis=1)
    assert np.all(s.confidence[s.boundary] == pytest.approx(0.2))
    assert np.all(s.confidence[d > 0.2] == 1.0)
    near = d[:n] < 0.08
    assert hole.confidence[near].mean() < 0.9
    # the same ramp (its width follows the median edge length, which the splits shorten)
    assert abs(s.confidence[:n][near].mean() - hole.confidence[near].mean()) < 0.03


def test_zero_area_triangles_make_no_border_and_no_nan():
    """Zero-area triangles hanging off edges (a collinear sliver with its own vertex on the
    edge, a needle to a vertex 1 nm from a corner) give no border and no NaN: their own
    vertices take the nearest vertex's normal."""
    rng = np.random.default_rng(7)
    E, _ = edge_use_counts(F0, len(V0))
    e = E[rng.choice(len(E), 400, replace=False)]
    a, b = e[:200, 0], e[:200, 1]
    p, q = e[200:, 0], e[200:, 1]
    n = len(V0)
    sliver = np.stack([a, b, n + np.arange(200)], 1)  # apex at the edge's midpoint
    needle = np.stack([p, q, n + 200 + np.arange(200)], 1)  # apex 1 nm from p
    V = np.vstack([V0, (V0[a] + V0[b]) / 2, V0[p] + 1e-9])
    s = prep(RawMesh(V=V, F=np.vstack([F0, sliver, needle])))
    assert np.isfinite(s.normals).all() and np.isfinite(s.confidence).all()
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0)
    assert not s.boundary.any()
    np.testing.assert_allclose(s.confidence, 1.0)
    own = np.concatenate([GT_N[a] + GT_N[b], GT_N[p]])
    assert np.all(np.sum(s.normals[n:] * own, axis=1) > 0.5)
