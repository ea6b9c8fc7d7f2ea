"""The per-part quality check: a good fit reads good; a fit with a part moved, rotated or collapsed
does not, and the reasons name the part (thresholds: ``core.registration.quality``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.cases import make_case
from core.registration.fit import fit
from core.registration.quality import PART_FIGURES, PARTS, THRESHOLDS, assess_fit, part_labels
from core.registration.schedule import Schedule
from core.registration.shape_prior import PriorOptions
from core.serialize import json_ready
from core.template import load_template
from service.cli import EXIT_QUALITY_FAILED, quality_exit


@pytest.fixture(scope="module")
def case():
    return make_case(101, small=True)


@pytest.fixture(scope="module")
def fitted(case):
    return fit(case.scan, case.markers, schedule=Schedule.fast())


def _mask(part: str) -> np.ndarray:
    labels, names = part_labels()
    return labels == names.index(part)


def _neck_joint(X: np.ndarray) -> np.ndarray:
    """Centre of the head/neck boundary of body X (the point a head collapses towards)."""
    tpl = load_template()
    head, neck = tpl.part_mask("head"), tpl.part_mask("neck")
    E = tpl.edges
    b = (head[E[:, 0]] & neck[E[:, 1]]) | (neck[E[:, 0]] & head[E[:, 1]])
    return X[np.unique(E[b])].mean(axis=0)


def _ring(X: np.ndarray, a: str, b: str) -> np.ndarray:
    """Centre of the boundary between template parts ``a`` and ``b`` of body X (a joint)."""
    tpl = load_template()
    ma, mb, E = tpl.part_mask(a), tpl.part_mask(b), np.asarray(tpl.edges)
    m = (ma[E[:, 0]] & mb[E[:, 1]]) | (mb[E[:, 0]] & ma[E[:, 1]])
    return X[np.unique(E[m])].mean(axis=0)


def test_labels_cover_the_template_with_ten_parts():
    labels, names = part_labels()
    assert names == tuple(PARTS) and len(names) == 10
    assert labels.min() == 0 and labels.max() == 9
    # left and right are mirror images of each other
    tpl = load_template()
    left = _mask("arm_L")
    assert np.array_equal(np.sort(tpl.mirror[left]), np.flatnonzero(_mask("arm_R")))


def test_good_fit_and_truth_read_good(case, fitted):
    q = fitted.report.quality
    assert q is not None and q.quality == "good", q.reasons
    t = assess_fit(case.scan, case.truth)
    assert t.quality == "good", t.reasons
    for name, p in q.parts.items():
        assert p.scan_points >= 30, name
        assert p.scan_to_fit_p95_m < THRESHOLDS["scan_to_fit_p95_m"].suspect, name
    for r in (q, t):  # well inside the limits, each figure only on its part(s)
        assert r.parts["head"].head_turn_deg < THRESHOLDS["head_turn_deg"].suspect - 15
        assert r.parts["head"].head_distortion_m < THRESHOLDS["head_distortion_m"].suspect - 0.004
        for side in ("leg_L", "leg_R"):
            assert r.parts[side].leg_proportion < THRESHOLDS["leg_proportion"].suspect - 0.15
        assert r.parts["torso"].sternum_proportion < THRESHOLDS["sternum_proportion"].suspect - 0.2
        for key, parts in PART_FIGURES.items():
            assert all(np.isnan(getattr(p, key)) for k, p in r.parts.items() if k not in parts)
    # the report carries it, strict-JSON ready
    rep = json.loads(json.dumps(json_ready(fitted.report.to_dict()), allow_nan=False))
    assert rep["quality"]["quality"] == "good"
    assert set(rep["quality"]["parts"]) == set(PARTS)


@pytest.mark.parametrize("offset_m", [0.04, 0.10, 0.15])
def test_head_moved_forward_fails_naming_the_head(case, fitted, offset_m):
    X = fitted.vertices.copy()
    X[_mask("head")] += [0.0, 0.0, offset_m]
    q = assess_fit(case.scan, X)
    assert q.quality == "failed"
    assert q.parts["head"].quality == "failed"
    assert any(r.startswith("head:") for r in q.reasons)


@pytest.mark.parametrize("scale", [0.6, 0.3])
def test_head_collapsed_into_the_neck_fails(case, fitted, scale):
    X = fitted.vertices.copy()
    head = load_template().part_mask("head")
    c = _neck_joint(X)
    X[head] = c + (X[head] - c) * scale
    q = assess_fit(case.scan, X)
    assert q.quality == "failed", q.reasons
    assert q.parts["head"].quality == "failed"
    assert q.parts["head"].coverage < THRESHOLDS["coverage"].failed
    assert q.parts["torso"].quality == "good"


def _neck_base(X: np.ndarray) -> np.ndarray:
    """Centre of the neck/torso boundary of body X (the pivot of a head turned on its neck)."""
    tpl = load_template()
    neck, torso = tpl.part_mask("neck"), tpl.part_mask("torso")
    E = tpl.edges
    b = (torso[E[:, 0]] & neck[E[:, 1]]) | (neck[E[:, 0]] & torso[E[:, 1]])
    return X[np.unique(E[b])].mean(axis=0)


@pytest.mark.parametrize(
    ("pivot", "axis", "deg"),
    [("ears", "y", 45.0), ("ears", "y", 60.0), ("ears", "x", 45.0), ("neck", "x", 60.0)],
)
def test_head_turned_on_its_data_fails_naming_the_head(case, fitted, pivot, axis, deg):
    # a head fitted turned or flexed on the right surface (raw-19 of core.synth.scanner_outputs:
    # 58° off the truth's, 72 mm off, scan→fit p95 5 mm, `good` before head_turn_deg). Turned
    # about the ears the skull stays on its data: without head_turn_deg the copies turned 45-60°
    # about the vertical read only suspect (scan→fit p95 19-24 mm, coverage 0.81-0.85)
    X = fitted.vertices.copy()
    lm = load_template().landmarks
    if pivot == "ears":
        head = load_template().part_mask("head")
        c = 0.5 * (X[lm["Tragion_L"]] + X[lm["Tragion_R"]])
    else:
        head = _mask("head")  # head and neck, about the neck's base
        c = _neck_base(X)
    R = Rotation.from_euler(axis, deg, degrees=True).as_matrix()
    X[head] = (X[head] - c) @ R.T + c
    q = assess_fit(case.scan, X)
    assert q.quality == "failed" and q.parts["head"].quality == "failed", q.reasons
    assert q.parts["head"].head_turn_deg > THRESHOLDS["head_turn_deg"].failed
    assert any(r.startswith("head: turned") for r in q.reasons), q.reasons
    assert q.parts["torso"].quality == "good"


def test_head_figures_do_not_hang_on_a_few_landmark_vertices(case, fitted):
    # a marker fit's tragion/sellion vertices follow the user's markers (other conventions move
    # them by centimetres): the head figures come from all the head's vertices, so marker fits
    # are judged too (the former landmark-frame head turn read 32-174° on correct marker fits)
    tpl = load_template()
    lm = tpl.landmarks
    X = fitted.vertices.copy()
    E = np.asarray(tpl.edges)
    ids = np.array([lm["Tragion_L"], lm["Tragion_R"], lm["Sellion"]])
    ring = np.unique(E[np.isin(E, ids).any(axis=1)])  # the landmarks and their neighbours
    X[ring] += np.array([0.0, 0.03, 0.03])
    q0, q = fitted.report.quality.parts["head"], assess_fit(case.scan, X).parts["head"]
    assert abs(q.head_turn_deg - q0.head_turn_deg) < 2.0
    assert q.head_distortion_m < THRESHOLDS["head_distortion_m"].suspect
    assert q.quality == "good"


def _slid_along_the_scan(case, X: np.ndarray, mask: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """X with the vertices ``mask`` moved by ``shift`` (n, 3) and put back on the scan (the
    nearest scan point's tangent plane): the surface stays on its data, the vertices slide."""
    from scipy.spatial import cKDTree

    Y = X.copy()
    P = Y[mask] + shift
    j = cKDTree(case.scan.V).query(P)[1]
    n = case.scan.normals[j]
    Y[mask] = P - np.einsum("nc,nc->n", P - case.scan.V[j], n)[:, None] * n
    return Y


@pytest.mark.parametrize(("slide_m", "verdict"), [(0.04, "suspect"), (0.07, "failed")])
def test_head_whose_face_slid_down_the_skull_is_not_good(case, fitted, slide_m, verdict):
    # bench.realworld --markers closed_touching-17: the fitted face slid down along the skull's
    # data (sellion 59 mm, menton 66 mm, the crown 14 mm below the truth's; head 53 mm off),
    # scan->fit p95 7 mm, fit->scan p95 12 mm, coverage 0.80: `good` before head_distortion_m
    # (19.8 mm there). Here the face slides slide_m down, the back of the head stays (sellion
    # 27 and 50 mm; 0.04 reads 14.7 mm, 0.07 20.2 mm)
    tpl = load_template()
    X = fitted.vertices.copy()
    head = tpl.part_mask("head")
    lm = tpl.landmarks
    ears = 0.5 * (X[lm["Tragion_L"]] + X[lm["Tragion_R"]])
    front = X[lm["Pronasale"]]
    fwd = (front - ears) / np.linalg.norm(front - ears)
    w = np.clip((X[head] - ears) @ fwd / ((front - ears) @ fwd), 0.0, 1.0)
    Y = _slid_along_the_scan(case, X, head, -slide_m * w[:, None] * np.array([0.0, 1.0, 0.0]))
    q = assess_fit(case.scan, Y)
    p = q.parts["head"]
    # on its data: the figures that see a part off its data do not see it
    assert p.fit_to_scan_p95_m < THRESHOLDS["fit_to_scan_p95_m"].suspect
    assert p.coverage > THRESHOLDS["coverage"].suspect
    assert p.scan_to_fit_p95_m < THRESHOLDS["scan_to_fit_p95_m"].suspect
    assert p.head_distortion_m > getattr(THRESHOLDS["head_distortion_m"], verdict), p
    assert p.quality == verdict and q.quality == verdict, q.reasons
    assert any(r.startswith("head: its shape") for r in q.reasons), q.reasons
    assert q.parts["torso"].quality == "good"


@pytest.mark.parametrize(("lift_m", "verdict"), [(0.08, "suspect"), (0.13, "failed")])
def test_torso_skin_slid_up_the_trunk_is_not_good_naming_the_torso(case, fitted, lift_m, verdict):
    # bench.realworld --palms raw_palms-605 (BMI 45, markerless): the shape-space fit slid the
    # chest's skin up the trunk on its data (Substernale 137 mm, nipples 28 cm up, above the
    # Suprasternale; torso centroid 47 mm off the truth's), every figure `good`: 1.83 there.
    # Here the front of the trunk between navel and notch slides up by lift_m at the sternum's
    # end, tapering to 0 at both (8 cm: 1.4-1.6, 13 cm: above 1.6)
    tpl = load_template()
    L = tpl.landmarks
    X = fitted.vertices.copy()
    navel, sub, notch = (X[L[n]][1] for n in ("Omphalion", "Substernale", "Suprasternale"))
    torso = tpl.part_mask("torso")
    front = torso & (X[:, 2] > X[torso, 2].mean()) & (X[:, 1] > navel) & (X[:, 1] < notch)
    y = X[front, 1]
    w = np.where(y < sub, (y - navel) / (sub - navel), (notch - y) / (notch - sub))
    Y = _slid_along_the_scan(case, X, front, lift_m * w[:, None] * np.array([0.0, 1.0, 0.0]))
    q = assess_fit(case.scan, Y)
    p = q.parts["torso"]
    assert p.sternum_proportion > getattr(THRESHOLDS["sternum_proportion"], verdict), p
    assert p.quality == verdict and q.quality == verdict, q.reasons
    assert any(r.startswith("torso: the sternum") for r in q.reasons), q.reasons


@pytest.mark.parametrize(("drop_m", "verdict"), [(0.10, "suspect"), (0.20, "failed")])
def test_crotch_slid_down_the_legs_is_not_good_naming_the_legs(case, fitted, drop_m, verdict):
    # bench.realworld raw-31 (feet 1 cm apart, markerless): the pelvis slid down over the
    # touching thighs (crotch 208 mm, hip rings 114 mm, knees 44 mm below the truth's, ankles in
    # place; legs 70 mm off) on the legs' data: legs `good` before leg_proportion (1.59 there).
    # Here the pelvis and thighs slide down by drop_m at the crotch, tapering to 0 at the knees
    # (10 cm reads 1.27-1.33, 20 cm 1.71-1.89; the truths' own proportions reach 1.21)
    tpl = load_template()
    X = fitted.vertices.copy()
    mask = tpl.part_mask("pelvis") | tpl.part_mask("thigh_L") | tpl.part_mask("thigh_R")
    crotch = X[tpl.landmarks["Crotch"]][1]
    knee = 0.5 * (X[tpl.landmarks["Patella_L"]][1] + X[tpl.landmarks["Patella_R"]][1])
    w = np.clip((X[mask, 1] - knee) / (crotch - knee), 0.0, 1.0)
    Y = _slid_along_the_scan(case, X, mask, -drop_m * w[:, None] * np.array([0.0, 1.0, 0.0]))
    q = assess_fit(case.scan, Y)
    legs = [q.parts[side] for side in ("leg_L", "leg_R")]
    assert max(p.leg_proportion for p in legs) > getattr(THRESHOLDS["leg_proportion"], verdict)
    assert q.quality == verdict, q.reasons
    assert any(r.split(":")[0] in ("leg_L", "leg_R") for r in q.reasons), q.reasons
    if verdict == "failed":
        assert all(p.quality == "failed" for p in legs), q.reasons


@pytest.mark.parametrize("deg", [10.0, 25.0])
def test_arm_swung_out_of_its_data_is_not_good(case, fitted, deg):
    X = fitted.vertices.copy()
    arm = _mask("arm_L") | _mask("hand_L")
    top = X[load_template().part_mask("upper_arm_L")]
    shoulder = top[np.argmax(top[:, 1])]
    R = Rotation.from_euler("z", deg, degrees=True).as_matrix()
    X[arm] = (X[arm] - shoulder) @ R.T + shoulder
    q = assess_fit(case.scan, X)
    assert q.quality == "failed"
    assert q.parts["arm_L"].quality == "failed" and q.parts["arm_R"].quality == "good"
    assert any(r.startswith("arm_L:") for r in q.reasons)


@pytest.mark.parametrize("slide_m", [0.05, 0.10, 0.20])
def test_hand_slid_up_the_forearm_fails_naming_the_hand(case, fitted, slide_m):
    # the hand moved towards the elbow along the forearm axis: it sits on the forearm's data
    # (coverage and fit->scan look fine) and leaves the real hand's scan points beyond it
    tpl = load_template()
    X = fitted.vertices.copy()
    E = np.asarray(tpl.edges)
    fore = tpl.part_mask("forearm_R")

    def ring(other: np.ndarray) -> np.ndarray:
        b = (fore[E[:, 0]] & other[E[:, 1]]) | (other[E[:, 0]] & fore[E[:, 1]])
        return X[np.unique(E[b])][fore[np.unique(E[b])]].mean(axis=0)

    axis = ring(tpl.part_mask("hand_R")) - ring(tpl.part_mask("upper_arm_R"))
    X[_mask("hand_R")] -= slide_m * axis / np.linalg.norm(axis)
    q = assess_fit(case.scan, X)
    assert q.quality == "failed", q.reasons
    assert q.parts["hand_R"].quality == "failed" and q.parts["hand_L"].quality == "good"
    assert any(r.startswith("hand_R:") for r in q.reasons)
    beyond = THRESHOLDS["data_beyond_m"]
    assert q.parts["hand_R"].data_beyond_m > (beyond.failed if slide_m >= 0.1 else beyond.suspect)
    assert q.parts["hand_R"].hand_proportion > THRESHOLDS["hand_proportion"].failed


def test_hands_of_good_fits_and_truths_sit_at_the_arms_end(case, fitted):
    for X in (fitted.vertices, case.truth):
        q = assess_fit(case.scan, X)
        for side in ("hand_L", "hand_R"):
            p = q.parts[side]
            assert p.data_beyond_m < THRESHOLDS["data_beyond_m"].suspect
            assert p.hand_bend_deg < THRESHOLDS["hand_bend_deg"].suspect
            assert p.hand_proportion < THRESHOLDS["hand_proportion"].suspect


def test_lifted_foot_is_not_good(case, fitted):
    X = fitted.vertices.copy()
    X[_mask("foot_R")] += [0.0, 0.03, 0.0]
    q = assess_fit(case.scan, X)
    assert q.quality in ("suspect", "failed")
    assert q.parts["foot_R"].quality != "good" and q.parts["foot_L"].quality == "good"


def test_failed_quality_exits_3_and_says_why(case, fitted, capsys):
    assert quality_exit(fitted) == 0
    assert "quality: good" in capsys.readouterr().err
    X = fitted.vertices.copy()
    X[_mask("head")] += [0.0, 0.0, 0.12]
    fitted.report.quality, good = assess_fit(case.scan, X), fitted.report.quality
    try:
        assert quality_exit(fitted) == EXIT_QUALITY_FAILED == 3
        err = capsys.readouterr().err.strip()
        assert err.startswith("bodyspace: quality: failed (head:") and "\n" not in err
    finally:
        fitted.report.quality = good


def test_rejects_a_body_of_the_wrong_shape(case):
    with pytest.raises(ValueError, match="13380"):
        assess_fit(case.scan, np.zeros((10, 3)))


def test_lost_head_is_retried_and_recovered_or_reported(case):
    # the head markers agree with each other but sit 12 cm in front of the face: the first fit
    # follows them off the scan; the retries (markers trusted, then the lost part weighted with
    # scan→body pairs) must bring the head back, or the verdict must name it
    names = (
        "Vertex", "Pronasale", "Sellion", "Glabella", "Menton", "Supramenton", "Opisthocranion",
        "Tragion_L", "Tragion_R", "Infraorbitale_L", "Infraorbitale_R",
    )  # fmt: skip
    m = {k: v + np.array([0.0, 0.0, 0.12]) if k in names else v for k, v in case.markers.items()}
    head = load_template().part_mask("head")
    first = fit(case.scan, m, schedule=Schedule.fast(), retry=False)
    assert first.report.quality.parts["head"].quality != "good"  # the check sees the lost head
    res = fit(case.scan, m, schedule=Schedule.fast())
    q = res.report.quality
    assert any(n.startswith("quality retries: first fit: ") for n in res.report.notes)
    err = np.linalg.norm(res.vertices[head] - case.truth[head], axis=1)
    if q.quality == "good":
        assert err.mean() < 0.015 and q.parts["head"].scan_to_fit_p95_m < 0.006
    else:
        assert any(r.startswith("head:") for r in q.reasons)


def _real_world_case(tmp_path, kind, seed):
    """A ``core.synth.scanner_outputs`` case loaded as the CLI does: (scan, markers, truth)."""
    from core.io import load_scan
    from core.synth.scanner_outputs import make_case as make_real_case

    case = make_real_case(seed, kind)
    scan, markers = load_scan(
        case.write(tmp_path / "scan.ply"), markers_path=case.write_markers(tmp_path / "m.csv")
    )
    return scan, markers, scan.frame.to_canonical(case.truth)


def _hand_offsets(X: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    tpl = load_template()
    return {
        s: float(np.linalg.norm(X[tpl.part_mask(s)].mean(0) - truth[tpl.part_mask(s)].mean(0)))
        for s in ("hand_L", "hand_R")
    }


@pytest.mark.parametrize(("kind", "seed"), [("closed_hair", 1), ("closed_touching", 5)])
def test_lost_hand_of_a_real_world_case_is_failed_and_named(tmp_path, kind, seed):
    # core.synth.scanner_outputs cases whose fast marker fit without the arm bones' pose prior
    # (bone_prior=(), the prior before it; other team's marker convention, no retries) puts a
    # hand 20-27 cm off the truth: the verdict must fail and name that hand. (cloud-6 was one;
    # since the toes of finely sampled scans take data its hand stays 9 cm off: closed_touching-5,
    # its left hand 20 cm off, took its place.)
    scan, markers, truth = _real_world_case(tmp_path, kind, seed)
    po = PriorOptions(bone_prior=())
    res = fit(scan, markers, schedule=Schedule.fast(), retry=False, prior_options=po)
    q = res.report.quality
    lost = [s for s, d in _hand_offsets(res.vertices, truth).items() if d > 0.10]
    for side in lost:
        assert q.parts[side].quality == "failed", (side, q.reasons)
        assert any(r.startswith(f"{side}:") for r in q.reasons)
    if not lost:  # the fitter changed: this case no longer exercises the check
        pytest.skip(f"{kind} seed {seed}: no hand > 10 cm off the truth any more; pick another")
    assert q.quality == "failed"


def test_arm_bones_prior_keeps_the_hands_of_a_real_world_case(tmp_path):
    # closed_hair seed 1 (arms 10° out, hands by the thighs): without the prior on the wrists'
    # and elbows' total rotation its fast fit bends a wrist 139° and puts that hand 27 cm off the
    # truth (test above); with it (the default) both hands stay within 5 cm and are not failed
    scan, markers, truth = _real_world_case(tmp_path, "closed_hair", 1)
    res = fit(scan, markers, schedule=Schedule.fast(), retry=False)
    q = res.report.quality
    off = _hand_offsets(res.vertices, truth)
    assert max(off.values()) < 0.05, off
    assert q.parts["hand_L"].quality != "failed" and q.parts["hand_R"].quality != "failed"


def test_lost_hand_is_retried_from_another_arm_start_and_recovered(tmp_path):
    # cloud seed 6 (arms 9° out): even with the arm bones' prior the first fast fit puts the left
    # hand 16 cm off the truth (the upper arm, started at the template's 40°, swings onto the
    # thigh's data) and fails; the retry that starts that arm 10° out brings it back
    scan, markers, truth = _real_world_case(tmp_path, "cloud", 6)
    res = fit(scan, markers, schedule=Schedule.fast())
    note = res.report.notes[-1]
    assert note.startswith("quality retries: first fit: failed; arms started 10° out: "), note
    q = res.report.quality
    assert _hand_offsets(res.vertices, truth)["hand_L"] < 0.05
    assert q.parts["hand_L"].quality != "failed", q.reasons
    # the head of this marker fit is turned (36-37° against the torso, 39 mm off the truth's in
    # bench.realworld --markers): failed for it, not for the hand
    head = _mask("head")
    head_off = np.linalg.norm(res.vertices[head].mean(0) - truth[head].mean(0))
    failed = {k for k, p in q.parts.items() if p.quality == "failed"}
    assert failed <= {"head"} and (not failed or head_off > 0.03), (q.reasons, head_off)


@pytest.mark.parametrize(("stretch_m", "level"), [(0.05, "suspect"), (0.08, "failed")])
def test_arm_stretched_along_its_data_is_not_good_naming_the_arms(case, fitted, stretch_m, level):
    # bench.realworld --heavy raw-102 (BMI 51, arms 12° along the body): the left forearm
    # stretched down the side (hand 124 mm, forearm 54 mm below the truth's) with every figure of
    # arm and hand in range (hand coverage 0.58, tip gap 29 mm); arm_symmetry 1.18 there, the
    # truths 1.00 (the generator's arms are alike; real people's differ by ~1-2 %). Here the
    # left forearm stretches by stretch_m (0 at the elbow, all of it at the wrist), the hand
    # moves with it, both slid back onto the scan (0.05 reads 1.11, 0.08 1.18)
    tpl = load_template()
    X = fitted.vertices.copy()
    fore, hand = tpl.part_mask("forearm_L"), tpl.part_mask("hand_L")
    elbow, wrist = _ring(X, "forearm_L", "upper_arm_L"), _ring(X, "forearm_L", "hand_L")
    axis = (wrist - elbow) / np.linalg.norm(wrist - elbow)
    mask = fore | hand
    t = np.clip((X[mask] - elbow) @ axis / np.linalg.norm(wrist - elbow), 0.0, 1.0)
    Y = _slid_along_the_scan(case, X, mask, stretch_m * t[:, None] * axis)
    q = assess_fit(case.scan, Y)
    arms = [q.parts[side] for side in ("arm_L", "arm_R")]
    assert fitted.report.quality.parts["arm_L"].arm_symmetry < 1.03
    assert min(p.arm_symmetry for p in arms) > getattr(THRESHOLDS["arm_symmetry"], level)
    assert q.quality != "good", q.reasons
    assert all(p.quality == level for p in arms), q.reasons
    assert any(r.startswith("arm_L: the arms' lengths differ") for r in q.reasons), q.reasons


@pytest.mark.parametrize(("deg", "level"), [(50.0, "suspect"), (100.0, "failed")])
def test_foot_turned_off_forward_is_not_good_naming_the_foot(case, fitted, deg, level):
    # closed_lowres-4 of core.synth.scanner_outputs meshed on a 17 mm grid (8 k vertices, feet 2
    # cm apart): the left foot fitted turned 100° inwards (135 mm off the truth's), the verdict
    # only `suspect` from the feet's unexplained data. Here the left foot turns deg about the
    # vertical through its ankle (the shin/foot ring)
    X = fitted.vertices.copy()
    foot = load_template().part_mask("foot_L")
    ankle = _ring(X, "foot_L", "shin_L")
    R = Rotation.from_euler("y", deg, degrees=True).as_matrix()
    X[foot] = (X[foot] - ankle) @ R.T + ankle
    q = assess_fit(case.scan, X)
    assert fitted.report.quality.parts["foot_L"].foot_turn_deg < 15.0
    assert abs(q.parts["foot_L"].foot_turn_deg - deg) < 5.0
    assert q.parts["foot_R"].foot_turn_deg < 15.0
    assert q.parts["foot_L"].foot_turn_deg > getattr(THRESHOLDS["foot_turn_deg"], level)
    rank = ("good", "suspect", "failed")  # off its data, coverage may fail it too
    assert rank.index(q.parts["foot_L"].quality) >= rank.index(level), q.reasons
    assert q.parts["foot_R"].quality == "good", q.reasons
    assert any(r.startswith("foot_L: turned") for r in q.reasons), q.reasons


def test_legs_crossed_onto_each_others_feet_fail_naming_the_feet(case, fitted):
    # bench.realworld --heavy raw-59 (BMI 47): the legs crossed, each foot on the other's data
    # (feet 139-162 mm off the truth's, pointing forward, scan->fit p95 7-24 mm): `suspect` from
    # the legs' unexplained data only; its feet read -0.15 m apart, the truth's +0.15. Here the
    # feet swap places (each moved by the other's centroid offset), the legs stay
    tpl = load_template()
    X = fitted.vertices.copy()
    fl, fr = tpl.part_mask("foot_L"), tpl.part_mask("foot_R")
    d = X[fl].mean(axis=0) - X[fr].mean(axis=0)
    d[1] = 0.0
    X[fl] -= d
    X[fr] += d
    q = assess_fit(case.scan, X)
    assert fitted.report.quality.parts["foot_L"].feet_apart_m > 0.1
    assert q.parts["foot_L"].feet_apart_m < -0.1
    assert q.parts["foot_L"].quality == q.parts["foot_R"].quality == "failed", q.reasons
    assert any(r.startswith("foot_L: the left foot's centre is") for r in q.reasons), q.reasons


def test_hand_resting_on_the_body_is_unresolved_not_misfitted(tmp_path, case, fitted):
    # booth meshes with the arms fused to the torso (bench.realworld --booth) put hands 45-136 mm
    # off the truth's with every other hand figure in range: a hand resting on the thigh is
    # fused with it in the data. The truth of such a case reads its hands suspect for that
    # alone (unresolved: no retry can place them better); hands held out from the body do not
    scan, _, truth = _real_world_case(tmp_path, "closed_booth", 309)  # hands on the thighs
    q = assess_fit(scan, truth)
    lim = THRESHOLDS["hand_body_gap_m"].suspect
    for side in ("hand_L", "hand_R"):
        p = q.parts[side]
        assert p.hand_body_gap_m < lim and p.quality == "suspect", (side, q.reasons)
        assert any(r.startswith(f"{side}: rests on the torso or thigh") for r in q.reasons)
    assert set(q.unresolved) == {"hand_L", "hand_R"}
    assert not set(q.weak_parts()) & {"hand_L", "hand_R"}
    for X in (fitted.vertices, case.truth):  # arms out (bench.cases' A-pose): far from the body
        r = assess_fit(case.scan, X)
        assert min(r.parts[s].hand_body_gap_m for s in ("hand_L", "hand_R")) > 3 * lim
        assert r.unresolved == []


def test_a_hand_missing_from_the_scan_is_named_missing_not_a_fist(tmp_path):
    """closed_lowres-8 with its left hand cut off (every scan point within 3 cm of the truth's
    hand removed: an amputee, or a hand out of the scanner's view): the markerless fit fails
    that hand as missing from the scan, without the fist hint (no hand was scanned), and keeps
    the other hand's and the rest's verdicts."""
    from scipy.spatial import cKDTree

    from core.io import load_scan, write_ply
    from core.matching.markerless import fit_markerless
    from core.synth.scanner_outputs import make_case

    tpl = load_template()
    case = make_case(8, "closed_lowres")  # mm, +Y up
    far = cKDTree(case.truth[tpl.part_mask("hand_L")]).query(case.V)[0] > 30.0
    new = np.cumsum(far) - 1
    F = new[case.F[far[case.F].all(axis=1)]]
    path = tmp_path / "no-left-hand.ply"
    write_ply(path, case.V[far], F)
    scan, _ = load_scan(path)
    q = fit_markerless(scan).report.quality
    hand = [r for r in q.reasons if r.startswith("hand_L:")]
    assert q.parts["hand_L"].quality == "failed", q.reasons
    assert hand[0].startswith("hand_L: only 0 scan points near it (missing from the scan"), hand
    assert not any("fitted to a fist" in r for r in hand), hand
    assert q.parts["hand_R"].quality != "failed" and q.parts["torso"].quality == "good", q.reasons


def test_skin_the_scan_does_not_show_is_left_out_of_fit_to_scan_unless_most_of_the_part(
    case, fitted
):
    """``assess_fit(unseen=)``: vertices the refinement found no skin over (thighs pressed
    together, ``bench.realworld`` raw-31) are left out of their part's fit→scan p95 while they
    are few (:data:`MAX_UNSEEN_SHARE`); a part mostly without skin over it is misplaced, and
    every vertex counts."""
    from core.geometry import vertex_normals
    from core.registration.quality import MAX_UNSEEN_SHARE

    tpl = load_template()
    X = fitted.vertices.copy()
    leg = np.flatnonzero(_mask("leg_L"))
    # the inner tenth of the left leg (nearest the body's midline) pushed 4 cm into the body
    mid = X[:, 0].mean()
    inner = leg[np.argsort(np.abs(X[leg, 0] - mid))[: len(leg) // 10]]
    N = vertex_normals(X, np.asarray(tpl.F, np.int64))
    Y = X.copy()
    Y[inner] -= 0.04 * N[inner]
    unseen = np.zeros(len(X), bool)
    unseen[inner] = True
    counted = assess_fit(case.scan, Y).parts["leg_L"].fit_to_scan_p95_m
    left_out = assess_fit(case.scan, Y, unseen=unseen).parts["leg_L"].fit_to_scan_p95_m
    assert counted > THRESHOLDS["fit_to_scan_p95_m"].suspect, counted
    assert left_out < 0.3 * THRESHOLDS["fit_to_scan_p95_m"].suspect, left_out
    # the whole leg 4 cm off its data, all of it unseen: every vertex counts, not good
    Z = X.copy()
    Z[leg] += [0.0, 0.0, 0.04]
    whole = np.zeros(len(X), bool)
    whole[leg] = True
    assert whole[leg].mean() > MAX_UNSEEN_SHARE
    q = assess_fit(case.scan, Z, unseen=whole)
    assert q.parts["leg_L"].fit_to_scan_p95_m > THRESHOLDS["fit_to_scan_p95_m"].suspect
    assert q.parts["leg_L"].quality != "good", q.reasons


def test_a_closed_meshs_mitten_over_a_hand_kept_from_the_body_prior_is_allowed_its_webbing(
    case, fitted
):
    """A closed mesh's fused mitten lies outside a hand the refinement keeps from the body
    prior (``closed_concavities.mitten_hands``), its webbing between thumb and fingers as far
    as the mesh's closing ball reaches: scan points 18 mm off the left hand make it `suspect`,
    unless it is a mitten of a mesh closed by a 12 mm ball (``mittens``, ``mitten_m``); the
    right hand, not a mitten, is judged as ever."""
    from dataclasses import replace

    from core.geometry import vertex_normals

    tpl = load_template()
    X = fitted.vertices
    N = vertex_normals(X, np.asarray(tpl.F, np.int64))
    rng = np.random.default_rng(0)
    webs = []
    for side in "LR":
        hand = np.flatnonzero(tpl.part_mask(f"hand_{side}"))
        pick = rng.choice(hand, len(hand) // 5, replace=False)
        webs.append((X[pick] + 0.018 * N[pick], N[pick]))
    P = np.concatenate([case.scan.V] + [w[0] for w in webs])
    scan = replace(
        case.scan,
        V=P,
        F=None,
        normals=np.concatenate([case.scan.normals] + [w[1] for w in webs]),
        confidence=np.ones(len(P)),
        boundary=np.zeros(len(P), bool),
    )
    plain = assess_fit(scan, X)
    assert plain.parts["hand_L"].quality == plain.parts["hand_R"].quality == "suspect"
    assert any(r.startswith("hand_L: scan→fit p95") for r in plain.reasons), plain.reasons
    mitten = assess_fit(scan, X, mittens="L", mitten_m=0.012)
    assert mitten.parts["hand_L"].quality == "good", mitten.reasons
    assert mitten.parts["hand_R"].quality == "suspect"
    assert mitten.parts["hand_L"].scan_to_fit_p95_m == plain.parts["hand_L"].scan_to_fit_p95_m


@pytest.mark.parametrize("layers", [True, False])
def test_a_scan_recording_the_head_twice_is_suspect_without_a_retry_unlike_a_head_off_its_data(
    case, fitted, layers
):
    """The head's scan points recorded twice, 12 mm out and 12 mm in along the fit's normals
    (a subject who moved between a sequential scan's views): the scan's own spread there reads
    them, the head stays `suspect` with the layers as its reason and is unresolved (no quality
    retry can explain both layers); the same points all moved 12 mm out (the fit off its data)
    read no spread and leave the head a weak part, as ever."""
    from dataclasses import replace

    from scipy.spatial import cKDTree

    from core.geometry import vertex_normals
    from core.registration.quality import SPREAD_NOISE_M, spread_warning

    tpl = load_template()
    X = fitted.vertices
    N = vertex_normals(X, np.asarray(tpl.F, np.int64))
    V = np.asarray(case.scan.V)
    _, nv = cKDTree(X).query(V)
    head = _mask("head")[nv]
    off = 0.012 * N[nv[head]]
    moved = [V[head] + off, V[head] - off] if layers else [V[head] + off]
    P = np.concatenate([V[~head], *moved])
    normals = np.asarray(case.scan.normals)
    n = np.concatenate([normals[~head]] + [normals[head]] * len(moved))
    scan = replace(case.scan, V=P, F=None, normals=n, confidence=np.ones(len(P)),
                   boundary=np.zeros(len(P), bool))  # fmt: skip
    q = assess_fit(scan, X)
    h = q.parts["head"]
    assert h.quality == "suspect", q.reasons
    assert h.scan_to_fit_p95_m > THRESHOLDS["scan_to_fit_p95_m"].suspect
    assert q.parts["torso"].scan_spread_m < SPREAD_NOISE_M
    warning = spread_warning(q)  # the report's warning of a thick scan
    if layers:
        assert h.scan_spread_m > 0.008
        assert "head" in q.unresolved and "head" not in q.weak_parts()
        assert any(r.startswith("head:") and "own spread" in r for r in q.reasons), q.reasons
        assert warning is not None and "surface is thick" in warning and "head" in warning
        assert "torso" not in warning
    else:
        assert h.scan_spread_m < SPREAD_NOISE_M
        assert "head" in q.weak_parts()
        assert not any("own spread" in r for r in q.reasons), q.reasons
        assert warning is None
