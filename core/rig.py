"""The MakeHuman standard rig on the template: joints, skin weights, linear blend skinning.

Conventions
-----------
- Bones are ordered parents before children (``Rig.parents[j] < j``; the root has ``-1``).
- A bone's *head* is its joint: the point it rotates about. Positions are metres in the template
  frame (+Y up, +Z front, +X the subject's left).
- A pose is ``{bone name: (3, 3) rotation}``. Each rotation is *local*: it is expressed in the
  rest-pose (template) axes and applied about the bone's head, after which the parent's transform
  is applied (forward kinematics along the parent chain). Bones not named keep the identity.
  With all ancestors at identity, ``R`` simply rotates the bone's subtree about its head in
  template axes.

Everything is numpy; bodies are in template vertex order, so one rig serves every fitted or
synthesised body: :func:`joint_positions` re-places the joints on a body from its own vertices.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache

import numpy as np

from core.template import Template, load_template


@dataclass(frozen=True)
class Rig:
    """The standard rig bound to the template.

    Attributes
    ----------
    names : J bone names (J = 163), parents before children.
    parents : (J,) int16 parent index, -1 for the root.
    heads, tails : (J, 3) float64 rest bone ends on the template, metres.
    rolls : (J,) float32 bone roll, radians, as in MakeHuman's rig file (Blender convention).
    skin_rows, skin_cols, skin_vals : sparse (13380, J) skin weights as triplets: vertex index,
        bone index, weight (rows sum to 1).
    head_reg_idx, head_reg_w, tail_reg_idx, tail_reg_w : (J, K) joint regressors: bone end ``j``
        of a body ``V`` is ``sum_k w[j, k] * V[idx[j, k]]`` (affine combination, rows sum to 1).
    """

    names: tuple[str, ...]
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    rolls: np.ndarray
    skin_rows: np.ndarray
    skin_cols: np.ndarray
    skin_vals: np.ndarray
    head_reg_idx: np.ndarray
    head_reg_w: np.ndarray
    tail_reg_idx: np.ndarray
    tail_reg_w: np.ndarray
    n_vertices: int

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of bone ``name``; ``ValueError`` naming some valid bones if unknown."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(
                f"unknown bone {name!r}; valid bones include "
                f"{', '.join(self.names[:12])}, ... ({self.n_joints} in all)"
            ) from None

    def descendants(self, name: str) -> list[int]:
        """Indices of bone ``name`` and every bone below it."""
        j = self.index(name)
        inside = np.zeros(self.n_joints, dtype=bool)
        inside[j] = True
        for k in range(j + 1, self.n_joints):  # parents come before children
            p = self.parents[k]
            if p >= 0 and inside[p]:
                inside[k] = True
        return np.flatnonzero(inside).tolist()

    def skin_weights(self) -> np.ndarray:
        """(13380, J) float64 dense skin weights (rows sum to 1)."""
        W = np.zeros((self.n_vertices, self.n_joints))
        W[self.skin_rows, self.skin_cols] = self.skin_vals
        return W

    def skin_top4(self) -> tuple[np.ndarray, np.ndarray]:
        """The 4 largest skin weights per vertex, renormalised (glTF ``JOINTS_0``/``WEIGHTS_0``).

        Returns
        -------
        joints : (13380, 4) uint16 bone indices (unused slots repeat a bone with weight 0).
        weights : (13380, 4) float32, rows sum to 1.
        """
        W = self.skin_weights()
        idx = np.argsort(-W, axis=1, kind="stable")[:, :4]
        w = np.take_along_axis(W, idx, axis=1)
        w /= w.sum(axis=1, keepdims=True)
        return idx.astype(np.uint16), w.astype(np.float32)


def _rig_of(template: Template) -> Rig:
    x = template.extras
    try:
        rows = x["skin_rows"].astype(np.int64)
        vals = x["skin_vals"].astype(np.float64)
        vals /= np.bincount(rows, weights=vals, minlength=template.n_vertices)[rows]  # float32 -> 1
        return Rig(
            names=tuple(str(n) for n in x["joint_names"]),
            parents=x["joint_parents"],
            heads=x["joint_heads"].astype(np.float64),
            tails=x["joint_tails"].astype(np.float64),
            rolls=x["joint_rolls"],
            skin_rows=rows,
            skin_cols=x["skin_cols"].astype(np.int64),
            skin_vals=vals,
            head_reg_idx=x["joint_head_reg_idx"].astype(np.int64),
            head_reg_w=x["joint_head_reg_w"].astype(np.float64),
            tail_reg_idx=x["joint_tail_reg_idx"].astype(np.int64),
            tail_reg_w=x["joint_tail_reg_w"].astype(np.float64),
            n_vertices=template.n_vertices,
        )
    except KeyError as e:
        raise KeyError(
            f"template asset has no rig array {e}; rebuild it with `python -m core.assets.build`"
        ) from None


@cache
def _default_rig() -> Rig:
    return _rig_of(load_template())


def load_rig(template: Template | None = None) -> Rig:
    """The standard rig of ``template`` (default: the committed template, cached)."""
    if template is None or template is load_template():
        return _default_rig()
    return _rig_of(template)


def _check_body(V: np.ndarray, rig: Rig) -> np.ndarray:
    V = np.asarray(V, dtype=np.float64)
    if V.shape != (rig.n_vertices, 3):
        raise ValueError(
            f"V must be ({rig.n_vertices}, 3) vertices in template order (metres), got {V.shape}"
        )
    return V


def joint_positions(V: np.ndarray, *, rig: Rig | None = None, ends: str = "head") -> np.ndarray:
    """Re-place the rig's joints on a body in template order.

    Each bone end is a fixed affine combination of ~14 body vertices surrounding it on the
    template (see ``core/assets/build.py: joint_regressor``). It reproduces the template's joints
    exactly and moves with the body under any affine map, so a morphed body gets joints inside
    its own limbs.

    Parameters
    ----------
    V : (13380, 3) float vertices, metres, template order.
    rig : the rig (default :func:`load_rig`).
    ends : ``"head"`` (the joints, default) or ``"tail"``.

    Returns
    -------
    (J, 3) float64 positions, metres.
    """
    rig = rig or load_rig()
    V = _check_body(V, rig)
    if ends == "head":
        idx, w = rig.head_reg_idx, rig.head_reg_w
    elif ends == "tail":
        idx, w = rig.tail_reg_idx, rig.tail_reg_w
    else:
        raise ValueError(f"ends must be 'head' or 'tail', got {ends!r}")
    return np.einsum("jk,jkc->jc", w, V[idx])


def axis_angle(axis: np.ndarray | list[float], angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about ``axis`` (any non-zero length), right-handed."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if a.shape != (3,) or n == 0:
        raise ValueError(f"axis must be a non-zero 3-vector, got {axis!r}")
    x, y, z = a / n
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def bone_transforms(
    rotations: Mapping[str, np.ndarray],
    joints: np.ndarray,
    *,
    rig: Rig | None = None,
    validate: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """World transforms of every bone for a pose (forward kinematics).

    Parameters
    ----------
    rotations : bone name -> (3, 3) local rotation (see the module docstring); others identity.
    joints : (J, 3) rest joint (head) positions, metres.
    rig : the rig (default :func:`load_rig`).
    validate : check that every rotation is a proper (3, 3) rotation (``ValueError`` otherwise);
        False for callers whose rotations are proper by construction (the body prior's, ~2 ms
        per call saved).

    Returns
    -------
    R : (J, 3, 3) world rotations, t : (J, 3) translations (metres): a rest point ``x`` skinned
    fully to bone ``j`` goes to ``R[j] @ x + t[j]``.
    """
    rig = rig or load_rig()
    J = rig.n_joints
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape != (J, 3):
        raise ValueError(f"joints must be ({J}, 3), got {joints.shape}")
    local = np.broadcast_to(np.eye(3), (J, 3, 3)).copy()
    for name, Rm in rotations.items():
        Rm = np.asarray(Rm, dtype=np.float64)
        if not validate:
            local[rig.index(name)] = Rm
            continue
        if Rm.shape != (3, 3):
            raise ValueError(f"rotation of {name!r} must be (3, 3), got {Rm.shape}")
        if not np.allclose(Rm @ Rm.T, np.eye(3), atol=1e-6) or np.linalg.det(Rm) <= 0:
            raise ValueError(f"rotation of {name!r} is not a proper rotation matrix")
        local[rig.index(name)] = Rm
    R = np.empty((J, 3, 3))
    t = np.empty((J, 3))
    for j in range(J):  # parents first
        h = joints[j]
        p = rig.parents[j]
        if p < 0:
            R[j] = local[j]
            t[j] = h - local[j] @ h
        else:
            R[j] = R[p] @ local[j]
            t[j] = R[p] @ h + t[p] - R[j] @ h
    return R, t


def finger_rotations(
    J: np.ndarray,
    tails: np.ndarray,
    side: str,
    fist: bool,
    amount: float,
    *,
    rig: Rig | None = None,
) -> dict[str, np.ndarray]:
    """Local rotations curling (``fist``: every finger joint by ``amount`` degrees, the thumb's by
    30°, towards the palm) or spreading (by up to ``amount`` degrees) the fingers of one hand.

    ``J``, ``tails`` (J, 3): the rest body's joints (:func:`joint_positions`, heads and tails);
    ``side`` ``".L"`` or ``".R"``; the rest pose is the template's A-pose (palms down and in).
    """
    rig = rig or load_rig()
    sgn = 1.0 if side == ".L" else -1.0
    palm = np.array([-sgn, -1.0, 0.0]) / np.sqrt(2.0)  # rest A-pose palms face down and in
    across = J[rig.index("finger5-1" + side)] - J[rig.index("finger2-1" + side)]
    across /= np.linalg.norm(across)
    rot: dict[str, np.ndarray] = {}
    for f in range(1, 6):
        for k in range(1, 4):
            name = f"finger{f}-{k}{side}"
            j = rig.index(name)
            d = tails[j] - J[j]
            if fist:
                ax = np.cross(d, palm) if f == 1 else across
                ang = np.radians(30.0 if f == 1 else amount)
                R = axis_angle(ax, ang)
                if (R @ d - d) @ palm < 0:  # curl towards the palm
                    R = R.T
            else:
                if k > 1 or f == 1:
                    continue
                ang = np.radians(amount) * (f - 3.0) / 2.0  # spread about the palm normal
                R = axis_angle(palm, sgn * ang)
            rot[name] = R
    return rot


def pose_body(
    V: np.ndarray,
    rotations: Mapping[str, np.ndarray],
    *,
    rig: Rig | None = None,
    joints: np.ndarray | None = None,
    influences: int | None = None,
) -> np.ndarray:
    """Pose a body in template order by linear blend skinning with the standard rig.

    Parameters
    ----------
    V : (13380, 3) float rest-pose vertices, metres, template order (the template or any
        fitted/synthesised body).
    rotations : bone name -> (3, 3) local rotation about the bone's head, in rest-pose axes,
        composed along the parent chain. Unnamed bones keep the identity.
    rig : the rig (default :func:`load_rig`).
    joints : (J, 3) rest joint positions of this body, metres; default
        ``joint_positions(V)`` (the body's own joints).
    influences : ``4``: the skin of a glTF file (:meth:`Rig.skin_top4`, what a viewer poses);
        None (default): every weight of the rig (up to 9 bones per vertex).

    Returns
    -------
    (13380, 3) float64 posed vertices, metres.
    """
    rig = rig or load_rig()
    V = _check_body(V, rig)
    if joints is None:
        joints = joint_positions(V, rig=rig)
    R, t = bone_transforms(rotations, joints, rig=rig)
    if influences is None:
        r, c, w = rig.skin_rows, rig.skin_cols, rig.skin_vals
    elif influences == 4:
        idx, w4 = rig.skin_top4()
        keep = w4.ravel() > 0
        r = np.repeat(np.arange(len(V)), 4)[keep]
        c, w = idx.ravel().astype(np.int64)[keep], w4.ravel().astype(np.float64)[keep]
    else:
        raise ValueError(f"influences must be None or 4, got {influences!r}")
    moved = np.einsum("eab,eb->ea", R[c], V[r]) + t[c]  # each (vertex, bone) pair
    out = np.empty_like(V)
    for k in range(3):
        out[:, k] = np.bincount(r, weights=w * moved[:, k], minlength=len(V))
    return out
