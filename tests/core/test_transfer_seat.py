"""Seat contact (core.transfer.seat): a seated body rests on a flat seat -- its seat region's
underside on one plane, nothing at or above the ischial tuberosity level moving, no triangle
turning over, a validator-clean GLB -- and bodies without a seat stay plain LBS."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry import vertex_normals
from core.io import write_glb
from core.rig import bone_transforms, load_rig, pose_body
from core.shapespace.model import load_model
from core.template import load_template
from core.transfer.rig import body_joints, pose, posture
from core.transfer.seat import (
    CONTACT_EDGE,
    IT_COMPRESSION,
    IT_TISSUE_UNLOADED,
    contact_lift,
    seat_contact,
    seat_region,
    seat_weights,
)
from service.testing import validate_glb


@pytest.fixture(scope="module")
def body() -> np.ndarray:
    return load_model().synthesize("female", {"height_m": 1.63, "weight_kg": 67.0})


def _posed(V: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """LBS-posed body (no floor shift) and its posed joints."""
    J = body_joints(V)
    R, t = bone_transforms(posture(name), J)
    return pose(V, posture(name), floor=False), np.einsum("jab,jb->ja", R, J) + t


def test_contact_lift_is_smooth_and_keeps_order():
    a, w = CONTACT_EDGE, 0.04
    s = np.linspace(-0.08, 0.08, 16001)
    y = s + contact_lift(s, a=a, w=w)
    assert np.all(np.diff(y) >= 0)  # heights keep their order: no fold
    assert np.all(y[s <= -a] == 0) and np.all(y[s >= w] == s[s >= w])
    slope = np.diff(y) / np.diff(s)
    assert np.abs(np.diff(slope)).max() < 0.01  # C1: no kink at -a or w


@pytest.mark.parametrize("name", ["seated", "driving"])
def test_seat_is_flat_and_nothing_above_moves(body, name):
    P, J = _posed(body, name)
    Q, info = seat_contact(P, J)
    assert info.lift == pytest.approx(IT_COMPRESSION * IT_TISSUE_UNLOADED)
    assert info.hip_to_it > 0  # the IT estimate lies below the hip joints
    moved = np.abs(Q - P).max(axis=1) > 0
    assert np.all(Q[:, [0, 2]] == P[:, [0, 2]])  # only heights change
    assert np.all(Q[:, 1] >= P[:, 1])  # and only upwards
    # the seat region's underside: pressed vertices on one plane, none below it
    s = P[:, 1] - info.plane
    pressed = (seat_weights(P, J) == 1) & (s <= -CONTACT_EDGE)
    assert pressed.sum() == info.n_contact >= 30
    assert np.ptp(Q[pressed, 1]) < 1e-3 and abs(Q[pressed, 1].mean() - info.plane) < 1e-3
    # nothing at or above the IT level moves, nor anything above the hip joints, the arms,
    # hands, lower legs or feet
    rig = load_rig()
    hip = J[[rig.index("upperleg01.L"), rig.index("upperleg01.R")], 1].min()
    assert not moved[P[:, 1] >= info.it_level].any()
    assert not moved[P[:, 1] >= hip].any()
    assert not moved[seat_region() == 0].any()
    assert 0 < P[moved, 1].max() - info.plane < info.it_level - info.plane
    # no triangle turns over (no fold, no crease through the surface)
    F = load_template().F
    touched = moved[F].any(axis=1)
    n0 = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])[touched]
    n1 = np.cross(Q[F[:, 1]] - Q[F[:, 0]], Q[F[:, 2]] - Q[F[:, 0]])[touched]
    assert np.all(np.einsum("ij,ij->i", n0, n1) > 0)


def test_pose_option_lowers_the_seat_only(body):
    rot = posture("seated")
    lbs = pose_body(body, rot, rig=load_rig(), influences=4)
    P0 = pose(body, rot, floor=False)
    np.testing.assert_array_equal(P0, lbs)  # off by default: exactly LBS
    P1 = pose(body, rot, floor=False, seat_contact=True)
    Q, info = seat_contact(*_posed(body, "seated"))
    np.testing.assert_array_equal(P1, Q)
    top = np.argmax(P0[:, 1])
    assert P1[top, 1] == P0[top, 1]
    # sitting height (head top - seat) shrinks by the compression, the feet stay on the floor
    lo0 = P0[seat_weights(*_posed(body, "seated")) == 1, 1].min()
    assert P1[top, 1] - info.plane == pytest.approx(P0[top, 1] - lo0 - info.lift, abs=1e-9)
    Pf = pose(body, rot, seat_contact=True)
    assert Pf[:, 1].min() == 0.0 and np.argmin(Pf[:, 1]) == np.argmin(P0[:, 1])


def test_standing_unchanged(body):
    """Postures without a seat are not touched by default: the standing body (and so every
    measurement of it) is exactly LBS."""
    rot = posture("standing")
    lbs = pose_body(body, rot, rig=load_rig(), influences=4)
    np.testing.assert_array_equal(pose(body, rot, floor=False), lbs)


def test_no_seat_no_contact(body):
    """A posture without a seat (the thighs hanging straight down or raised above the hips)
    is a clear error, not a made-up seat."""
    with pytest.raises(ValueError, match="no seat"):
        pose(body, posture("standing"), seat_contact=True)
    up = {"upperleg01.L": posture("seated")["upperleg01.L"] @ posture("seated")["upperleg01.L"]}
    up["upperleg01.R"] = posture("seated")["upperleg01.R"] @ posture("seated")["upperleg01.R"]
    with pytest.raises(ValueError, match="no seat"):
        pose(body, up, seat_contact=True)


def test_seated_glb_validates(body, tmp_path):
    P = pose(body, posture("seated"), seat_contact=True)
    F = load_template().F
    assert np.isfinite(vertex_normals(P, F)).all()
    path = tmp_path / "seated.glb"
    path.write_bytes(write_glb(None, P, F))
    report = validate_glb(path)
    assert report["errors"] == 0 and report["warnings"] == 0, report
