"""Skeleton and skin transfer: joints follow the body (scaling, inside 100 bodies), the skinned
GLB is validator-clean and a glTF viewer's skinning of it equals our LBS, named postures."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry import winding_number
from core.rig import bone_transforms, load_rig, pose_body
from core.shapespace.ansur import load_ansur
from core.shapespace.model import load_model
from core.template import load_template
from core.transfer.rig import POSTURES, body_joints, pose, posture, rig_glb
from service.testing import glb_parts, validate_glb


@pytest.fixture(scope="module")
def body() -> np.ndarray:
    return load_model().synthesize("male", {"height_m": 1.80, "weight_kg": 85.0})


@pytest.mark.parametrize("method", ["regressor", "markers"])
def test_joints_scale_and_move_with_the_body(body, method):
    J = body_joints(body, method=method)
    t = np.array([0.3, -0.2, 1.1])
    for s in (0.8, 1.25):
        # float32 regressor weights sum to 1 within ~1e-7: 0.1 µm at 1 m
        np.testing.assert_allclose(body_joints(s * body + t, method=method), s * J + t, atol=1e-7)
    tpl = load_template()
    np.testing.assert_allclose(body_joints(tpl.V, method=method), load_rig().heads, atol=1e-6)


def _subjects(sex: str, k: int, rng: np.random.Generator) -> list[tuple[float, float]]:
    """(stature, weight) of ANSUR II subjects inside the 1st-99th percentile box of both: the
    four extremes of the box and random others (real, so plausible, combinations)."""
    a = load_ansur(sex)
    h, w = a["stature"], a["weightkg"]
    box = (
        (h >= np.percentile(h, 1)) & (h <= np.percentile(h, 99))
        & (w >= np.percentile(w, 1)) & (w <= np.percentile(w, 99))
    )  # fmt: skip
    idx = np.flatnonzero(box)
    ends = [idx[np.argmin(h[idx])], idx[np.argmax(h[idx])]]
    ends += [idx[np.argmin(w[idx])], idx[np.argmax(w[idx])]]
    rest = rng.choice(np.setdiff1d(idx, ends), k - len(ends), replace=False)
    return [(float(h[i]), float(w[i])) for i in [*ends, *rest]]


def skeleton_joints() -> np.ndarray:
    """(J,) bool: the joints of the skeleton that lie inside the template -- 103 of 163: not
    the 59 face-expression bones under ``head`` (placed on skin vertices or in the mouth by
    MakeHuman) nor the root (on the skin of the lower back)."""
    tpl, rig = load_template(), load_rig()
    face = set(rig.descendants("head")) - {rig.index("head")}
    inside = winding_number(tpl.V, tpl.F, rig.heads, chunk=16) > 0.5
    inside[sorted(face)] = False
    return inside


def test_joints_inside_100_bodies():
    """Every skeleton joint inside the template (:func:`skeleton_joints`) stays inside each of
    100 bodies: generalised winding number > 0.5."""
    tpl, rig, model = load_template(), load_rig(), load_model()
    inside = skeleton_joints()
    assert inside.sum() == 103 and not inside[rig.index("root")]
    rng = np.random.default_rng(0)
    n = 0
    for sex in ("female", "male"):
        for h, w in _subjects(sex, 50, rng):
            V = model.synthesize(sex, {"height_m": h, "weight_kg": w})
            J = body_joints(V)[inside]
            wn = winding_number(V, tpl.F, J, chunk=16, dtype=np.float32)  # joints lie deep inside
            bad = [rig.names[j] for j, x in zip(np.flatnonzero(inside), wn, strict=True) if x < 0.5]
            assert not bad, (sex, h, w, bad)
            n += 1
    assert n == 100


def _gltf_skinning(data: bytes, rotations: dict[str, np.ndarray]) -> np.ndarray:
    """What a glTF viewer does with our skinned GLB when the joint nodes get ``rotations``:
    joint matrix = global node transform x inverse bind matrix, 4 weighted influences."""
    doc, accessor = glb_parts(data)
    prim = doc["meshes"][0]["primitives"][0]
    P = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
    Jn = accessor(prim["attributes"]["JOINTS_0"]).astype(np.int64)
    W = accessor(prim["attributes"]["WEIGHTS_0"]).astype(np.float64)
    skin = doc["skins"][0]
    IBM = accessor(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    nodes = doc["nodes"]
    parent = {c: i for i, nd in enumerate(nodes) for c in nd.get("children", [])}
    G: dict[int, np.ndarray] = {}
    for ni in skin["joints"]:  # parents first
        nd = nodes[ni]
        L = np.eye(4)
        L[:3, 3] = nd["translation"]
        if nd["name"] in rotations:
            L[:3, :3] = rotations[nd["name"]]
        G[ni] = G[parent[ni]] @ L if ni in parent else L
    JM = np.stack([G[ni] @ IBM[k] for k, ni in enumerate(skin["joints"])])
    Ph = np.c_[P, np.ones(len(P))]
    out = np.zeros((len(P), 4))
    for c in range(4):
        out += W[:, c : c + 1] * np.einsum("nab,nb->na", JM[Jn[:, c]], Ph)
    return out[:, :3]


def test_skinned_glb_validates_and_poses_like_lbs(body, tmp_path):
    data = rig_glb(body)
    path = tmp_path / "rig.glb"
    path.write_bytes(data)
    report = validate_glb(path)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(data)
    rig = load_rig()
    assert len(doc["skins"][0]["joints"]) == rig.n_joints
    prim = doc["meshes"][0]["primitives"][0]
    W = accessor(prim["attributes"]["WEIGHTS_0"])
    assert W.dtype == np.float32 and W.shape == (13380, 4)
    assert np.abs(W.sum(axis=1, dtype=np.float64) - 1).max() < 1e-6
    for name in POSTURES:
        rot = posture(name)
        ours = _gltf_skinning(data, rot)
        lbs = pose_body(body, rot, rig=rig, influences=4)  # the template rig, the GLB's skin
        assert np.linalg.norm(ours - lbs, axis=1).max() < 1e-3, name
        P = pose(body, rot)
        np.testing.assert_allclose(P, lbs - [0.0, lbs[:, 1].min(), 0.0], atol=1e-12)


def test_postures(body):
    rig = load_rig()
    J = body_joints(body)

    def posed(name: str) -> np.ndarray:
        R, t = bone_transforms(posture(name), J)
        return np.einsum("jab,jb->ja", R, J) + t

    hip, knee, ankle = (rig.index(b) for b in ("upperleg01.L", "lowerleg01.L", "foot.L"))
    s = posed("seated")
    assert abs(s[knee, 1] - s[hip, 1]) < 0.05  # thigh horizontal
    assert s[knee, 2] - s[hip, 2] > 0.35  # and forward
    assert s[knee, 1] - s[ankle, 1] > 0.3  # shank down
    r = posed("reach")
    wrist, shoulder = rig.index("wrist.R"), rig.index("upperarm01.R")
    assert r[wrist, 1] > r[shoulder, 1] and r[wrist, 2] - r[shoulder, 2] > 0.3
    st = posed("standing")
    assert st[rig.index("wrist.L"), 1] < J[rig.index("wrist.L"), 1] - 0.05  # arms lowered
    with pytest.raises(ValueError, match="postures: standing"):
        posture("lying")
