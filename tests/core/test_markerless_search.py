"""The markerless search's facing cue (core.matching.markerless.feet_forward) on off-model scans
of core.synth.scanner_outputs: the feet tell front from back, whatever the facing and up sign."""

from __future__ import annotations

import re
from dataclasses import replace
from functools import cache

import numpy as np
import pytest

pytest.importorskip("skimage")


@cache
def _case():
    """closed_lowres-2 (off-model, 20 k vertices) in canonical metres: points, faces, truth."""
    from core.synth.scanner_outputs import make_case

    c = make_case(2, "closed_lowres")
    A = c.to_file
    inv = np.linalg.inv(A[:3, :3])
    return (c.V - A[:3, 3]) @ inv.T, np.asarray(c.F), (c.truth - A[:3, 3]) @ inv.T


def _scan(R: np.ndarray):
    from core.io import detect_frame, prepare_scan
    from core.scan import RawMesh

    V, F, truth = _case()
    V, truth = V @ R.T, truth @ R.T
    return prepare_scan(RawMesh(V=V, F=F), detect_frame(V, units="m", up="+y")), truth


def _toes(truth: np.ndarray) -> np.ndarray:
    from core.template import load_template

    L = load_template().landmarks
    d = truth[[L["Toe_tip_L"], L["Toe_tip_R"]]].sum(0)
    d = d - truth[[L["Calcaneus_posterior_L"], L["Calcaneus_posterior_R"]]].sum(0)
    return d[[0, 2]] / np.linalg.norm(d[[0, 2]])


@pytest.mark.parametrize("deg, upside_down", [(0, False), (150, False), (250, True)])
def test_feet_show_which_way_the_body_faces(deg, upside_down):
    from core.matching.markerless import (
        FEET_CUE_ANGLE,
        _rot_y,
        _rot_z,
        _template_toes,
        candidate_alignments,
        feet_forward,
    )

    R = _rot_y(deg) @ (_rot_z(180.0) if upside_down else np.eye(3))
    scan, truth = _scan(R)
    toes = _toes(truth)
    cue = feet_forward(scan, top=upside_down)
    assert cue is not None and cue @ toes > np.cos(np.radians(15))
    # the candidates of the body's own up sign all face the feet's way (front and back of a
    # body match a scan almost equally well, so the other facing is not even tried)
    mine = [s for s in candidate_alignments(scan) if (s.R[1, 1] < 0) == upside_down]
    assert mine
    for s in mine:
        assert (s.R @ _template_toes())[[0, 2]] @ toes > np.cos(np.radians(FEET_CUE_ANGLE + 15))


def test_search_puts_a_flexed_head_on_the_scans_head(tmp_path):
    """raw-12 (a raw scan, written upside down in cm; neck and head flexed ~20° together): the
    articulated search tilted the head bone ~50° and its centroid started 72 mm off the truth's;
    the head step (:func:`core.matching.markerless._head_start`) puts it back."""
    from core.io import load_scan
    from core.matching.markerless import choose_alignment
    from core.registration.correspondence import ScanIndex
    from core.registration.shape_prior import fit_body_prior
    from core.synth.scanner_outputs import make_case
    from core.template import load_template
    from core.threads import single_blas_thread

    case = make_case(12, "raw")
    scan, _ = load_scan(case.write(tmp_path / "raw-12.ply"))
    truth = scan.frame.to_canonical(case.truth)
    index = ScanIndex(scan)
    start, scores = single_blas_thread(choose_alignment)(scan, index)
    assert "head" in start.label and any(s["stage"] == "head" for s in scores)
    tpl = load_template()
    F, none = np.asarray(tpl.F, np.int64), np.zeros(0, np.int64)
    X = fit_body_prior(
        index, tpl.V, F, none, np.zeros((0, 3)), start.similarity, iterations=0,
        initial_pose=start.pose, initial_coefficients=start.coefficients,
    ).X  # fmt: skip
    head = tpl.part_mask("head")
    off = np.linalg.norm(X[head].mean(0) - truth[head].mean(0)) * 1000
    assert off < 30.0, off  # measured 16 mm (72 mm with the search's own head)


def test_near_tied_starts_are_told_apart_by_the_shape_space_fit(tmp_path):
    """closed_lowres-4 (feet 2 cm apart): the search scores arms 50° and 30° nearly alike; from
    50° the fit once put the left leg on the right foot (foot_L 128 mm off the truth). The
    markerless fit runs its shape-space fit from both and keeps the one that scores best (since
    the first fit's denser scan sample, ``FIRST_FIT_SCAN_OVERSAMPLE``, both land alike: 0.378)."""
    from core.io import load_scan
    from core.matching.markerless import fit_markerless
    from core.registration.quality import part_labels
    from core.synth.scanner_outputs import make_case

    case = make_case(4, "closed_lowres")
    scan, _ = load_scan(case.write(tmp_path / "closed_lowres-4.ply"))
    truth = scan.frame.to_canonical(case.truth)
    res = fit_markerless(scan, refine=False)
    note = next(n for n in res.report.notes if n.startswith("markerless: best"))
    assert "near-tied starts" in note, note
    kept = note.split("(", 1)[1].split(";")[0]  # the kept start's label
    tied = re.findall(r"(candidate [^,]+, arms \d+°[^;]*?) (\d\.\d{3})", note.split("scored ")[1])
    # (the head's start, ``_head_start``, may add ", head neck 15°": before stop 51's upright
    # search both did)
    assert {lab.split(", head")[0] for lab, _ in tied} >= {
        "candidate 0, arms 50°",
        "candidate 0, arms 30°",
    }, note
    scores = dict(tied)
    assert float(scores[kept]) == min(float(x) for x in scores.values()), note  # the best kept
    labels, names = part_labels()
    foot = labels == names.index("foot_L")
    off = np.linalg.norm(res.vertices[foot].mean(0) - truth[foot].mean(0)) * 1000
    assert off < 30.0, off


def test_a_scan_read_upside_down_is_turned_over():
    """closed_lowres-2 stored with -Y up (as scanners rarely do, but files get flipped): the up
    axis's sign cannot be told from the extents (read as +y); the search finds the body head-down
    and the scan is turned over: the fit stands head up in the canonical frame, the frame says
    -y, and the fit mapped back to the file lies on the body."""
    from core.io import detect_frame, prepare_scan
    from core.io.frame import rotation_for_up
    from core.matching.markerless import fit_markerless
    from core.scan import RawMesh
    from core.template import load_template

    V, F, truth = _case()
    R = rotation_for_up("-y")
    Vf, truth_f = V @ R, truth @ R  # canonical -> a -Y-up file (x_canonical = R x_file)
    frame = detect_frame(Vf)
    assert frame.up == "+y"  # the extents tell the axis, not its sign
    scan = prepare_scan(RawMesh(V=Vf, F=F), frame)
    res = fit_markerless(scan, refine=False)
    assert scan.frame.up == "-y" and res.report.up == "-y"
    assert any("turned over" in n for n in scan.notes)
    L = load_template().landmarks
    head, toe = res.vertices[L["Vertex"], 1], res.vertices[L["Toe_tip_L"], 1]
    assert head - toe > 1.5, (head, toe)
    np.testing.assert_allclose(scan.frame.to_canonical(Vf), scan.V, atol=1e-9)
    err = np.linalg.norm(scan.frame.to_file(res.vertices) - truth_f, axis=1)
    assert err.mean() < 0.03, err.mean()


def test_markerless_fit_keeps_the_head_facing_forward(tmp_path):
    """raw-19 (a raw scan, head turned ~19° against the torso): without the head's pose prior
    (:data:`core.registration.shape_prior.HEAD_PRIOR`) the markerless fit turned the head 69° on
    the skull's data, 72 mm off the truth's, and read `good` before the quality check's head
    turn; with it the head stays within 30 mm and faces forward."""
    from core.io import load_scan
    from core.matching.markerless import fit_markerless
    from core.registration.quality import THRESHOLDS, head_turn
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    case = make_case(19, "raw")
    scan, _ = load_scan(case.write(tmp_path / "raw-19.ply"))
    truth = scan.frame.to_canonical(case.truth)
    res = fit_markerless(scan)
    tpl = load_template()
    head = tpl.part_mask("head") | tpl.part_mask("neck")
    off = np.linalg.norm(res.vertices[head].mean(0) - truth[head].mean(0)) * 1000
    assert off < 30.0, off  # measured 13 mm (72 mm without the prior)
    assert head_turn(res.vertices) < THRESHOLDS["head_turn_deg"].suspect
    assert res.report.quality.parts["head"].quality != "failed", res.report.quality.reasons


def test_twin_deliveries_put_the_feet_alike(tmp_path):
    """closed_lowres-28 and raw-28 are the same body: a closed mesh with flat-cut soles and a
    raw scan without its lowest 1 cm. Without a floor the raw scan's shape-space fit grew its
    feet down and forward along the instep (heels 41 mm under the truth's soles, feet 40.6 mm
    from the truth's, 20.9 mm from the closed twin's); with the floor
    (:data:`core.matching.markerless.FLOOR_GAP_M`) 20.6 and 5.2 mm. Since the toes of a finely
    sampled scan take data (``fit_data_mask``) the raw fit's feet are 8.1 mm from the truth's,
    the closed one's (coarse, no toe data) 18.6, the twins 12.1 apart."""
    from core.io import load_scan
    from core.matching.markerless import fit_markerless
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl = load_template()
    feet = tpl.part_mask("foot_L") | tpl.part_mask("foot_R")
    body, truth = {}, {}
    for kind in ("closed_lowres", "raw"):
        case = make_case(28, kind)
        scan, _ = load_scan(case.write(tmp_path / f"{kind}-28.ply"))
        res = fit_markerless(scan, refine=False)
        A = case.to_file  # the generator's body frame (metres), shared by the twins

        def in_body(X: np.ndarray, A: np.ndarray = A, scan=scan) -> np.ndarray:
            return (scan.frame.to_file(X) - A[:3, 3]) @ np.linalg.inv(A[:3, :3]).T

        body[kind] = in_body(res.vertices)
        truth[kind] = in_body(scan.frame.to_canonical(case.truth))
    raw_off = np.linalg.norm(body["raw"][feet] - truth["raw"][feet], axis=1).mean() * 1000
    twins = np.linalg.norm(body["raw"][feet] - body["closed_lowres"][feet], axis=1).mean() * 1000
    closed_off = np.linalg.norm(body["closed_lowres"][feet] - truth["closed_lowres"][feet], axis=1)
    assert raw_off < 12.0, raw_off  # measured 8.1 mm (20.6 before the toes took data)
    # the twins differ by less than the coarse closed fit's own error: what remains is its
    # (toes fused: no toe data), not the raw fit's. Measured 12.1 vs 18.6 mm.
    assert twins < closed_off.mean() * 1000, (twins, closed_off.mean() * 1000)


def test_rigid_runner_up_far_behind_gets_no_arm_hypotheses(monkeypatch):
    """closed_lowres-2: its runner-up rigid candidate trails by 0.12 (> RIGID_KEEP_MARGIN); the
    search runs the arm hypotheses of the best only, and chooses the start it chose from both."""
    import core.matching.markerless as ml
    from core.registration.correspondence import ScanIndex

    scan, _ = _scan(np.eye(3))
    index = ScanIndex(scan)
    # (its rigid fits match 17 % of the template: the best head-down candidate's middle arm
    # start joins the search, RIGID_POOR_COVERAGE; not this test's subject)
    monkeypatch.setattr(ml, "RIGID_POOR_COVERAGE", 0.0)
    starts, scores = ml.search_starts(scan, index)
    # (the average template's candidates; a BMI 37 body's trunk also brings the widened one's)
    rigid = sorted(s["score"] for s in scores if s["stage"] == "rigid" and s["girth"] == 1.0)
    art = [s for s in scores if s["stage"] == "articulated" and s["girth"] == 1.0]
    assert len(rigid) >= 2 and rigid[1] > rigid[0] + ml.RIGID_KEEP_MARGIN
    assert len(art) == len(ml.ARM_HYPOTHESES) and len({s["candidate"] for s in art}) == 1
    monkeypatch.setattr(ml, "RIGID_KEEP_MARGIN", np.inf)  # every kept candidate tried
    all_starts, all_scores = ml.search_starts(scan, index)
    plain = [s for s in all_scores if s["stage"] == "articulated" and s["girth"] == 1.0]
    assert len(plain) == 2 * len(art)
    assert [st.label for st in all_starts[:2]] == [st.label for st in starts[:2]]
    assert all_starts[0].score == starts[0].score


def test_a_heavy_body_is_searched_with_a_template_of_its_girth(monkeypatch):
    """closed_lowres-73 (a man of BMI 49): from the average template every start scored
    1.2-1.5 (of 2) and the best one stood the body upside down (the fit 1.04 m from the truth);
    with the template widened to the scan's trunk depth the best start stands up (the fit:
    19.7 mm, good) and scores better. Since the search keeps each start standing as it was
    put (``upright``, stop 51: no start rolls over on its way), the average template's best
    stands up too."""
    import core.matching.markerless as ml
    from core.io import detect_frame, prepare_scan
    from core.registration.correspondence import ScanIndex
    from core.scan import RawMesh
    from core.synth.scanner_outputs import make_case

    c = make_case(73, "closed_lowres")
    scan = prepare_scan(RawMesh(V=c.V, F=np.asarray(c.F)), detect_frame(c.V))
    index = ScanIndex(scan)
    assert ml.girth_scale(scan) > 1.15
    starts, _ = ml.search_starts(scan, index)
    assert starts[0].similarity.R[1, 1] > 0.9, starts[0].label  # head up
    monkeypatch.setattr(ml, "girth_scale", lambda scan: 1.0)  # the average template's search
    plain, _ = ml.search_starts(scan, index)
    assert plain[0].similarity.R[1, 1] > 0.9, plain[0].label  # head up (before upright: down)
    assert plain[0].score > starts[0].score


def test_rigid_candidates_that_cannot_tell_up_from_down_go_on_both_ways(monkeypatch):
    """closed_booth-305 (BMI 38, ponytail, arms against the body): its rigid candidates match
    7-9 % of the template, the two head-down ones best; the best upright one, past the keep
    margin, goes on to the middle arm hypothesis, beats every start (upright 1.13 vs head-down
    1.32) and gets the others too; without it the body was fitted head-down (1.02 m from the
    truth)."""
    import core.matching.markerless as ml
    from core.io import detect_frame, prepare_scan
    from core.registration.correspondence import ScanIndex
    from core.scan import RawMesh
    from core.synth.scanner_outputs import make_case

    c = make_case(305, "closed_booth")
    scan = prepare_scan(RawMesh(V=c.V, F=np.asarray(c.F)), detect_frame(c.V))
    index = ScanIndex(scan)
    starts, scores = ml.search_starts(scan, index)
    rigid = [s for s in scores if s["stage"] == "rigid" and s["girth"] == 1.0]
    assert max(s["coverage"] for s in rigid) < ml.RIGID_POOR_COVERAGE
    assert starts[0].similarity.R[1, 1] > 0.9, starts[0].label  # head up
    up = [st for st in starts if st.similarity.R[1, 1] > 0.9]
    assert len(up) == len(ml.ARM_HYPOTHESES)  # it beat the rest: every arm hypothesis
    monkeypatch.setattr(ml, "RIGID_POOR_COVERAGE", 0.0)  # the kept candidates only
    kept, _ = ml.search_starts(scan, index)
    assert all(st.similarity.R[1, 1] < -0.9 for st in kept), [st.label for st in kept]
    assert kept[0].score > starts[0].score + 0.1


def test_a_poor_best_start_widens_the_near_tie():
    """Near-tied starts: within TIE_MARGIN of the best; where even the best start matches less
    than min_coverage of the template (heavy raw-63: arms 10° 1.239, right start 1.271), within
    POOR_TIE_MARGIN. Never more than two standing the same way up."""
    from core.geometry import Similarity
    from core.matching.markerless import POOR_TIE_MARGIN, TIE_MARGIN, Start, near_tied

    def start(score: float, coverage: float, label: str) -> Start:
        sim = Similarity(1.0, np.eye(3), np.zeros(3))
        return Start(sim, {}, np.zeros(0), score, coverage, label)

    gap = (TIE_MARGIN + POOR_TIE_MARGIN) / 2  # beyond the usual margin, within the poor one
    good = [start(1.0, 0.6, "a"), start(1.0 + gap, 0.5, "b"), start(1.0 + gap, 0.5, "c")]
    poor = [start(1.2, 0.35, "a"), start(1.2 + gap, 0.3, "b"), start(1.2 + gap, 0.3, "c")]
    assert [s.label for s in near_tied(good, 0.4)] == ["a"]
    assert [s.label for s in near_tied(poor, 0.4)] == ["a", "b"]
    far = [poor[0], start(1.2 + POOR_TIE_MARGIN * 1.5, 0.3, "b")]
    assert [s.label for s in near_tied(far, 0.4)] == ["a"]
    close = [good[0], start(1.0 + TIE_MARGIN / 2, 0.5, "b")]
    assert [s.label for s in near_tied(close, 0.4)] == ["a", "b"]


def test_near_tied_adds_the_best_start_standing_the_other_way_up():
    """closed_wide-501 (BMI 57, arms 76°): the two best starts stood head-down and the best
    upright one trailed by 0.05 (within the poor margin): it is tried too, as a third
    contender; not when beyond the margin, nor when the two already stand either way."""
    from core.geometry import Similarity
    from core.matching.markerless import POOR_TIE_MARGIN, TIE_MARGIN, Start, near_tied

    down = np.diag([-1.0, -1.0, 1.0])

    def start(score: float, coverage: float, label: str, head_down: bool) -> Start:
        sim = Similarity(1.0, down if head_down else np.eye(3), np.zeros(3))
        return Start(sim, {}, np.zeros(0), score, coverage, label)

    gap = (TIE_MARGIN + POOR_TIE_MARGIN) / 2
    poor = [start(1.3, 0.17, "a", True), start(1.301, 0.16, "b", True),
            start(1.3 + gap, 0.23, "c", False), start(1.3 + gap, 0.2, "d", False)]  # fmt: skip
    assert [s.label for s in near_tied(poor, 0.4)] == ["a", "b", "c"]
    good = [start(1.0, 0.6, "a", False), start(1.01, 0.6, "b", False),
            start(1.0 + gap, 0.5, "c", True)]  # fmt: skip
    assert [s.label for s in near_tied(good, 0.4)] == ["a", "b"]  # beyond TIE_MARGIN
    close = [good[0], start(1.0 + TIE_MARGIN / 2, 0.5, "c", True), good[1]]
    assert [s.label for s in near_tied(close, 0.4)] == ["a", "c"]  # either way already


def test_feet_fused_by_a_coarse_closed_mesh_stay_forward(tmp_path):
    """closed_lowres-4 (feet 2 cm apart) meshed on a 17 mm grid (8 k vertices: the feet fuse):
    without the feet's prior (shape_prior.FOOT_PRIOR) the left foot was fitted turned 77° (135
    mm off the truth's). It stays forward and on its own data."""
    from core.io import load_scan
    from core.matching.markerless import fit_markerless
    from core.registration.quality import part_labels
    from core.synth.scanner_outputs import make_case

    case = make_case(4, "closed_lowres", voxel_m=0.017)
    assert len(case.V) < 10_000
    scan, _ = load_scan(case.write(tmp_path / "closed_lowres-4-coarse.ply"))
    truth = scan.frame.to_canonical(case.truth)
    res = fit_markerless(scan)
    labels, names = part_labels()
    for side in ("foot_L", "foot_R"):
        m = labels == names.index(side)
        off = np.linalg.norm(res.vertices[m].mean(0) - truth[m].mean(0)) * 1000
        assert off < 40.0, (side, off)  # measured 10-12 mm (135 without the prior)
        assert res.report.quality.parts[side].foot_turn_deg < 20.0


def test_arms_out_80_to_90_degrees_are_searched_from_a_wide_arm_start(tmp_path):
    """raw_wide-509 (arms 80-90° out, a T-pose capture): from the usual arm starts (10/30/50°)
    the search's best start left both arms 300-400 mm from the scan's and the fit failed; the
    scan is wider than WIDE_ARMS_RATIO of its height, so the search also starts the arms at 80°,
    and that start wins with the posed arms on the scan's arms. A scan with the arms down gets
    no such start (no extra CPU)."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.registration.correspondence import ScanIndex
    from core.synth.scanner_outputs import make_case

    case = make_case(509, "raw_wide")
    assert case.params["posture"]["arm_abduction"] >= 80.0
    scan, _ = load_scan(case.write(tmp_path / "wide.ply"))
    assert ml.width_ratio(scan) > ml.WIDE_ARMS_RATIO
    assert ml.arm_hypotheses(scan) == ml.ARM_HYPOTHESES + ml.WIDE_ARM_HYPOTHESES
    starts, scores = ml.search_starts(scan, ScanIndex(scan))
    assert "arms 80°" in starts[0].label, starts[0].label
    usual = min(s["score"] for s in scores if s.get("arms_deg", 0) in ml.ARM_HYPOTHESES)
    assert starts[0].score < usual - ml.TIE_MARGIN  # clearly better, not a near tie
    narrow, _ = _scan(np.eye(3))  # closed_lowres-2: arms ~25° out
    assert ml.width_ratio(narrow) < ml.WIDE_ARMS_RATIO
    assert ml.arm_hypotheses(narrow) == ml.ARM_HYPOTHESES


def test_a_hand_fitted_palm_over_is_refitted_from_a_twisted_forearm(tmp_path):
    """closed_palms-606 (palms turned backwards 76-84°, open hands): the first shape-space fit
    laid the left hand with its palm the wrong way round (centroid 34 mm off the truth's, hand
    suspect). Its hand matches the scan poorly (hand_mismatch > POOR_HAND), so the body is fitted
    again from that fit with the forearm twisted either way; the twist that matches the hand
    (and the other does not) is kept. Both its palms are turned (84° / 76°): since the fingertip's
    allowance follows the scan's sampling (``tip_allowance``) the right hand is refitted too."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl = load_template()
    case = make_case(606, "closed_palms")
    assert case.params["posture"]["forearm_twist_L"] > 70.0 and not case.params["posture"]["fist"]
    scan, _ = load_scan(case.write(tmp_path / "palms.ply"))
    res = ml.fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)
    twisted = re.search(r"forearm (\S+) twisted", res.report.notes[-1])
    assert twisted and "L" in twisted.group(1).split("+"), res.report.notes[-1]
    hand = tpl.part_mask("hand_L")
    off = np.linalg.norm(res.vertices[hand].mean(0) - truth[hand].mean(0)) * 1000
    assert off < 20.0, off  # measured 13 mm (34 without the twisted refit)
    assert res.report.quality.parts["hand_L"].quality == "good"
    # the twist turns the palm about the forearm and back; the right side is mirrored
    prior = res.body_prior
    there = ml.twisted_pose(prior, "LR", 90.0)
    back = ml.twisted_pose(replace(prior, pose=there), "LR", -90.0)
    for b in ("lowerarm01.L", "lowerarm01.R"):
        assert np.allclose(back[b], prior.pose.get(b, np.eye(3)), atol=1e-12)
    assert not np.allclose(there["lowerarm01.L"], prior.pose.get("lowerarm01.L", np.eye(3)))


def test_legs_fitted_crossed_are_fitted_again_uncrossed(tmp_path):
    """raw-59 of ``bench.realworld --heavy`` (a man of BMI 47, feet 5 cm apart, 225 k points):
    the first shape-space fit crosses the legs, each foot on the other's data. Its feet read
    crossed (feet_apart < CROSSED_FEET_M), so the body is fitted again from that fit with the
    legs' bones at rest, and kept: the feet apart and a two-way score within the tie margin
    (measured: feet 4.7 / 4.7 mm off the truth's, good). (closed_booth-328, this test's case
    until the search also tried the other way up, no longer starts crossed.)"""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.registration.quality import feet_apart
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl = load_template()
    case = make_case(59, "raw")
    assert "feet 5 cm apart" in case.description
    scan, _ = load_scan(case.write(tmp_path / "raw.ply"))
    res = ml.fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)
    assert "legs uncrossed" in res.report.notes[-1], res.report.notes[-1]
    assert feet_apart(res.vertices) > 0.0
    for side in "LR":
        foot = tpl.part_mask(f"foot_{side}")
        off = np.linalg.norm(res.vertices[foot].mean(0) - truth[foot].mean(0)) * 1000
        assert off < 25.0, (side, off)
        assert res.report.quality.parts[f"foot_{side}"].quality == "good"


def test_normals_a_point_cloud_turned_over_on_a_leg_are_turned_back(tmp_path):
    """cloud_wide-505 (a raw scan's points without normals, arms 61°, feet 33 cm apart): the
    normals' propagation over the points turned the left leg over at the crotch (shin and foot
    97-99 % of their points flipped), and the fit found no compatible data there (left foot 41 mm
    off the truth's, verdict failed). After the first fit, points whose normal points into that
    body are turned back and the rounds fit them."""
    from scipy.spatial import cKDTree

    import core.matching.markerless as ml
    from core.geometry import vertex_normals
    from core.io import load_scan
    from core.registration.correspondence import normals_against_body
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl = load_template()
    case = make_case(505, "cloud_wide")
    scan, _ = load_scan(case.write(tmp_path / "cloud.ply"))
    assert scan.F is None
    truth = scan.frame.to_canonical(case.truth)
    # the check on its own, around the true body: it finds the flipped points and little else
    nearest = cKDTree(truth).query(scan.V)[1]
    N_true = vertex_normals(truth, np.asarray(tpl.F, np.int64))[nearest]
    wrong = np.einsum("ij,ij->i", scan.normals, N_true) < 0
    turned = normals_against_body(scan, truth, tpl.F)
    assert wrong.sum() > 20_000  # the flipped leg (measured 30 k points)
    assert (turned & wrong).sum() > 0.9 * wrong.sum()
    assert (turned & ~wrong).sum() < 0.002 * len(wrong)
    res = ml.fit_markerless(scan)
    assert any(n.startswith("normals turned at") for n in res.report.notes), res.report.notes
    foot = tpl.part_mask("foot_L")
    truth = scan.frame.to_canonical(case.truth)  # the fit may have turned the scan over
    off = np.linalg.norm(res.vertices[foot].mean(0) - truth[foot].mean(0))
    assert off * 1000 < 35.0, off * 1000  # measured 29 mm (41 without the turned normals)
    assert res.report.quality.quality != "failed", res.report.quality.reasons


def test_an_arm_stretched_along_its_data_is_fitted_again_posed_as_the_other(tmp_path):
    """raw-102 of the heavy set (BMI 51, arms 12° from the body, the left hand resting on the
    thigh): the first shape-space fit stretched the left arm along the flank (arms' lengths
    1.25x apart; left hand 146 mm off the truth's in the end). That arm is fitted again from
    the fit with the other arm's pose mirrored onto it, and kept: closer arms' lengths within
    the tie margin."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.registration.quality import arm_symmetry
    from core.rig import axis_angle
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl = load_template()
    case = make_case(102, "raw")
    scan, _ = load_scan(case.write(tmp_path / "heavy.ply"))
    res = ml.fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)
    assert "arm L posed as arm R" in res.report.notes[-1], res.report.notes[-1]
    assert arm_symmetry(res.vertices) < 1.23  # measured 1.19 (1.28 without the refit)
    hand = tpl.part_mask("hand_L")
    off = np.linalg.norm(res.vertices[hand].mean(0) - truth[hand].mean(0)) * 1000
    assert off < 120.0, off  # measured 95 mm (146 without the refit): still placed badly
    assert res.report.quality.quality != "good"  # and the verdict still says so
    # the mirror turns a rotation about x the other way and keeps one about y
    Rx, Ry = axis_angle([1.0, 0.0, 0.0], 0.3), axis_angle([0.0, 1.0, 0.0], 0.3)
    assert np.allclose(ml.MIRROR_X @ Rx @ ml.MIRROR_X, Rx)
    assert np.allclose(ml.MIRROR_X @ Ry @ ml.MIRROR_X, Ry.T)


def test_hands_resting_on_the_thighs_are_placed_by_the_arms_not_the_thigh(tmp_path):
    """closed_booth-322 (booth software's closed mesh, both hands resting on the thighs and
    fused to them): the thigh's data and the first fit's hand landmarks pull the hands down and
    forward along the thigh (with them now: (y, z) offsets from the truth's (-20, +22) / (-11,
    +20) mm). In the round the resting hands take no data and no landmarks (a note says so),
    and the arms' data and the body prior place them: not down the thigh, nor forward on it."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl = load_template()
    case = make_case(322, "closed_booth")
    scan, _ = load_scan(case.write(tmp_path / "booth.ply"))
    res = ml.fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)
    assert any(n.startswith("hands resting on the body (L, R)") for n in res.report.notes)
    for side in "LR":
        hand = tpl.part_mask(f"hand_{side}")
        off = (res.vertices[hand].mean(0) - truth[hand].mean(0)) * 1000  # canonical: +y up
        # measured (y, z) (+3, +16) / (+5, +14), 17 / 15 mm off since the closed meshes' mouth
        # is closed (before: (+4, +14) / (+8, +13); ~2 cm higher, 23 / 26 mm, with their
        # forearms pulled to 0.135 of the stature instead of 0.145; the truth's 0.149)
        assert off[1] > -5.0 and off[2] < 18.0, (side, off)
        assert np.linalg.norm(off) < 30.0, (side, off)


def test_an_arm_fused_to_the_flank_keeps_a_forearm_of_a_human_length(tmp_path):
    """closed_booth-339 (BMI 40, arms touching the torso, hands fused to the thighs): the flank's
    data stretched the first fit's forearms to 0.18 of the stature (truth 0.137), hands 95 mm
    low. The soft-marker round's bone length prior holds them (the resting hands' forearms
    pulled to ``ARM_BONE_CENTRES``, 0.145, inside ``ARM_BONE_RATIOS``' band), and the hands come
    up."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.registration.shape_prior import ARM_BONE_CENTRES, LEG_BONE_RATIOS
    from core.rig import joint_positions, load_rig
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    tpl, rig = load_template(), load_rig()
    case = make_case(339, "closed_booth")
    scan, _ = load_scan(case.write(tmp_path / "booth.ply"))
    res = ml.fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)
    assert res.body_prior is not None
    rest = res.body_prior.rest
    J = joint_positions(rest)
    stature = rest[:, 1].max() - rest[:, 1].min()
    centre = ARM_BONE_CENTRES["lowerarm01"]
    for side in "LR":
        elbow, wrist = J[rig.index(f"lowerarm01.{side}")], J[rig.index(f"wrist.{side}")]
        ratio = np.linalg.norm(wrist - elbow) / stature
        assert abs(ratio - centre) < 0.005, (side, ratio)  # measured 0.147 (0.182 / 0.178 without)
        hand = tpl.part_mask(f"hand_{side}")
        off = np.linalg.norm(res.vertices[hand].mean(0) - truth[hand].mean(0)) * 1000
        # measured 30.5 / 25.7 mm (95 / 93 without; 18 / 6 with the centre at 0.135: this
        # truth's forearms, 0.137, are shorter than an adult's mean)
        assert off < 35.0, (side, off)
    # and its thighs (BMI 40: the shape space's fat slid the knees up) within their band
    lo = LEG_BONE_RATIOS["upperleg01"][0]
    for side in "LR":
        hip, knee = J[rig.index(f"upperleg01.{side}")], J[rig.index(f"lowerleg01.{side}")]
        ratio = np.linalg.norm(knee - hip) / stature
        assert ratio > lo - 0.005, (side, ratio)  # measured 0.209 (0.202 without the band)
    assert res.report.quality.quality != "good"  # hands fused to the thighs: it says so


def test_the_soft_marker_round_keeps_the_clavicles_near_rest(tmp_path):
    """closed_plate-15 (a closed mesh on a floor plate, BMI 33, arms 34° out): the first
    shape-space fit turned both clavicles ~33° and the upper arms back against them, the
    Acromions 83 / 84 mm off the truth's. The soft-marker round's clavicle prior
    (:data:`core.registration.shape_prior.CLAVICLE_PRIOR`) turns them back."""
    from scipy.spatial.transform import Rotation

    from core.io import load_scan
    from core.matching.markerless import fit_markerless
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    case = make_case(15, "closed_plate")
    scan, _ = load_scan(case.write(tmp_path / "plate.ply"))
    truth = scan.frame.to_canonical(case.truth)
    res = fit_markerless(scan)
    assert res.body_prior is not None
    lms = load_template().landmarks
    for side in "LR":
        turn = np.degrees(Rotation.from_matrix(res.body_prior.pose[f"clavicle.{side}"]).magnitude())
        assert turn < 15.0, (side, turn)  # measured 9.7 / 9.2° (33.1 / 32.5 without)
        i = lms[f"Acromion_{side}"]
        off = np.linalg.norm(res.vertices[i] - truth[i]) * 1000
        assert off < 78.0, (side, off)  # measured 69 / 71 mm (83 / 84 without)


def test_the_soft_marker_round_keeps_the_thighs_skin_from_sliding_down(tmp_path):
    """closed_booth-337 (a closed booth mesh, arms 48° out): the shape-space fit slid the upper
    thighs' skin 4-5 cm down the thigh (rest thighs 0.206 of the stature, truth's 0.230; legs
    30 mm off the truth's on average). The round's gentle pull of the thighs to their mean
    length (:data:`core.registration.shape_prior.LEG_BONE_CENTRES`) brings it back up."""
    from core.io import load_scan
    from core.matching.markerless import fit_markerless
    from core.registration.quality import part_labels
    from core.rig import joint_positions, load_rig
    from core.synth.scanner_outputs import make_case

    rig = load_rig()
    case = make_case(337, "closed_booth")
    scan, _ = load_scan(case.write(tmp_path / "booth.ply"))
    truth = scan.frame.to_canonical(case.truth)
    res = fit_markerless(scan)
    assert res.body_prior is not None
    rest = res.body_prior.rest
    J = joint_positions(rest, rig=rig)
    stature = rest[:, 1].max() - rest[:, 1].min()
    for side in "LR":
        hip, knee = J[rig.index(f"upperleg01.{side}")], J[rig.index(f"lowerleg01.{side}")]
        ratio = np.linalg.norm(knee - hip) / stature
        assert ratio > 0.215, (side, ratio)  # measured 0.222 (0.206 without the pull)
    labels, names = part_labels()
    legs = np.isin(labels, [names.index("leg_L"), names.index("leg_R")])
    off = np.linalg.norm(res.vertices[legs] - truth[legs], axis=1).mean() * 1000
    assert off < 27.0, off  # measured 22.6 mm (30.5 without)


def test_the_soft_marker_round_keeps_a_heavy_torsos_skin_from_sliding_down(tmp_path, monkeypatch):
    """closed_lowres-69 (BMI 49, a coarse closed mesh): the shape space's fat slid the waist's
    skin down the belly, the navel 80 mm and the iliac crests 92 mm off the truth's, the waist's
    spine joint 52 mm low. The round's trunk prior (:data:`core.registration.shape_prior.
    TRUNK_CHAINS`: each spine joint at its template share of the way from pelvis to neck)
    holds the waist up. Measured against the same fit without it (the torso's mean offset
    was 31.5 mm against 38.6 when the prior came; since the fists' fingers took data, hands
    35 -> 24 mm and legs 24 -> 30, it is 37.9 against 42.9; the navel 39 against 62 mm since
    the mesh's bridges take no data, ``core.registration.closed_concavities``). Since the round's
    shape prior weighs 400 data rows (:data:`core.matching.markerless.ROUND_SHAPE_PRIOR`) the
    torso is 28.5 mm off against 40.9 without the trunk prior (37.9 / 42.7 at 1), but the navel
    itself 50.4 against 57.1 (38.8 / 61.7 at 1; at 150 and 250 45.6 / 56.2 and 49.1 / 76.7:
    the fit without the trunk prior is the noisy one): the torso's bounds tightened, the navel's
    loosened, both recorded here."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.registration.quality import part_labels
    from core.synth.scanner_outputs import make_case
    from core.template import load_template

    fit_markerless = ml.fit_markerless
    case = make_case(69, "closed_lowres")
    scan, _ = load_scan(case.write(tmp_path / "heavy.ply"))
    truth = scan.frame.to_canonical(case.truth)
    i = load_template().landmarks["Omphalion"]
    labels, names = part_labels()
    torso = labels == names.index("torso")

    def errors(X: np.ndarray) -> tuple[float, float]:  # navel, torso mean (mm)
        navel = np.linalg.norm(X[i] - truth[i]) * 1000
        return float(navel), float(np.linalg.norm(X[torso] - truth[torso], axis=1).mean() * 1000)

    navel, off = errors(fit_markerless(scan).vertices)
    monkeypatch.setattr(ml, "TRUNK_PRIOR", 0.0)
    navel_free, off_free = errors(
        fit_markerless(load_scan(case.write(tmp_path / "h2.ply"))[0]).vertices
    )
    # measured 47.9 / 62.3 (50.4 / 57.1 before the round's point-to-point rows; 38.8 / 61.7 with
    # the round's shape prior at 1; 40 / 91 before the closed mesh's bridged navel took no data)
    assert navel < 55.0 and navel < navel_free - 5.0, (navel, navel_free)
    # measured 27.8 / 31.5: the round's point-to-point rows (ROUND_POINT_WEIGHT) hold the skin of
    # the fit without the trunk prior too (28.5 / 40.9 before them; 37.9 / 42.7 at shape prior 1)
    assert off < 30.0 and off < off_free - 2.5, (off, off_free)


def test_the_report_says_how_far_the_rounds_body_prior_moved_last(tmp_path, monkeypatch):
    """raw-0: the round's body prior from the landmarks' alignment and rest pose stopped after 12
    iterations still moving the body 2.6 mm per iteration (mean over its vertices); the report
    says so, and :data:`core.matching.markerless.ROUND_ITERATIONS` (24) settle it (0.24 mm)."""
    import core.matching.markerless as ml
    from core.io import load_scan
    from core.synth.scanner_outputs import make_case

    case = make_case(0, "raw")
    steps = []
    assert ml.ROUND_ITERATIONS > 12
    for iterations in (12, ml.ROUND_ITERATIONS):
        monkeypatch.setattr(ml, "ROUND_ITERATIONS", iterations)
        scan, _ = load_scan(case.write(tmp_path / f"raw-{iterations}.ply"))
        res = ml.fit_markerless(scan)
        assert res.body_prior is not None
        step = res.body_prior.last_step_m * 1000
        note = next(n for n in res.report.notes if n.startswith("markerless refinement:"))
        assert f"body prior moved the body {step:.2f} mm (mean) in its last iteration" in note
        steps.append(step)
    assert steps[1] < 1.0 < steps[0], steps  # measured 2.61 / 0.24 mm


def test_thighs_pressed_together_keep_the_body_priors_inner_skin_and_a_good_verdict(tmp_path):
    """raw-31 (feet 1 cm apart: the inner thighs pressed together, no skin in the scan there):
    the refinement drops the data that lies off the body prior's normal lines there instead of
    sliding the skin onto the thighs' fronts and backs, the report says how many vertices, and
    the quality check leaves them out of the legs' fit→scan p95 (the truth's own reads 39 mm).
    Counted, the legs read `suspect` and a retry kept a body 15.6 mm off the truth, its legs
    34 mm off (measured now: 6.6 mm, the legs' centroids 4 / 6 mm)."""
    from core.registration.quality import part_labels
    from core.synth.scanner_outputs import make_case
    from service.cli import run_fit

    case = make_case(31, "raw")
    # the CLI's path: its up axis read head-down is turned over, the truth with it
    scan, res, _ = run_fit(case.write(tmp_path / "raw.ply"), None, quiet=True)
    truth = scan.frame.to_canonical(case.truth)
    q = res.report.quality
    assert q is not None and q.parts["leg_L"].quality == q.parts["leg_R"].quality == "good"
    assert not any(n.startswith("quality retries") for n in res.report.notes)
    assert any("where the scan shows no skin over the body prior" in n for n in res.report.notes)
    corr = np.linalg.norm(res.vertices - truth, axis=1).mean() * 1000
    assert corr < 9.0, corr
    labels, names = part_labels()
    for leg in ("leg_L", "leg_R"):
        m = labels == names.index(leg)
        off = np.linalg.norm(res.vertices[m].mean(0) - truth[m].mean(0)) * 1000
        assert off < 15.0, (leg, off)


def test_a_body_tilted_in_a_handheld_scanners_frame_is_levelled_and_fitted(tmp_path):
    """closed_tilted-811: the body 16° off every file axis (a handheld scanner's frame). The
    frame levels it (the report's first note says by how much) and the markerless fit finds it
    (measured: 7.35 mm, good); without the levelling the search started it upright, and the
    fit ended 1 088 mm off the truth, `failed`."""
    from core.synth.scanner_outputs import make_case
    from core.template import load_template
    from service.cli import run_fit

    case = make_case(811, "closed_tilted")
    scan, res, _ = run_fit(case.write(tmp_path / "handheld.ply"), None, quiet=True)
    assert abs(scan.frame.tilt_deg - case.params["output"]["tilt_deg"]) < 3.0
    assert "the scan was levelled" in res.report.notes[0]
    truth = scan.frame.to_canonical(case.truth)
    lms = load_template().landmarks
    up = truth[lms["Vertex"]] - truth[lms["Calcaneus_posterior_L"]]
    assert np.degrees(np.arccos(up[1] / np.linalg.norm(up))) < 8.0  # the truth now upright
    q = res.report.quality
    assert q is not None and q.quality == "good", q.reasons
    corr = np.linalg.norm(res.vertices - truth, axis=1).mean() * 1000
    assert corr < 9.0, corr


def test_a_heavy_bodys_hole_filled_booth_mesh_is_fitted_standing_square(tmp_path):
    """closed_filled-901 (BMI 51, booth software's watertight mesh of its own raw scan,
    decimated to 13 k vertices): the markerless fit keeps the body upright on the levelled scan
    (``fit_body_prior(upright=True)``) and spreads its scan→body pairs by area on the decimated
    mesh. Before, the whole body stood rolled 10° and turned 15° with the spine and knees turned
    back against it: pelvis 7.6° and thighs 15-17.5° about the vertical off the truth's (their
    raw twin's 1-3°), correspondence 15.8 mm; measured now 2.9° / 6.6-7.5°, 13.9 mm."""
    from scipy.spatial.transform import Rotation

    from core.synth.scanner_outputs import make_case
    from core.template import load_template
    from service.cli import run_fit

    case = make_case(901, "closed_filled")
    scan, res, _ = run_fit(case.write(tmp_path / "booth.ply"), None, quiet=True)
    truth = scan.frame.to_canonical(case.truth)
    tpl = load_template()

    def turn(part: str) -> float:
        m = tpl.part_mask(part)
        a, b = res.vertices[m] - res.vertices[m].mean(0), truth[m] - truth[m].mean(0)
        return abs(float(np.degrees(Rotation.align_vectors(b, a)[0].as_rotvec()[1])))

    assert turn("pelvis") < 5.0, turn("pelvis")
    assert max(turn("thigh_L"), turn("thigh_R")) < 10.0, (turn("thigh_L"), turn("thigh_R"))
    assert np.linalg.norm(res.vertices - truth, axis=1).mean() * 1000 < 15.0


def test_a_scan_cut_below_the_crown_is_fitted_from_a_taller_start(realworld_case):
    """raw_headcut-1109 (a raw scan that ends 8 cm below the crown: a tall subject in a short
    scan volume). The search scales the template to the scan's height; from a body that short
    the fit bent the head down into the scan: 32.1 mm from the truth, the head 74 mm off,
    `failed`. A fit whose head fails is run again with the search's best rigid candidate also
    tried 4 % taller on the same soles (TALLER_START), the better kept: 4.4 mm, and the report
    says the crown is the body prior's guess."""
    from core.matching.markerless import fit_markerless
    from core.template import load_template

    case, scan, _ = realworld_case(1109, "raw_headcut")
    res = fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)  # the fit may have turned the scan over
    err = np.linalg.norm(res.vertices - truth, axis=1) * 1000
    head = load_template().part_mask("head")
    assert err.mean() < 10.0, err.mean()
    assert err[head].mean() < 15.0, err[head].mean()
    assert res.report.quality.quality != "failed", res.report.quality.reasons
    assert any("below the fitted crown" in w for w in res.report.warnings), res.report.warnings
    assert any(n.startswith("the head failed") and "kept" in n for n in res.report.notes)
    stature = np.ptp(res.vertices[:, 1]) * 1000
    assert abs(stature - np.ptp(truth[:, 1]) * 1000) < 25.0, stature
