"""Rigging and posing over HTTP against a real ``bodyspace serve``: ``GET /v1/bodies/{id}?rig=true``
(skinned GLB, validator-clean) and ``POST /v1/bodies/{id}/pose`` (a new stored body equal to
``core.transfer.rig.pose`` of the body)."""

from __future__ import annotations

import numpy as np

from core.rig import axis_angle
from core.transfer.rig import pose, posture
from service.testing import glb_parts, glb_vertices, validate_glb

JSON = {"Accept": "application/json"}


def _create(client, **body) -> dict:
    r = client.post("/v1/bodies", json=body)
    assert r.status_code == 201, r.text
    return r.json()


def _mesh(client, body_id: str) -> np.ndarray:
    r = client.get(f"/v1/bodies/{body_id}", headers=JSON)
    assert r.status_code == 200, r.text
    return np.asarray(r.json()["vertices"], dtype=np.float64)


def test_rigged_glb(client, tmp_path, gltf_validator):
    b = _create(client, sex="female", height_m=1.62, weight_kg=60)
    r = client.get(f"/v1/bodies/{b['id']}", params={"rig": "true"})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "rig.glb"
    path.write_bytes(r.content)
    report = validate_glb(path)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, _ = glb_parts(r.content)
    assert len(doc["skins"][0]["joints"]) == 163
    assert doc["nodes"][0]["skin"] == 0
    np.testing.assert_allclose(glb_vertices(r.content), _mesh(client, b["id"]), atol=1e-6)


def test_pose_stores_a_new_body(client, tmp_path, gltf_validator):
    b = _create(client, sex="male", height_m=1.78, weight_kg=80)
    V = _mesh(client, b["id"])
    r = client.post(
        f"/v1/bodies/{b['id']}/pose",
        json={"posture": "seated", "rotations": {"lowerleg01.R": [0.3, 0, 0]}},
    )
    assert r.status_code == 201, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "posed.glb"
    path.write_bytes(r.content)
    assert validate_glb(path)["errors"] == 0
    new_id = r.headers["location"].rsplit("/", 1)[-1]
    rot = posture("seated")
    rot["lowerleg01.R"] = axis_angle([1, 0, 0], 0.3)
    # seated rests on the seat by default (core.transfer.seat), plain LBS when asked
    np.testing.assert_allclose(_mesh(client, new_id), pose(V, rot, seat_contact=True), atol=1e-9)
    r = client.post(
        f"/v1/bodies/{b['id']}/pose",
        json={"posture": "seated", "seat_contact": False},
        headers=JSON,
    )
    assert r.status_code == 201 and r.json()["params"]["seat_contact"] is False, r.text
    np.testing.assert_allclose(r.json()["vertices"], pose(V, posture("seated")), atol=1e-9)
    meta = client.get(f"/v1/bodies/{new_id}", headers=JSON).json()
    assert meta["source"] == "pose" and meta["derived_from"] == b["id"]
    assert meta["features"] == b["features"]  # the rest body's
    # a posed body is not re-posed, edited or rigged
    for method, url, body in (
        ("post", f"/v1/bodies/{new_id}/pose", {"posture": "reach"}),
        ("post", f"/v1/bodies/{new_id}/edit", {"delta": {"weight_kg": 5}}),
        ("get", f"/v1/bodies/{new_id}?rig=true", None),
    ):
        r = client.request(method.upper(), url, json=body)
        assert r.status_code == 422 and "derived_from" in r.json()["error"]["message"], r.text


def test_pose_errors(client):
    b = _create(client, sex="female", seed=3)["id"]
    for body, needle in (
        ({}, "posture"),
        ({"posture": "lying"}, "posture"),
        ({"rotations": {"nosuchbone": [0, 0, 1]}}, "nosuchbone"),
        ({"rotations": {"head": [0, 1]}}, "3 finite numbers"),
        ({"posture": "standing", "seat_contact": True}, "no seat"),
        ({"posture": "seated", "seat_contact": 0}, "seat_contact"),  # strict: 0 is no boolean
    ):
        r = client.post(f"/v1/bodies/{b}/pose", json=body)
        assert r.status_code == 422, (body, r.text)
        assert needle in r.text, (body, r.text)
    r = client.post("/v1/bodies/bdy_nope/pose", json={"posture": "seated"})
    assert r.status_code == 404
