"""Linear blend skinning with the standard rig on the template and on a deformed body."""

from __future__ import annotations

import numpy as np
import pytest

from core.rig import axis_angle, bone_transforms, joint_positions, load_rig, pose_body
from core.template import load_template


@pytest.fixture(scope="module", name="T")
def template_fixture():
    return load_template()


@pytest.fixture(scope="module")
def rig():
    return load_rig()


def test_identity_pose_is_identity(T, rig):
    P = pose_body(T.V, {})
    np.testing.assert_allclose(P, T.V, atol=1e-6)
    P = pose_body(T.V, {"spine03": np.eye(3), "upperleg01.R": np.eye(3)})
    np.testing.assert_allclose(P, T.V, atol=1e-6)


def test_joint_regressor_reproduces_template_joints(T, rig):
    np.testing.assert_allclose(joint_positions(T.V), rig.heads, atol=1e-6)
    np.testing.assert_allclose(joint_positions(T.V, ends="tail"), rig.tails, atol=1e-6)


def test_joints_follow_an_affine_body(T, rig):
    A = np.array([[1.1, 0.05, 0.0], [0.0, 0.9, 0.1], [0.02, 0.0, 1.3]])
    b = np.array([0.3, -0.2, 1.0])
    J = joint_positions(T.V @ A.T + b)
    np.testing.assert_allclose(J, rig.heads @ A.T + b, atol=1e-5)


def test_joints_lie_inside_their_limbs(T, rig):
    # the elbow joint lies within the arm cross-section, near the mean of nearby arm vertices
    for name, part in [("lowerarm01.L", "upper_arm_L"), ("lowerleg01.R", "thigh_R")]:
        j = rig.heads[rig.index(name)]
        d = np.linalg.norm(T.V[T.part_mask(part)] - j, axis=1)
        assert 0.01 < d.min() < 0.08, name


def test_upper_arm_rotation_moves_only_that_arm(T, rig):
    angle = np.deg2rad(20)
    R = axis_angle([0, 0, 1], angle)
    P = pose_body(T.V, {"upperarm01.L": R})
    d = np.linalg.norm(P - T.V, axis=1)
    h = rig.heads[rig.index("upperarm01.L")]
    for part in ("upper_arm_R", "forearm_R", "hand_R", "thigh_L", "shin_L", "foot_L", "pelvis"):
        assert d[T.part_mask(part)].max() < 1e-9, part
    hand = T.part_mask("hand_L")
    # rigid rotation about the Z axis through the shoulder joint: chord = 2 r sin(angle / 2),
    # r = distance from that axis
    r_axis = np.linalg.norm((T.V[hand] - h)[:, :2], axis=1)
    np.testing.assert_allclose(d[hand], 2 * r_axis * np.sin(angle / 2), rtol=1e-6)
    r = np.linalg.norm(T.V[hand] - h, axis=1)
    arm_len = np.linalg.norm(rig.heads[rig.index("wrist.L")] - h)
    assert 0.3 < arm_len < 0.55
    assert np.median(d[hand]) == pytest.approx(arm_len * np.sin(angle), rel=0.25)
    # lengths are kept: hand vertices keep their distance to the shoulder joint
    np.testing.assert_allclose(np.linalg.norm(P[hand] - h, axis=1), r, atol=1e-9)
    # abducting about +Z lifts the left hand (+X side) upward
    assert P[hand, 1].mean() > T.V[hand, 1].mean() + 0.05


def test_forward_kinematics_composes_along_chain(T, rig):
    Ra = axis_angle([1, 0, 0], 0.3)
    Rb = axis_angle([0, 1, 0], -0.4)
    R, t = bone_transforms({"upperleg01.L": Ra, "lowerleg01.L": Rb}, rig.heads)
    k = rig.index("lowerleg01.L")
    hk = rig.heads[k]
    hp = rig.heads[rig.index("upperleg01.L")]
    x = np.array([0.2, 0.3, 0.05])
    expect = Ra @ (hk + Rb @ (x - hk) - hp) + hp
    np.testing.assert_allclose(R[k] @ x + t[k], expect, atol=1e-12)
    # the knee joint itself moves with the thigh only
    np.testing.assert_allclose(R[k] @ hk + t[k], Ra @ (hk - hp) + hp, atol=1e-12)
    # the other leg is untouched
    o = rig.index("lowerleg01.R")
    np.testing.assert_allclose(R[o], np.eye(3), atol=1e-12)


def test_morphed_body_posed_with_its_own_joints(T, rig):
    s = 1.2
    V = T.V * s
    P = pose_body(V, {"lowerarm01.R": axis_angle([1, 0, 0], 0.5)})
    P0 = pose_body(T.V, {"lowerarm01.R": axis_angle([1, 0, 0], 0.5)})
    np.testing.assert_allclose(P, P0 * s, atol=1e-5)


def test_skin_top4(rig):
    idx, w = rig.skin_top4()
    assert idx.shape == w.shape == (13380, 4)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-5)
    assert (w >= 0).all()


def test_bad_inputs(T, rig):
    with pytest.raises(ValueError, match="unknown bone"):
        pose_body(T.V, {"tail.L": np.eye(3)})
    with pytest.raises(ValueError, match="13380"):
        pose_body(T.V[:100], {})
    with pytest.raises(ValueError, match="rotation"):
        pose_body(T.V, {"head": 2 * np.eye(3)})
    with pytest.raises(ValueError, match="ends"):
        joint_positions(T.V, ends="middle")
