"""Hands of markerless fits (``core.registration.hand_length``, ``core.matching.markerless``):
the hand's length comes from the scanned hand where it is free, a flat open hand whose fingers
reach past the scan is not taken for a fist, and a heavy body's open hands end where the scan's
do."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("skimage")


def _scaled_hands(X: np.ndarray, factor: float) -> np.ndarray:
    """X (13380, 3) with both hands scaled by ``factor`` about their wrists (styloids' midpoint)."""
    from core.template import load_template

    tpl = load_template()
    out = X.copy()
    for s in "LR":
        w = (X[tpl.landmarks[f"Radial_styloid_{s}"]] + X[tpl.landmarks[f"Ulnar_styloid_{s}"]]) / 2
        m = tpl.part_mask(f"hand_{s}")
        out[m] = w + factor * (X[m] - w)
    return out


def _hand_length(X: np.ndarray, s: str) -> float:
    from core.template import load_template

    L = load_template().landmarks
    w = (X[L[f"Radial_styloid_{s}"]] + X[L[f"Ulnar_styloid_{s}"]]) / 2
    return float(np.linalg.norm(X[L[f"Dactylion_{s}"]] - w))


def test_hands_take_their_length_from_the_scan_or_the_stature(realworld_case, monkeypatch):
    """raw-35 (BMI 44, open hands 27° from the body): the true body with hands 20 % long gets
    them back to the scanned hands' length (within 8 mm of the truth's 169 mm); read as hands at
    the body (not measured), the same hands are held in ANSUR II's band of the stature."""
    from core.registration import hand_length
    from core.registration.correspondence import ScanIndex
    from core.template import load_template

    _, scan, truth = realworld_case(35, "raw")
    index = ScanIndex(scan)
    tpl = load_template()
    stature = float(np.ptp(truth[:, 1]))  # this scan reads head-down: the fit turns it over
    long_ = _scaled_hands(truth, 1.2)
    fixed, made = hand_length.correct_hand_lengths(index, long_, stature)
    assert [h.source for h in made] == ["scan", "scan"], made
    for s in "LR":
        assert _hand_length(long_, s) - _hand_length(truth, s) > 0.030  # the error made
        assert abs(_hand_length(fixed, s) - _hand_length(truth, s)) < 0.008, made
    # the forearms stay where they were (but for the ramp's first mm past the styloids)
    fore = tpl.part_mask("forearm_L") | tpl.part_mask("forearm_R")
    moved = np.linalg.norm(fixed[fore] - long_[fore], axis=1)
    assert np.median(moved) == 0.0 and moved.max() < 0.008, moved.max()
    # a few mm too long is corrected too (MIN_CORRECTION_M: 2 mm; it was 6)
    lengths = {s: _hand_length(fixed, s) for s in "LR"}
    slightly = _scaled_hands(fixed, 1.0 + 0.004 / min(lengths.values()))
    again, made = hand_length.correct_hand_lengths(index, slightly, stature)
    assert [h.source for h in made] == ["scan", "scan"], made
    for s in "LR":
        assert abs(_hand_length(again, s) - lengths[s]) < 0.0015, made
    # a fist is left alone
    _, made_fist = hand_length.correct_hand_lengths(index, long_, stature, fists="LR")
    assert made_fist == []
    # hands at the body: the scan cannot say where they end; the band holds them
    monkeypatch.setattr(hand_length, "FREE_HAND_GAP_M", 10.0)
    held, made = hand_length.correct_hand_lengths(index, long_, stature)
    assert [h.source for h in made] == ["stature", "stature"], made
    for s in "LR":
        target = hand_length.HAND_STATURE_BAND[1] * stature  # the styloids ride the ramp
        assert _hand_length(held, s) == pytest.approx(target, abs=0.001)


def test_a_mittens_fingertip_landmark_lies_on_the_hands_axis(realworld_case):
    """closed_filled-904/905 (booth software's meshes hole-filled from their raw scans): on the
    true body the right mitten's furthest scan points lie off the middle finger's line, and the
    fingertip landmark from them lands 34/38 mm from the true fingertip; on the hand's axis at
    the same reach, 9 mm. The markerless round puts it there on a closed mesh: 904's right hand
    was fitted 9.6 mm from the truth (its raw twin's 4.2), now 5.0."""
    from core.matching.markerless import fit_markerless
    from core.registration.correspondence import ScanIndex
    from core.registration.hand_length import free_hand_ends, tip_allowance
    from core.registration.quality import part_labels
    from core.template import load_template

    dact = load_template().landmarks
    for seed in (904, 905):
        case, scan, truth = realworld_case(seed, "closed_filled")
        index = ScanIndex(scan)
        assert index.closing_radius_m > 0
        ends = free_hand_ends(index, truth)
        t = tip_allowance(index)
        tip = truth[dact["Dactylion_R"]]
        off_point = np.linalg.norm(ends["R"].fingertip(t) - tip)
        off_axis = np.linalg.norm(ends["R"].fingertip(t, on_axis=True) - tip)
        assert off_point > 0.025 and off_axis < 0.012, (seed, off_point, off_axis)
    case, scan, _ = realworld_case(904, "closed_filled")
    res = fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)
    labels, names = part_labels()
    m = labels == names.index("hand_R")
    err = float(np.linalg.norm(res.vertices[m] - truth[m], axis=1).mean())
    assert err < 0.007, err


def test_flat_hands_past_the_scan_are_not_fists(realworld_case):
    """An open hand whose fingertips reach past the scan (here the true body's hands 40 % long
    on raw-35) reads like a fist by the tip gap alone; its scanned palm is flat and the fit
    keeps it open. The fists of closed_lowres-24, fitted with open hands, are still fists."""
    from core.matching.markerless import FIST_ROUNDNESS, FIST_TIP_GAP_M, fisted_hands
    from core.registration.correspondence import ScanIndex
    from core.registration.hand_length import scanned_hand_roundness
    from core.registration.quality import hand_tip_gap
    from core.synth.realworld import off_model_body, posture

    _, scan, truth = realworld_case(35, "raw")
    index = ScanIndex(scan)
    long_ = _scaled_hands(truth, 1.4)
    for s in "LR":
        assert hand_tip_gap(index, long_, s) > FIST_TIP_GAP_M  # what made it a fist before
        r = scanned_hand_roundness(index, long_, s)
        assert r is not None and r < FIST_ROUNDNESS - 0.05, r  # measured 0.48 on the left
    assert fisted_hands(index, long_) == ""

    case, scan, truth = realworld_case(24, "closed_lowres")
    assert case.params["posture"]["fist"]
    body = off_model_body(np.random.default_rng([24, 101]))
    open_, _ = posture(body.V, np.random.default_rng([24, 102]), fist=False)
    open_ = scan.frame.to_canonical(open_ @ case.to_file[:3, :3].T + case.to_file[:3, 3])
    index = ScanIndex(scan)
    for s in "LR":
        r = scanned_hand_roundness(index, open_, s)
        assert r is not None and r > FIST_ROUNDNESS, r
    assert fisted_hands(index, open_) == "LR"


def test_a_heavy_bodys_open_hands_end_where_the_scan_does(realworld_case):
    """raw-35 markerless: the first fit puts the arms 3-5 cm out along themselves and the
    fingertips 50-58 mm past the scan. Before, both hands were fitted as fists (centroids 32 and
    22 mm off the truth's); now open, their fingertips at the scanned hands' ends."""
    from core.matching.markerless import fit_markerless
    from core.registration.quality import part_labels

    case, scan, _ = realworld_case(35, "raw")
    res = fit_markerless(scan)
    truth = scan.frame.to_canonical(case.truth)  # after the fit: it may have turned the scan
    assert not any("fitted as fists" in n for n in res.report.notes), res.report.notes
    labels, names = part_labels()
    for s in "LR":
        m = labels == names.index(f"hand_{s}")
        assert res.data_weight[m].any()  # a finely sampled scan's hands take data in the refinement
        off = np.linalg.norm(res.vertices[m].mean(0) - truth[m].mean(0)) * 1000
        assert off < 20.0, (s, off)  # measured 12 / 15
        assert res.report.quality.parts[f"hand_{s}"].hand_tip_gap_m < 0.015


def test_a_decimated_mesh_is_read_by_its_detail_not_its_sampling():
    """An ellipsoid (semi-axes 25, 10 and 5 cm: it bends more at its ends) meshed by marching
    cubes on a 12 mm grid (its vertices on the grid's edges, their neighbour distances spread
    widely) is as detailed as its sampling. Meshed on a 4 mm grid and decimated by edge collapse
    to an eighth of its vertices (sampled about as coarsely, spread evenly, denser at its ends)
    it holds a finer surface: ``resolution_m`` is at most ``DECIMATED_RESOLUTION_M`` there,
    the fingertip's allowance follows it, and the report's note says so. Clustered on a 12 mm
    grid instead (evenly spread, as dense everywhere: the cells' means round the ends off) and
    as a point cloud it keeps its sampling."""
    pytest.importorskip("skimage")
    pytest.importorskip("fast_simplification")
    from skimage.measure import marching_cubes

    from core.geometry import vertex_normals
    from core.io.prepare import decimate_voxel_grid
    from core.io.readers import RawMesh
    from core.registration.correspondence import DECIMATED_RESOLUTION_M, ScanIndex
    from core.registration.fit import decimated_mesh_note
    from core.registration.hand_length import TIP_PER_SPACING, tip_allowance
    from core.scan import Scan
    from core.synth.scanner_outputs import decimate

    axes = np.array([0.25, 0.10, 0.05])

    def ellipsoid(h: float) -> tuple[np.ndarray, np.ndarray]:  # outward
        g = [np.arange(-a - 2 * h, a + 3 * h, h) + 0.137 * h for a in axes]
        X, Y, Z = np.meshgrid(*g, indexing="ij")
        f = np.sqrt((X / axes[0]) ** 2 + (Y / axes[1]) ** 2 + (Z / axes[2]) ** 2) - 1.0
        V, F, _, _ = marching_cubes(f, 0.0, spacing=(h, h, h))
        return V + np.array([gi[0] for gi in g]), F[:, [0, 2, 1]].astype(np.int64)

    def index(V: np.ndarray, F: np.ndarray | None) -> ScanIndex:
        N = vertex_normals(V, F) if F is not None else V / np.linalg.norm(V, axis=1)[:, None]
        ones = np.ones(len(V))
        return ScanIndex(Scan(V=V, F=F, normals=N, confidence=ones, boundary=ones < 0))

    coarse = index(*ellipsoid(0.012))
    Vf, Ff = ellipsoid(0.004)
    fine = index(Vf, Ff)
    Vd, Fd = decimate(Vf, Ff, len(Vf) // 8)
    dec = index(Vd, Fd)
    cl = decimate_voxel_grid(RawMesh(V=Vf, F=Ff, normals=None, confidence=None, colors=None), 0.012)
    keep = (cl.F[:, 0] != cl.F[:, 1]) & (cl.F[:, 1] != cl.F[:, 2]) & (cl.F[:, 0] != cl.F[:, 2])
    clustered = index(cl.V, cl.F[keep])
    cloud = index(Vd, None)  # the decimated points without faces: nothing says how they were made
    assert dec.spacing_m > 0.8 * coarse.spacing_m, (dec.spacing_m, coarse.spacing_m)
    for ix in (coarse, fine, clustered, cloud):
        assert not ix.decimated and ix.resolution_m == ix.spacing_m
        assert decimated_mesh_note(ix) is None
    assert fine.spacing_m < 0.004 and clustered.spacing_m > 0.006
    assert dec.decimated and dec.resolution_m == DECIMATED_RESOLUTION_M < dec.spacing_m
    assert abs(tip_allowance(dec) - TIP_PER_SPACING * DECIMATED_RESOLUTION_M) < 1e-12
    note = decimated_mesh_note(dec)  # the report says how it was read
    assert note is not None and "read as a 3 mm surface" in note, note
    assert f"sampled every {dec.spacing_m * 1000:.1f} mm" in note


def test_tip_allowance_follows_the_scans_sampling():
    """The fingertip's allowance past the scanned hand's end scales with the scan's sampling
    (a coarse booth mesh rounds the mitten's tip off), within its bounds."""
    from core.registration.correspondence import ScanIndex
    from core.registration.hand_length import TIP_ALLOWANCE_RANGE_M, TIP_PER_SPACING, tip_allowance
    from core.scan import Scan

    def grid(step: float) -> ScanIndex:  # a flat sheet of points `step` metres apart
        u = np.arange(0.0, 0.6, step)
        P = np.array([(x, y, 0.0) for x in u for y in u])
        N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
        return ScanIndex(
            Scan(
                V=P, F=None, normals=N, confidence=np.ones(len(P)), boundary=np.zeros(len(P), bool)
            )
        )

    fine, mid, coarse = grid(0.001), grid(0.005), grid(0.02)
    assert abs(mid.spacing_m - 0.005) < 1e-9 and abs(coarse.spacing_m - 0.02) < 1e-9
    assert tip_allowance(fine) == TIP_ALLOWANCE_RANGE_M[0]  # 1.2 mm: held at the lower bound
    assert abs(tip_allowance(mid) - TIP_PER_SPACING * 0.005) < 1e-9
    assert tip_allowance(coarse) == TIP_ALLOWANCE_RANGE_M[1]  # 24 mm: held at the upper bound
