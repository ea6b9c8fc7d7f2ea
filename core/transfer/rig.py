"""Skeleton and skin transfer (Allen et al. 2003, section 4.6): the template's standard rig
carried to any body in template order, as a skinned GLB, and named postures.

- :func:`body_joints` -- a body's joints from its own vertices: the rig's vertex-group
  regression (``"regressor"``, :func:`core.rig.joint_positions`) or a similarity fitted to the
  joint's surface markers (``"markers"``: the regressor's support vertices; the template joint
  moved by the least-squares similarity of its markers, a local inverse-kinematics solve).
- :func:`rig_glb` -- a GLB with a ``skin``: one node per bone (translations only: the bind pose
  has no rotation, so a node's ``rotation`` is the rig's local rotation), inverse bind matrices,
  ``JOINTS_0``/``WEIGHTS_0`` from the template's skin weights (4 largest, renormalised, float32).
- :data:`POSTURES` / :func:`posture` -- ``standing``, ``seated``, ``driving``, ``reach`` as
  local bone rotations; :func:`pose` -- a posed body by linear blend skinning
  (:func:`core.rig.pose_body`), optionally resting on a seat (``seat_contact``: the tissue
  under the buttocks compressed on a flat seat, :mod:`core.transfer.seat`), floor reset to
  y = 0.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from core.geometry import umeyama
from core.io.writers import GlbSkin, write_glb
from core.rig import Rig, axis_angle, bone_transforms, joint_positions, load_rig, pose_body
from core.template import load_template
from core.transfer.seat import seat_contact as rest_on_seat

JOINT_METHODS = ("regressor", "markers")


def _rx(deg: float) -> np.ndarray:
    return axis_angle([1.0, 0.0, 0.0], np.radians(deg))


def _rz(deg: float) -> np.ndarray:
    return axis_angle([0.0, 0.0, 1.0], np.radians(deg))


def _sides(bone: str, R_left: np.ndarray) -> dict[str, np.ndarray]:
    """``bone.L`` -> R and ``bone.R`` -> R mirrored in the sagittal plane (x -> -x)."""
    M = np.diag([-1.0, 1.0, 1.0])
    return {f"{bone}.L": R_left, f"{bone}.R": M @ R_left @ M}


def _postures() -> dict[str, dict[str, np.ndarray]]:
    # Template axes: +X the subject's left, +Y up, +Z front. The template stands in an A-pose
    # (upper arms ~39 deg from vertical). Hip flexion is a rotation about -X, knee flexion
    # about +X; arms come down to the sides about -Z (left) / +Z (right).
    arms_down = {**_sides("upperarm01", _rz(-25.0)), **_sides("lowerarm01", _rx(15.0))}
    sit = {**_sides("upperleg01", _rx(-90.0)), **_sides("lowerleg01", _rx(90.0))}
    hands_on_thighs = {
        **_sides("upperarm01", _rz(-25.0)),
        **_sides("lowerarm01", _rx(-20.0)),
    }
    driving = {
        **_sides("upperleg01", _rx(-75.0)),
        **_sides("lowerleg01", _rx(55.0)),
        **_sides("upperarm01", _rx(-45.0) @ _rz(-25.0)),
        **_sides("lowerarm01", _rx(-35.0)),
        "spine05": _rx(-12.0),  # reclined backrest
    }
    reach = {
        **arms_down,
        "upperarm01.R": _rx(-100.0) @ _rz(35.0),  # right arm forward and a little up
        "lowerarm01.R": _rx(-10.0),
    }
    return {
        "standing": arms_down,
        "seated": {**sit, **hands_on_thighs},
        "driving": driving,
        "reach": reach,
    }


POSTURES: dict[str, dict[str, np.ndarray]] = _postures()


def posture(name: str) -> dict[str, np.ndarray]:
    """Local bone rotations ``{bone: (3, 3)}`` of a named posture (see :data:`POSTURES`)."""
    try:
        return {k: v.copy() for k, v in POSTURES[name].items()}
    except KeyError:
        raise ValueError(f"unknown posture {name!r}; postures: {', '.join(POSTURES)}") from None


def _similarity(P: np.ndarray, Q: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``Q ~ s R P + t`` (:func:`core.geometry.umeyama`); P, Q (k, 3)."""
    sim = umeyama(P, Q)
    return sim.s, sim.R, sim.t


def body_joints(
    V: np.ndarray, *, method: str = "regressor", rig: Rig | None = None, ends: str = "head"
) -> np.ndarray:
    """A body's joints from its own vertices.

    Parameters
    ----------
    V : (13380, 3) body in template order, metres.
    method : ``"regressor"`` (the rig's vertex-group regression) or ``"markers"`` (per joint,
        the least-squares similarity taking the template's markers -- the regressor's support
        vertices -- to the body's, applied to the template joint).
    rig : the rig (default :func:`core.rig.load_rig`).
    ends : ``"head"`` (joints) or ``"tail"``.

    Returns
    -------
    (J, 3) float64 positions, metres.
    """
    rig = rig or load_rig()
    if method == "regressor":
        return joint_positions(V, rig=rig, ends=ends)
    if method != "markers":
        raise ValueError(f"method must be one of {', '.join(JOINT_METHODS)}, got {method!r}")
    V = np.asarray(V, dtype=np.float64)
    if V.shape != (rig.n_vertices, 3):
        raise ValueError(f"V must be ({rig.n_vertices}, 3) in template order, got {V.shape}")
    T = load_template().V
    idx, rest = (rig.head_reg_idx, rig.heads) if ends == "head" else (rig.tail_reg_idx, rig.tails)
    out = np.empty((rig.n_joints, 3))
    for j in range(rig.n_joints):
        s, R, t = _similarity(T[idx[j]], V[idx[j]])
        out[j] = s * R @ rest[j] + t
    return out


def skin(V: np.ndarray, *, rig: Rig | None = None, method: str = "regressor") -> GlbSkin:
    """The rig carried to body ``V``: its joints (:func:`body_joints`) and the template's skin
    weights, 4 largest per vertex, renormalised."""
    rig = rig or load_rig()
    joint_index, weights = rig.skin_top4()
    return GlbSkin(
        names=rig.names,
        parents=np.asarray(rig.parents, dtype=np.int64),
        joints=body_joints(V, method=method, rig=rig),
        joint_index=joint_index,
        weights=weights,
    )


def rig_glb(
    V: np.ndarray,
    *,
    rig: Rig | None = None,
    method: str = "regressor",
    colors: np.ndarray | None = None,
    texture: bytes | None = None,
) -> bytes:
    """Skinned GLB of body ``V`` (template order, metres): mesh, normals, ``skin`` (and
    ``COLOR_0`` from ``colors``, (13380, 3) uint8 or floats in [0, 1], if given; or a PNG
    ``texture`` on the template UV layout: :func:`core.transfer.texture.textured_glb`)."""
    sk = skin(V, rig=rig, method=method)
    if texture is not None:
        from core.transfer.texture import textured_glb

        return textured_glb(None, V, texture, skin=sk)
    tpl = load_template()
    return write_glb(None, V, tpl.F, colors=colors, skin=sk)


def rotations_from_vectors(rotations: Mapping[str, object]) -> dict[str, np.ndarray]:
    """``{bone: rotation vector}`` (axis x angle, radians, template axes) -> ``{bone: (3, 3)}``;
    ``ValueError`` naming the bone for anything but 3 finite numbers or an unknown bone."""
    rig = load_rig()
    out = {}
    for name, rv in rotations.items():
        rig.index(name)  # ValueError for unknown bones
        a = np.asarray(rv, dtype=np.float64)
        if a.shape != (3,) or not np.isfinite(a).all():
            raise ValueError(f"rotation of {name!r} must be 3 finite numbers (radians)")
        angle = float(np.linalg.norm(a))
        out[name] = np.eye(3) if angle == 0.0 else axis_angle(a, angle)
    return out


def pose(
    V: np.ndarray,
    rotations: Mapping[str, np.ndarray],
    *,
    rig: Rig | None = None,
    method: str = "regressor",
    floor: bool = True,
    seat_contact: bool = False,
) -> np.ndarray:
    """Pose body ``V`` by linear blend skinning with the template rig on the body's own joints
    and the skin of its GLB (4 influences per vertex: what a glTF viewer shows).

    Parameters
    ----------
    V : (13380, 3) rest body, template order, metres.
    rotations : bone name -> (3, 3) local rotation (:mod:`core.rig` conventions), e.g.
        :func:`posture`.
    method : how the joints are placed (:func:`body_joints`).
    floor : shift vertically so that the lowest vertex is at y = 0.
    seat_contact : rest the body on a flat seat (:func:`core.transfer.seat.seat_contact`: the
        soft tissue under the buttocks compressed as measured in seated people); what the API
        and CLI do by default for the postures with a seat
        (:data:`core.transfer.seat.SEATED_POSTURES`). Off: exactly linear blend skinning.

    Returns
    -------
    (13380, 3) float64 posed vertices, metres.
    """
    rig = rig or load_rig()
    J = body_joints(V, method=method, rig=rig)
    P = pose_body(V, rotations, rig=rig, joints=J, influences=4)
    if seat_contact:
        R, t = bone_transforms(rotations, J, rig=rig)
        P, _ = rest_on_seat(P, np.einsum("jab,jb->ja", R, J) + t, rig=rig)
    if floor:
        P[:, 1] -= P[:, 1].min()
    return P
