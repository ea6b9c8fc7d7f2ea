"""The body prior's scan→template pairs: data in regions the template takes no data from
(fingers, toes, ears) do not pull the nearest data vertex over them."""

import numpy as np
from scipy.spatial import cKDTree

from core.registration.correspondence import ScanIndex
from core.registration.operators import vertex_normals
from core.registration.shape_prior import (
    ShapeBasis,
    _bone_length_terms,
    _scan_to_template,
    load_shape_basis,
)
from core.scan import Scan
from core.template import load_template


def test_scan_points_on_the_fingers_pull_no_palm_vertex() -> None:
    tpl = load_template()
    V, F = tpl.V, np.asarray(tpl.F, np.int64)
    N = vertex_normals(V, F)
    n = len(V)
    scan = Scan(V=V, F=F, normals=N, confidence=np.ones(n), boundary=np.zeros(n, bool))
    index = ScanIndex(scan)  # the scan is the template's own surface
    data = ~np.asarray(tpl.bad_scan_mask, bool)
    cand, masked = np.flatnonzero(data), np.flatnonzero(~data)
    finger_tree = cKDTree(V[tpl.mask("fingers")])

    # without the masked vertices, the fingers' scan points pair with palm vertices cm away
    v, P, _, _ = _scan_to_template(index, V, N, cand, 0.05, n)
    on_fingers = finger_tree.query(P)[0] < 1e-9
    assert on_fingers.sum() > 100
    assert np.linalg.norm(V[v] - P, axis=1)[on_fingers].max() > 0.02
    # with them, a point on the fingers is explained by the fingers: only exact pairs are left
    v, P, _, _ = _scan_to_template(index, V, N, cand, 0.05, n, explained=masked)
    assert np.linalg.norm(V[v] - P, axis=1).max() < 1e-6
    assert not np.isin(v, masked).any()
    assert not (finger_tree.query(P)[0] < 1e-9).any()


def test_the_leg_twist_prior_weighs_twist_about_the_thigh_only() -> None:
    from core.registration.shape_prior import LEG_TWIST_PRIOR, _articulation, _bone_metrics
    from core.rig import joint_positions

    art = _articulation()
    V0 = load_template().V
    metrics = _bone_metrics(art, V0, LEG_TWIST_PRIOR)
    assert len(metrics) == 2
    J = joint_positions(V0, rig=art.rig)
    for a, M in metrics:
        name = art.names[a]
        knee = J[art.rig.names.index(name.replace("upperleg01", "lowerleg01"))]
        axis = knee - J[art.bones[a]]
        axis /= np.linalg.norm(axis)
        w, vecs = np.linalg.eigh(M)
        assert np.allclose(w[:2], 0.0) and w[2] > 0.05  # bending the thigh costs nothing
        assert abs(vecs[:, 2] @ axis) > 0.95, name  # twisting it about its own axis does


def _bone_terms() -> tuple[dict, ShapeBasis]:
    """The bone length terms of the template and the shape basis."""
    from core.rig import load_rig

    basis = load_shape_basis()
    return _bone_length_terms(load_template().V, basis.U, load_rig()), basis


def test_the_bone_length_prior_rows_are_the_lengths_linearised_with_a_band() -> None:
    from core.registration.shape_prior import BONE_LENGTH_RATIOS, _bone_length_rows

    terms, basis = _bone_terms()
    k = basis.U.shape[2]
    J, r = _bone_length_rows(terms, np.zeros(k))
    # the template's arms and thighs lie inside their bands and are alike: only the L-R rows, ~0
    assert J.shape == (len(BONE_LENGTH_RATIOS), k) and np.abs(r).max() < 1e-4
    # the rows are the lengths' first-order change (finite differences at a random shape)
    c = np.random.default_rng(0).normal(0.0, 1.0, k) * basis.sigma * 0.5
    J, r = _bone_length_rows(terms, c)
    dc = np.random.default_rng(1).normal(0.0, 1.0, k) * basis.sigma * 1e-4
    _, r2 = _bone_length_rows(terms, c + dc)
    assert len(r2) == len(r)
    np.testing.assert_allclose(r2 - r, J @ dc, rtol=1e-3, atol=1e-9)
    # a stature the limbs are far too short for: every bone gets a row pulling it to the band
    tall = {**terms, "s0": 3.0}
    J, r = _bone_length_rows(tall, np.zeros(k))
    assert len(r) == 2 * len(BONE_LENGTH_RATIOS) + len(BONE_LENGTH_RATIOS)
    assert (r[: 2 * len(BONE_LENGTH_RATIOS)] < -0.05).all()  # length - low * stature, metres
    # a centred side: its forearm gets a row to the centre even inside the band
    from core.registration.shape_prior import ARM_BONE_CENTRES

    J, r = _bone_length_rows(terms, np.zeros(k), centred="L")
    assert len(r) == 1 + len(BONE_LENGTH_RATIOS)
    stature = terms["s0"]
    pa, pb = terms["joints"]["lowerarm01.L"][0], terms["joints"]["wrist.L"][0]
    want = np.linalg.norm(pb - pa) - ARM_BONE_CENTRES["lowerarm01"] * stature
    assert abs(r[0] - want) < 1e-12 and abs(r[0]) > 1e-4  # the template's 0.1359, not 0.145


def test_the_leg_centre_rows_pull_each_thigh_to_its_centre() -> None:
    """A row per thigh: its rest length minus :data:`LEG_BONE_CENTRES`' share of the stature,
    linearised (finite differences); the template's thighs (0.253) are long of 0.241."""
    from core.registration.shape_prior import LEG_BONE_CENTRES, _leg_centre_rows

    terms, basis = _bone_terms()
    k = basis.U.shape[2]
    J, r = _leg_centre_rows(terms, np.zeros(k))
    assert J.shape == (2 * len(LEG_BONE_CENTRES), k)
    for i, side in enumerate("LR"):
        pa, pb = terms["joints"][f"upperleg01.{side}"][0], terms["joints"][f"lowerleg01.{side}"][0]
        want = np.linalg.norm(pb - pa) - LEG_BONE_CENTRES["upperleg01"] * terms["s0"]
        assert abs(r[i] - want) < 1e-12 and r[i] > 0.01 * terms["s0"]  # 0.253 vs 0.241
    c = np.random.default_rng(0).normal(0.0, 1.0, k) * basis.sigma * 0.5
    J, r = _leg_centre_rows(terms, c)
    dc = np.random.default_rng(1).normal(0.0, 1.0, k) * basis.sigma * 1e-4
    _, r2 = _leg_centre_rows(terms, c + dc)
    np.testing.assert_allclose(r2 - r, J @ dc, rtol=1e-3, atol=1e-9)


def test_the_trunk_rows_are_the_spine_joints_offsets_along_the_trunk() -> None:
    """Per spine joint of :data:`TRUNK_CHAINS`, its offset along the pelvis→neck axis from its
    template share: 0 on the template; a shape moving that joint's surrounding vertices 1 m
    down moves its row by about -1 (the axis is nearly vertical), the others' barely."""
    from core.registration.shape_prior import TRUNK_CHAINS, _limb_rows
    from core.rig import load_rig

    tpl, rig = load_template(), load_rig()
    n = len(tpl.V)
    G, g0 = _limb_rows(tpl.V, np.zeros((n, 3, 1)), rig, TRUNK_CHAINS)
    assert G.shape == (len(TRUNK_CHAINS), 1) and np.abs(g0).max() < 1e-9
    i = [b for _, b, _ in TRUNK_CHAINS].index("spine03")
    U = np.zeros((n, 3, 1))
    U[rig.head_reg_idx[rig.index("spine03")], 1, 0] = -1.0
    G, _ = _limb_rows(tpl.V, U, rig, TRUNK_CHAINS)
    assert -1.0 < G[i, 0] < -0.85  # -0.92: one of its vertices also places the pelvis
    assert np.abs(np.delete(G[:, 0], i)).max() < 0.1  # the others only through that vertex


def _four_nearest_pairs(index, X, N, cand, max_distance, n_sample, min_cos):
    """The rule of ``_scan_to_template`` written plainly: each sampled scan point (``n_sample``
    at an even stride: the scan is not a decimated mesh) with the first of its 4 nearest vertices
    of ``cand`` whose normal is compatible."""
    pts = index.points
    sel = np.linspace(0, len(pts) - 1, min(n_sample, len(pts))).astype(np.int64)
    d, j = cKDTree(X[cand]).query(pts[sel], k=4, distance_upper_bound=max_distance)
    out = []
    for s, (ds, js) in enumerate(zip(d, j, strict=True)):
        for dk, jk in zip(ds, js, strict=True):
            if np.isfinite(dk) and N[cand[jk]] @ index.normals[sel[s]] > min_cos:
                out.append((cand[jk], sel[s]))
                break
    return out


def test_scan_to_template_pairs_are_the_first_compatible_of_the_four_nearest() -> None:
    tpl = load_template()
    V, F = tpl.V, np.asarray(tpl.F, np.int64)
    rng = np.random.default_rng(1)
    n = len(V)
    N = vertex_normals(V, F)
    # the scan: the template moved by up to 2 cm, a third of its normals turned at random
    P = V + rng.normal(scale=0.007, size=V.shape)
    Ns = vertex_normals(P, F) * np.where(rng.random(n) < 0.33, -1.0, 1.0)[:, None]
    scan = Scan(V=P, F=F, normals=Ns, confidence=np.ones(n), boundary=np.zeros(n, bool))
    index = ScanIndex(scan)
    cand = np.flatnonzero(rng.random(n) < 0.4)
    v, pts, _, _ = _scan_to_template(index, V, N, cand, 0.01, 6000, min_cos=0.5)
    want = _four_nearest_pairs(index, V, N, cand, 0.01, 6000, 0.5)
    assert len(want) > 1000
    np.testing.assert_array_equal(v, [a for a, _ in want])
    np.testing.assert_array_equal(pts, P[[b for _, b in want]])


def test_a_denser_scan_sample_weighs_as_the_rows_asked_for() -> None:
    """The direction's weight is ``n_sample`` unit rows however many points are paired: more
    points, each lighter (an even stride's choice of points averages out)."""
    tpl = load_template()
    V, F = tpl.V, np.asarray(tpl.F, np.int64)
    N = vertex_normals(V, F)
    n = len(V)
    scan = Scan(V=V, F=F, normals=N, confidence=np.ones(n), boundary=np.zeros(n, bool))
    index = ScanIndex(scan)  # the scan is the template itself: every point pairs
    cand = np.arange(n)
    for n_sample in (1000, 3000):
        v, _, w, _ = _scan_to_template(index, V, N, cand, 0.05, n_sample, oversample=3)
        paired = 3 * n_sample  # the even stride's points (not a decimated mesh)
        assert len(v) == paired > 2 * n_sample  # more points than unit rows ...
        np.testing.assert_allclose(w, n_sample / paired)  # ... that weigh as those rows
        assert abs(w.sum() - n_sample) < 1e-6 * n_sample
    # a scan smaller than the rows asked for: every point at full weight
    v, _, w, _ = _scan_to_template(index, V, N, cand, 0.05, 20000, oversample=3)
    assert len(v) == n and np.all(w == 1.0)
