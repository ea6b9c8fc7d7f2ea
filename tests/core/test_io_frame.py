"""Units and up-axis detection on the template body in metres / millimetres, Y-up / Z-up."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import UnitsError
from core.io.frame import UPS, _level, apply_frame, detect_frame, rotation_for_up
from core.scan import RawMesh
from core.template import load_template

TPL = load_template()


def to_file(X, up, scale):
    """Canonical -> a file with the given up axis and units (inverse of the frame map)."""
    return (np.asarray(X) @ rotation_for_up(up)) / scale


@pytest.mark.parametrize("up", UPS)
def test_rotations_are_proper_and_map_up_to_y(up):
    R = rotation_for_up(up)
    np.testing.assert_allclose(R @ R.T, np.eye(3))
    assert np.isclose(np.linalg.det(R), 1.0)
    axis = np.zeros(3)
    axis["xyz".index(up[1])] = 1.0 if up[0] == "+" else -1.0
    np.testing.assert_allclose(R @ axis, [0, 1, 0])


def test_zup_keeps_facing_conventional():
    # the usual Z-up -> Y-up map: x stays, file +z -> +y, file +y -> -z
    np.testing.assert_allclose(rotation_for_up("+z") @ [1, 2, 3], [1, 3, -2])


@pytest.mark.parametrize(
    ("units", "scale"), [("m", 1.0), ("cm", 0.01), ("mm", 0.001), ("in", 0.0254)]
)
@pytest.mark.parametrize("up", ["+y", "+z", "+x"])
def test_auto_detects_units_and_positive_up(units, scale, up):
    V = to_file(TPL.V, up, scale)
    fr = detect_frame(V)
    assert (fr.units, fr.up, fr.detected) == (units, up, True)
    np.testing.assert_allclose(fr.to_canonical(V), TPL.V, atol=1e-9)


def test_mm_zup_explicit():
    V = to_file(TPL.V, "+z", 0.001)
    fr = detect_frame(V, units="mm", up="+z")
    assert fr.detected is False and fr.scale == 0.001
    np.testing.assert_allclose(fr.to_canonical(V), TPL.V, atol=1e-9)


def test_upside_down_needs_markers_or_option():
    V = to_file(TPL.V, "-z", 0.001)
    assert detect_frame(V).up == "+z"  # documented rule: the largest axis is taken as positive
    marks = {
        k: V[TPL.landmarks[k]] for k in ("Vertex", "Sellion", "Toe_tip_L", "Calcaneus_posterior_R")
    }
    fr = detect_frame(V, markers=marks)
    assert (fr.up, fr.units) == ("-z", "mm")
    np.testing.assert_allclose(fr.to_canonical(V), TPL.V, atol=1e-9)
    assert detect_frame(V, up="-z").up == "-z"


def test_markers_without_head_and_foot_fall_back_to_extent():
    V = to_file(TPL.V, "+z", 0.01)
    fr = detect_frame(V, markers={"Crotch": V[TPL.landmarks["Crotch"]]})
    assert (fr.up, fr.units) == ("+z", "cm")


def test_ambiguous_size_names_the_options():
    V = TPL.V / TPL.V[:, 1].max() * 25.0  # 25 units tall: neither m, in, cm nor mm
    with pytest.raises(UnitsError) as e:
        detect_frame(V)
    msg = str(e.value)
    assert "units tall" in msg and "units=" in msg and '"mm"' in msg and "up=" in msg
    assert '"in"' in msg and "inches (39.4-90.6)" in msg
    assert detect_frame(V, units="cm").units == "cm"  # explicit units are trusted


def test_ambiguous_up_axis():
    rng = np.random.default_rng(0)
    V = rng.random((2000, 3)) * [1.7, 1.6, 0.3]  # two nearly equal extents
    with pytest.raises(UnitsError, match=r"which axis is up.*up="):
        detect_frame(V)


@pytest.mark.parametrize(("height", "units"), [(40.0, "in"), (90.0, "in"), (99.0, None),
                                               (2.4, None), (229.0, "cm")])  # fmt: skip
def test_height_ranges_do_not_overlap_and_bound_each_unit(height, units):
    """Inches hold 1.0-2.3 m adults (39.4-90.6 in); between the ranges no unit is guessed."""
    V = TPL.V / np.ptp(TPL.V[:, 1]) * height
    if units is None:
        with pytest.raises(UnitsError, match="cannot tell the units"):
            detect_frame(V)
    else:
        assert detect_frame(V).units == units


def test_unknown_options():
    with pytest.raises(UnitsError, match="unknown units"):
        detect_frame(TPL.V, units="inch")
    with pytest.raises(UnitsError, match="unknown up"):
        detect_frame(TPL.V, up="z")


def test_apply_frame_maps_normals_and_keeps_faces():
    V = to_file(TPL.V, "+z", 0.001)
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    fr = detect_frame(V)
    out = apply_frame(RawMesh(V=V, F=np.array(TPL.F), normals=N), fr)
    np.testing.assert_allclose(out.V, TPL.V, atol=1e-9)
    np.testing.assert_allclose(out.normals, np.tile([0, 1, 0], (len(V), 1)), atol=1e-12)
    np.testing.assert_array_equal(out.F, TPL.F)


@pytest.mark.parametrize("up", UPS)
def test_turn_over_flips_the_up_axis_and_keeps_the_file_map(up):
    from core.io import prepare_scan, turn_over

    V_file = to_file(TPL.V, up, 0.001)
    wrong = ("-" if up[0] == "+" else "+") + up[1]  # the body read head-down
    scan = prepare_scan(RawMesh(V=V_file, F=TPL.F), detect_frame(V_file, units="mm", up=wrong))
    n0 = scan.normals.copy()
    M = turn_over(scan)
    assert scan.frame.up == up
    np.testing.assert_allclose(scan.frame.R, rotation_for_up(up))
    np.testing.assert_allclose(scan.V, scan.frame.to_canonical(V_file), atol=1e-12)
    np.testing.assert_allclose(scan.normals, n0 @ M.T)
    assert scan.V[TPL.landmarks["Vertex"], 1] > scan.V[:, 1].min() + 1.5  # head up now


@pytest.mark.parametrize("up", ["+y", "+x", "+z"])
def test_arms_spread_as_wide_as_the_body_is_tall(up):
    # closed_lowres-59 of core.synth.scanner_outputs: a man with his arms 60° out, 1.52 m wide
    # and 1.65 m tall (1.08x): the extents alone cannot tell up; the body's left-right mirror
    # symmetry can (refused as "cannot tell which axis is up" before)
    pytest.importorskip("skimage")
    from core.io.frame import _mirror_gap
    from core.synth.scanner_outputs import make_case

    c = make_case(59, "closed_lowres")
    assert c.up == "+y" and c.units == "mm"
    V = to_file(np.asarray(c.V) @ rotation_for_up(c.up).T, up, 1.0)  # file +y -> file `up`
    a = "xyz".index(up[1])
    ext = np.ptp(V, axis=0)
    side = int(np.argmax(np.where(np.arange(3) == a, 0.0, ext)))
    assert ext[a] < 1.15 * ext[side]  # ambiguous by extents
    assert _mirror_gap(V, a, about=side) > 1.6 * _mirror_gap(V, side, about=a)
    fr = detect_frame(V)
    assert (fr.up, fr.units) == (up, "mm")


def test_mirror_gap_finds_the_left_right_plane_of_a_turned_t_pose():
    # a body with its arms out 85-90° (T-pose capture) is about as wide as tall; turned 40°
    # about its up axis in the file, its arm span lies between two file axes. The left-right
    # mirror plane is then 40° off the file axis: with turns of ±20° only its gap read 3-7×
    # that of the body facing the axis (a raw T-pose scan turned ~30° was refused as "cannot
    # tell which axis is up"); it must read about the same whichever way the body faces
    from core.io.frame import _mirror_gap
    from core.synth.realworld import off_model_body, posture
    from core.synth.scanner_outputs import file_transform

    body = off_model_body(np.random.default_rng([3, 101]))
    P, _ = posture(body.V, np.random.default_rng([3, 102]), arm_range=(85.0, 90.0))
    gaps = {}
    for facing in (0.0, 40.0):
        A = file_transform("m", "+x", facing, np.zeros(3))
        V = P @ A[:3, :3].T
        ext = np.ptp(V, axis=0)
        side = 1 if ext[1] >= ext[2] else 2  # the horizontal axis nearer the arm span
        gaps[facing] = (_mirror_gap(V, side, about=0), _mirror_gap(V, 0, about=side))
        assert detect_frame(V).up == "+x"
    assert gaps[40.0][0] < 1.5 * gaps[0.0][0]  # left-right: as symmetric turned as not
    assert gaps[40.0][1] > 3.0 * gaps[40.0][0]  # head to foot: not symmetric


@pytest.mark.parametrize(("tilt", "up"), [(8.0, "+z"), (20.0, "+y"), (35.0, "-x"), (48.0, "+y")])
def test_a_tilted_body_is_levelled_and_the_file_map_kept(tilt, up):
    """A handheld scanner's frame: the body stands ``tilt`` degrees off the file's nearest
    axis. The frame turns it upright (its rest pose's long axis within 2° of +Y) and says by
    how much; ``to_file`` still inverts ``to_canonical``; turned over, it stays levelled."""
    from scipy.spatial.transform import Rotation

    from core.io import prepare_scan, turn_over

    axis = np.array([0.6, 0.0, 0.8])
    T = Rotation.from_rotvec(np.radians(tilt) * axis).as_matrix()
    V_file = to_file(TPL.V @ T.T, up, 0.001)
    fr = detect_frame(V_file, up="auto" if up[0] == "+" else up)
    if tilt > 45:  # no extent is clearly the largest: the long axis tells the up axis
        ext = np.sort(np.ptp(V_file, axis=0))
        assert ext[2] < 1.15 * ext[1]
    assert (fr.units, fr.up) == ("mm", up)
    assert abs(fr.tilt_deg - tilt) < 2.0, fr.tilt_deg
    np.testing.assert_allclose(fr.R @ fr.R.T, np.eye(3), atol=1e-12)
    X = fr.to_canonical(V_file)
    _, off = _level(X, np.eye(3))  # what is left of the tilt
    assert off < 2.0, off
    np.testing.assert_allclose(fr.to_file(X), V_file, atol=1e-9)
    assert "levelled" in fr.describe("auto", up) and f"{fr.tilt_deg:.1f}°" in fr.describe(
        "auto", up
    )
    # read head-down and turned over: the body stays upright, the file map kept
    wrong = ("-" if up[0] == "+" else "+") + up[1]
    scan = prepare_scan(RawMesh(V=V_file, F=TPL.F), detect_frame(V_file, units="mm", up=wrong))
    turn_over(scan)
    assert scan.frame.up == up and scan.frame.tilt_deg > 0
    np.testing.assert_allclose(scan.V, scan.frame.to_canonical(V_file), atol=1e-9)
    assert _level(scan.V, np.eye(3))[1] < 2.0
    assert scan.V[TPL.landmarks["Vertex"], 1] > scan.V[:, 1].min() + 1.5


def test_upright_bodies_and_marker_sets_are_not_levelled():
    """Upright bodies (the template, random bodies, their arms spread) keep the pure axis map,
    whatever their posture tilts their principal axis by; a marker set is never levelled."""
    from core.synth import random_body

    rng = np.random.default_rng(0)
    for V in [TPL.V] + [random_body(rng).V for _ in range(6)]:
        fr = detect_frame(to_file(V, "+z", 0.001))
        assert fr.tilt_deg == 0.0
        np.testing.assert_allclose(fr.R, rotation_for_up("+z"))
    marks = to_file(TPL.V[list(TPL.landmarks.values())], "+z", 0.001)
    assert detect_frame(marks).tilt_deg == 0.0
