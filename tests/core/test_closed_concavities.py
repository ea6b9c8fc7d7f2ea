"""A closed mesh's bridged gaps: its closing radius, the body's vertices under the bridges, and
the fit taking those from the body prior (``core.registration.closed_concavities``)."""

from __future__ import annotations

import numpy as np
import pytest


def test_a_closed_mesh_reads_its_closing_radius_a_raw_scan_none(realworld_case):
    """closed_lowres-0 (closed with a 10-14 mm ball, 19 k vertices): a ball of 8 mm or more
    reaches its whole surface; its raw twin's armpits, ears and fingers stop even a 4 mm ball
    (measured: closed meshes 0.1 % of the points unreached at 8 mm, raw scans 8 %)."""
    from core.registration.correspondence import ScanIndex

    _, closed, _ = realworld_case(0, "closed_lowres")
    _, raw, _ = realworld_case(0, "raw")
    assert ScanIndex(closed).closing_radius_m >= 0.008
    assert ScanIndex(raw).closing_radius_m == 0.0


def test_a_scan_with_holes_has_no_closing_radius():
    """The held-in simulated scans (``bench.cases``, small: 6 mm sampling, 17 % of the points on
    hole boundaries) are sampled too sparsely to show a ball's way into their concavities (they
    read 14 mm by the ball alone), but their holes say no software closed them."""
    from bench.cases import make_case
    from core.registration.closed_concavities import scan_closing_radius
    from core.registration.correspondence import ScanIndex

    index = ScanIndex(make_case(3, small=True).scan)
    assert index.boundary.mean() > 0.1
    assert index.closing_radius_m == 0.0
    by_ball = scan_closing_radius(index.points, index.normals, index.tree, index.spacing_m)
    assert by_ball >= 0.008  # the ball alone is fooled: the holes decide


def _sphere(n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere of radius 0.1 m, outward-wound: (V, F)."""
    th, ph = np.meshgrid(np.linspace(0.05, np.pi - 0.05, n), np.linspace(0, 2 * np.pi, n + 1)[:-1])
    V = 0.1 * np.c_[np.sin(th.ravel()) * np.cos(ph.ravel()), np.cos(th.ravel()),
                    np.sin(th.ravel()) * np.sin(ph.ravel())]  # fmt: skip
    F = []
    for j in range(n):
        for i in range(n - 1):
            a, b = j * n + i, ((j + 1) % n) * n + i
            F += [(a, b, a + 1), (b, b + 1, a + 1)]
    return V, np.array(F)


def test_closed_over_marks_the_bodys_narrow_gaps_not_its_open_surface(realworld_case):
    """On a true body (raw-0's): a 10 mm ball cannot reach between the fingers (a fifth of
    their vertices) nor into the face's and toes' folds (a quarter of the head's), but reaches
    the neck, forearms and shins everywhere and all but the armpits and crotch of the torso,
    upper arms and thighs; on a sphere (convex) it reaches everything; ``vertices=`` tests only
    those, with the same verdicts."""
    from core.geometry import vertex_normals
    from core.registration.closed_concavities import closed_over
    from core.template import load_template

    tpl = load_template()
    F = np.asarray(tpl.F, np.int64)
    _, _, truth = realworld_case(0, "raw")
    m = closed_over(truth, F, 0.010)
    fingers = np.asarray(tpl.mask("fingers"), bool)
    assert m[fingers].mean() > 0.15, m[fingers].mean()  # measured 0.22 (curled: more)
    assert m[tpl.part_mask("head")].sum() > 300
    share = {p: m[tpl.part_mask(p)].mean() for p in tpl.part_names}
    for part in ("neck", "forearm_L", "forearm_R", "shin_L", "shin_R"):  # measured 0
        assert share[part] < 0.01, part
    # armpits and crotch: measured torso 5 %, upper arms 6 %, thighs 6 %, pelvis 13 %
    for part in ("torso", "upper_arm_L", "upper_arm_R", "thigh_L", "thigh_R"):
        assert share[part] < 0.10, part
    assert share["pelvis"] < 0.2
    some = np.flatnonzero(fingers)[::2]
    sub = closed_over(truth, F, 0.010, vertices=some)
    assert (
        np.array_equal(sub[some], m[some]) and not sub[np.setdiff1d(np.arange(len(m)), some)].any()
    )
    V, Fs = _sphere()
    assert vertex_normals(V, Fs)[0] @ V[0] > 0  # outward
    assert not closed_over(V, Fs, 0.010).any()
    assert not closed_over(truth, F, 0.0).any()


def test_rounded_off_marks_convex_detail_narrower_than_the_ball(realworld_case):
    """On a true body (raw-0's): a 6 mm ball inside cannot reach most of the lips and mouth's
    edge, the ears' rims and the nose's wings, but reaches the neck, forearms, shins and the
    back of the head everywhere and nearly all of the torso and thighs; a sphere of 10 cm
    radius is reached everywhere, one of 4 mm nowhere; ``vertices=`` tests only those."""
    from core.registration.closed_concavities import rounded_off
    from core.template import load_template

    tpl = load_template()
    F = np.asarray(tpl.F, np.int64)
    _, _, truth = realworld_case(0, "raw")
    m = rounded_off(truth, F, 0.006)
    L = tpl.landmarks

    def near(p: np.ndarray, r: float) -> np.ndarray:
        return np.linalg.norm(truth - p, axis=1) < r

    mouth = near((truth[L["Menton"]] + truth[L["Pronasale"]]) / 2, 0.015)
    assert m[mouth].mean() > 0.6, m[mouth].mean()  # measured 0.83
    assert m[near(truth[L["Pronasale"]], 0.02)].mean() > 0.15  # measured 0.26 (wings, not tip)
    assert m[np.asarray(tpl.mask("ears"), bool)].mean() > 0.25  # measured 0.39
    share = {p: m[tpl.part_mask(p)].mean() for p in tpl.part_names}
    for part in ("neck", "forearm_L", "forearm_R", "shin_L", "shin_R"):  # measured 0
        assert share[part] == 0.0, part
    for part in ("torso", "thigh_L", "thigh_R"):  # measured 0.058, 0.027
        assert share[part] < 0.1, (part, share[part])
    assert not m[tpl.part_mask("head") & near(truth[L["Opisthocranion"]], 0.05)].any()
    some = np.flatnonzero(mouth)[::2]
    sub = rounded_off(truth, F, 0.006, vertices=some)
    assert np.array_equal(sub[some], m[some]) and sub.sum() == sub[some].sum()
    V, Fs = _sphere()
    assert not rounded_off(V, Fs, 0.006).any()
    assert rounded_off(V * 0.04, Fs, 0.006).all()
    assert not rounded_off(truth, F, 0.0).any()


@pytest.mark.parametrize("kind", ["closed_lowres", "raw"])
def test_a_closed_meshs_bridged_gaps_take_no_data(realworld_case, kind):
    """A marker fit of closed_lowres-0 (markers at the truth's landmarks): the body's vertices
    under the mesh's bridges end with no data weight, the rest of the body keeps its data; its
    raw twin (no bridges) keeps data on most of those vertices."""
    from core.registration.closed_concavities import (
        ROUNDED_OFF_PER_RESOLUTION,
        closed_over,
        mitten_hands,
        rounded_off,
    )
    from core.registration.correspondence import ScanIndex
    from core.registration.fit import fit, template_operators
    from core.template import load_template

    tpl = load_template()
    dmask = template_operators().full.data_mask
    _, scan, truth = realworld_case(0, kind)
    index = ScanIndex(scan)
    markers = {k: truth[i] for k, i in tpl.landmarks.items()}
    res = fit(scan, markers, index=index, retry=False)
    under = closed_over(res.body_prior.X, tpl.F, 0.010) & dmask
    assert under.sum() > 200
    takes = res.data_weight > 0
    if kind == "closed_lowres":
        assert index.closing_radius_m >= 0.008
        r = index.closing_radius_m
        assert not takes[closed_over(res.body_prior.X, tpl.F, r) & dmask].any()
        assert any(n.startswith("hole-filled closed mesh: ") and f"{r * 1000:.0f} mm ball" in n
                   for n in res.report.notes), res.report.notes  # fmt: skip
        # convex detail finer than the mesh (its nose, lips, chin) keeps the body prior's too
        r_in = ROUNDED_OFF_PER_RESOLUTION * index.resolution_m
        rounded = rounded_off(res.body_prior.X, tpl.F, r_in) & dmask
        assert rounded.sum() > 100 and not takes[rounded].any()
        assert any("of convex detail narrower than its resolution" in n for n in res.report.notes)
        # a marker fit's hands take their data (its body prior can misplace them); in the
        # markerless round (soft markers: the body prior places the hands) the fused mittens'
        # hands and wrists keep the body prior's (neither hand a fist)
        mittens = mitten_hands(tpl) & dmask
        assert mittens.sum() > 500 and takes[mittens].mean() > 0.5
        assert not any("fused mittens" in n for n in res.report.notes)
        soft = fit(scan, markers, index=index, retry=False, soft_markers=True)
        assert not (soft.data_weight > 0)[mittens].any()
        assert any("cm of forearm next to them, which its fused mittens inflate" in n
                   for n in soft.report.notes)  # fmt: skip
        rest = dmask & ~under & ~rounded & ~mittens
        assert takes[rest].mean() > 0.8  # the rest of the body keeps its data
    else:
        palms = (tpl.part_mask("hand_L") | tpl.part_mask("hand_R")) & dmask
        assert takes[palms].mean() > 0.5, takes[palms].mean()  # a raw scan's hands are the skin
        assert takes[under].mean() > 0.5, takes[under].mean()
        nose = np.linalg.norm(truth - truth[tpl.landmarks["Pronasale"]], axis=1) < 0.015
        assert takes[nose & dmask].mean() > 0.8  # a raw scan's nose is the skin
        assert not any(n.startswith("hole-filled closed mesh") for n in res.report.notes)


def test_mitten_hands_are_the_hands_and_their_wrists_but_a_fists():
    """The hands and the forearm within MITTEN_WRIST_BAND_M of them (on the template), not the
    elbows nor the rest of the body; a fisted side (its curled fingers place the fist) keeps
    its data."""
    from scipy.spatial import cKDTree

    from core.registration.closed_concavities import MITTEN_WRIST_BAND_M, mitten_hands
    from core.template import load_template

    tpl = load_template()
    V = np.asarray(tpl.V)
    m = mitten_hands(tpl)
    for x in "LR":
        hand, fore = tpl.part_mask(f"hand_{x}"), tpl.part_mask(f"forearm_{x}")
        assert m[hand].all()
        d = cKDTree(V[hand]).query(V[fore])[0]
        assert m[fore][d < MITTEN_WRIST_BAND_M * 0.9].all()
        assert not m[fore][d > MITTEN_WRIST_BAND_M * 1.1].any()
        assert 0 < m[fore].mean() < 0.5  # the wrist's end of the forearm, not the elbow's
    others = ~np.any([tpl.part_mask(f"{p}_{x}") for p in ("hand", "forearm") for x in "LR"], 0)
    assert not m[others].any()
    fist_l = mitten_hands(tpl, "L")
    assert not fist_l[tpl.part_mask("hand_L")].any() and fist_l[tpl.part_mask("hand_R")].all()


def test_fist_bridges_are_the_fisted_hands_palm_side():
    """A fused fist's bridged vertices: only the fisted hand's, the palm and the curled fingers'
    pads (the palm's centre, not the knuckles' backs), more under a wider ball."""
    from core.registration.closed_concavities import fist_bridges
    from core.template import load_template

    tpl = load_template()
    m = fist_bridges("L", 0.008)
    hand_l, hand_r = tpl.part_mask("hand_L"), tpl.part_mask("hand_R")
    assert not m[~hand_l].any() and 0.15 < m[hand_l].mean() < 0.5
    assert fist_bridges("L", 0.006).sum() < m.sum() < fist_bridges("L", 0.010).sum()
    both = fist_bridges("LR", 0.008)
    assert both[hand_r].sum() == m[hand_l].sum() and (both & hand_l).sum() == m.sum()
    # one side of the hand (the palm's, facing the body: -x and down on the left hand in the
    # rest A-pose), not all round it: their open-hand normals agree (mean 0.47 long; the rest of
    # the hand's point the other way)
    from core.geometry import vertex_normals

    N = vertex_normals(np.asarray(tpl.V), np.asarray(tpl.F))
    side = N[m].mean(0)
    assert np.linalg.norm(side) > 0.35 and side[0] < 0 and side[1] < 0
    assert side @ N[hand_l & ~m].mean(0) < 0
