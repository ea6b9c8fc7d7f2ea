"""bench.realworld's measurements: area sampling and the surface metrics on known geometry."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_report_counts_lost_parts_and_good_verdicts_on_them():
    from bench.realworld import LOST_PART_MM, lost_parts, report

    def row(seed: int, quality: str, hand_off: float, hand_q: str) -> dict:
        return {
            "seed": seed, "kind": "raw", "family": "raw", "outcome": "fitted", "quality": quality,
            "scan_to_fit_median_mm": 1.0, "scan_to_fit_p95_mm": 3.0, "fit_to_scan_mean_mm": 1.0,
            "body_scan_to_fit_median_mm": 1.0, "body_scan_to_fit_p95_mm": 3.0, "corr_p95_mm": 20.0,
            "corr_mean_mm": 10.0, "fit_wall_s": 1.0, "fit_cpu_s": 1.0,
            "part_truth_offset_mm": {"head": 5.0, "hand_L": hand_off},
            "part_quality": {"head": "good", "hand_L": hand_q},
        }  # fmt: skip

    rows = [row(0, "good", 10.0, "good"), row(1, "failed", 140.0, "failed"),
            row(2, "good", LOST_PART_MM + 1, "good")]  # fmt: skip
    assert lost_parts(rows[0]) == [] and lost_parts(rows[1]) == ["hand_L"]
    text = "\n".join(report(rows, [], True))
    assert "fits with a lost part (centroid > 50 mm off the truth's): 2/3" in text
    assert "'good' verdicts with a lost part: 1; lost parts not 'failed': 1" in text
    assert "raw-1 (failed): hand_L 140 mm (failed)" in text


def test_removal_check_counts_the_plate_and_spares_the_body():
    """``removal_check`` judges ``core.io.clean`` by the truth: the template standing on a
    thin disc of points loses the disc, not its body."""
    from bench.realworld import removal_check, report

    tpl = load_template()
    V = np.asarray(tpl.V, float)
    sole = V[:, 1].min()
    g = np.arange(-0.5, 0.5, 0.01)
    X, Z = (a.ravel() for a in np.meshgrid(g, g))
    disc = np.c_[X, np.full(len(X), sole - 0.003), Z][np.hypot(X, Z) < 0.5]
    c = removal_check(np.vstack([V, disc]), V)
    assert c["not_body_points"] >= len(disc) and c["body_points"] > 0.8 * len(V)
    assert c["not_body_points_removed"] >= 0.95 * c["not_body_points"]
    assert c["body_points_removed"] <= 0.005 * c["body_points"]
    row = {
        "seed": 0, "kind": "raw", "family": "raw", "outcome": "fitted", "quality": "good",
        "scan_to_fit_median_mm": 1.0, "scan_to_fit_p95_mm": 3.0, "fit_to_scan_mean_mm": 1.0,
        "body_scan_to_fit_median_mm": 1.0, "body_scan_to_fit_p95_mm": 3.0, "corr_mean_mm": 1.0,
        "corr_p95_mm": 2.0, "fit_wall_s": 1.0, "fit_cpu_s": 1.0, "removal_check": c,
        "removed": {"floor_points": len(disc), "stray_points": 0},
    }  # fmt: skip
    text = "\n".join(report([row], [], True))
    assert f"removed as not the body (reports): floor points {len(disc):,}" in text


def test_truth_floor_and_twin_split():
    """The truth's own fit->scan (the floor) is ~0 on a scan that is the truth, and grows where
    the scan lacks it (a cloud of half the vertices: point-to-point has a sampling floor); a
    twin slid along its surface is far vertex by vertex but not surface to surface."""
    from bench.realworld import twins

    tpl = load_template()
    F = np.asarray(tpl.F, np.int64)
    V = np.asarray(tpl.V, float)
    N = tpl.vertex_normals()
    ones, no = np.ones(len(V)), np.zeros(len(V), bool)
    m = surface_metrics(Scan(V=V, F=F, normals=N, confidence=ones, boundary=no), V, F, truth=V)
    assert m["truth_fit_to_scan_mean_mm"] < 0.01
    assert m["part_truth_fit_to_scan_mean_mm"]["torso"] < 0.01
    half = slice(0, None, 2)
    cloud = Scan(V=V[half], F=None, normals=N[half], confidence=ones[half], boundary=no[half])
    m = surface_metrics(cloud, V, F, truth=V)
    assert m["truth_fit_to_scan_mean_mm"] > 1.0  # no faces: the distance to the nearest point
    assert abs(m["truth_fit_to_scan_mean_mm"] - m["fit_to_scan_mean_mm"]) < 0.05
    # twin B: every vertex slid 5 mm along the surface (horizontally, around the body)
    t_ = np.cross(N, [0.0, 1.0, 0.0])
    n_ = np.linalg.norm(t_, axis=1, keepdims=True)
    B = V + 0.005 * np.where(n_ > 0.5, t_ / np.maximum(n_, 1e-9), 0.0)
    rows = [{"seed": 0, "kind": "closed_lowres", "_fit_body": V},
            {"seed": 0, "kind": "raw", "_fit_body": B}]  # fmt: skip
    (t,) = twins(rows)
    assert 3.0 < t["mean_mm"] <= 5.0 + 1e-9
    assert t["tangential_mm"] > 5 * t["normal_mm"]
    assert t["surface_mm"] < 0.25 * t["mean_mm"]


def test_twins_report_each_fits_slide_along_the_up_axis():
    """With the truths, each twin's mean offset from its truth along the up axis is reported per
    part: a raw fit whose legs slid 6 mm down reads -6 on the legs and 0 elsewhere."""
    from bench.realworld import twin_part_lines, twins
    from core.registration.quality import part_labels

    V = np.asarray(load_template().V, float)
    labels, pnames = part_labels()
    legs = np.isin(labels, [pnames.index("leg_L"), pnames.index("leg_R")])
    B = V.copy()
    B[legs, 1] -= 0.006
    rows = [{"seed": 3, "kind": "closed_lowres", "_fit_body": V, "_truth_body": V},
            {"seed": 3, "kind": "raw", "_fit_body": B, "_truth_body": V}]  # fmt: skip
    (t,) = twins(rows)
    assert t["part_up_mm"]["leg_L"] == pytest.approx((0.0, -6.0), abs=1e-6)
    assert t["part_up_mm"]["torso"] == pytest.approx((0.0, 0.0), abs=1e-6)
    lines = twin_part_lines([t])
    assert any("leg_L +0/-6" in line for line in lines)
    # without the truths (older rows): no such line
    for r in rows:
        del r["_truth_body"]
    (t,) = twins(rows)
    assert "part_up_mm" not in t


def test_twins_report_the_body_priors_own():
    """With the body priors kept (``_prior_body``), their own twin distance is reported beside
    the fits': priors 4 mm apart, fits identical."""
    from bench.realworld import twin_part_lines, twins

    V = np.asarray(load_template().V, float)
    P = V + np.array([0.004, 0.0, 0.0])
    rows = [{"seed": 2, "kind": "closed_lowres", "_fit_body": V, "_prior_body": V},
            {"seed": 2, "kind": "raw", "_fit_body": V, "_prior_body": P}]  # fmt: skip
    (t,) = twins(rows)
    assert t["mean_mm"] == pytest.approx(0.0, abs=1e-9)
    assert t["prior_mm"] == pytest.approx(4.0, abs=1e-6)
    assert any("the body priors' own 4.0 mm" in line for line in twin_part_lines([t]))


def test_twins_weighed_by_area_count_the_hands_by_their_skin():
    """Twins apart only in the hands (10 mm): by vertex 10 mm × the hands' 24 % of the
    template's vertices, by area 10 mm × their 4 % of its skin."""
    from bench.realworld import twins

    tpl = load_template()
    V = np.asarray(tpl.V, float)
    hands = tpl.part_mask("hand_L") | tpl.part_mask("hand_R")
    B = V.copy()
    B[hands, 2] += 0.010
    rows = [{"seed": 1, "kind": "closed_lowres", "_fit_body": V},
            {"seed": 1, "kind": "raw", "_fit_body": B}]  # fmt: skip
    (t,) = twins(rows)
    assert t["mean_mm"] == pytest.approx(10.0 * hands.mean(), rel=1e-6)
    assert 0.2 < t["area_mm"] < 0.6  # the hands' share of the skin
    assert t["no_hands_mm"] == pytest.approx(0.0, abs=1e-9)


def test_landmark_lines_average_over_cases_and_name_the_worst():
    """Two cases: every landmark 2 mm off in one and 4 mm in the other, but the Crotch 30 mm off
    in the second: mean (2 + 4) / 2 + 13 / 62, the Crotch named worst at 16 mm."""
    from bench.realworld import landmark_lines

    names = list(load_template().landmarks)
    a = {k: 2.0 for k in names}
    b = {k: 4.0 for k in names} | {"Crotch": 30.0}
    lines = landmark_lines([{"landmark_err_mm": a}, {"landmark_err_mm": b}])
    want = (2.0 * 62 + 4.0 * 61 + 30.0) / 124
    assert f"mean {want:.2f} mm" in lines[0]
    assert "within 10 mm 99 %" in lines[0]
    assert lines[1].split(": ", 1)[1].startswith("Crotch 16.0")
    assert landmark_lines([{"seed": 1}]) == []


def test_landmark_bias_is_the_mean_signed_offset():
    """Acromion_L 10 mm forward in one case and 20 mm in the other, every other landmark off by
    +-5 mm sideways alternately: the Acromion_L leads with (+0, +0, +15)."""
    from bench.realworld import landmark_bias_lines

    names = list(load_template().landmarks)
    rows = []
    for k, fwd in enumerate((10.0, 20.0)):
        off = {n: [5.0 * (-1) ** k, 0.0, 0.0] for n in names}
        off["Acromion_L"] = [0.0, 0.0, fwd]
        rows.append({"landmark_offset_mm": off})
    (line,) = landmark_bias_lines(rows)
    assert line.split(": ", 1)[1].startswith("Acromion_L (+0, +0, +15), ")


def test_part_corr_lines_average_and_share_by_vertex_count():
    """Two cases, every part 2 mm off but the head 10 / 20 mm: the head reads 15.0 mm and its
    share is its vertices' part of the summed error."""
    from bench.realworld import part_corr_lines
    from core.registration.quality import part_labels

    labels, names = part_labels()
    rows = [{"part_corr_mean_mm": {p: 2.0 for p in names} | {"head": h}} for h in (10.0, 20.0)]
    (line,) = part_corr_lines(rows)
    n = np.bincount(labels, minlength=len(names))
    head = names.index("head")
    share = 15.0 * n[head] / (15.0 * n[head] + 2.0 * (n.sum() - n[head])) * 100
    assert f"head 15.0 ({share:.0f} %)" in line
    assert "torso 2.0 (" in line
    assert part_corr_lines([{"seed": 1}]) == []


def test_hair_option_names_the_styles_it_takes(capsys):
    from bench.realworld import main

    with pytest.raises(SystemExit) as e:
        main(["--hair", "curly", "--cases", "1", "--no-save"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--hair: one of" in err and "long" in err and "ponytail" in err


def test_decimated_meshes_pair_with_their_raw_twins(capsys):
    """A closed_decimated fit is compared with the raw fit of its body (``twins``), and
    ``--decimated`` is a set of its own (not with another set but ``--booth``)."""
    from bench.realworld import main, twins

    V = np.asarray(load_template().V, float)
    rows = [{"seed": 700, "kind": "closed_decimated", "_fit_body": V},
            {"seed": 700, "kind": "raw", "_fit_body": V + np.array([0.002, 0.0, 0.0])}]  # fmt: skip
    (t,) = twins(rows)
    assert t["seed"] == 700 and abs(t["mean_mm"] - 2.0) < 1e-6
    with pytest.raises(SystemExit) as e:
        main(["--decimated", "--heavy", "--cases", "1", "--no-save"])
    assert e.value.code == 2 and "--decimated are different sets" in capsys.readouterr().err
