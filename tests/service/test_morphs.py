"""Morphing over HTTP against a real ``bodyspace serve``: ``POST /v1/morphs`` (GLB with morph
targets, validator-clean; base + delta = each body within 1e-4 m) and ``POST /v1/bodies``
``{"morph": …}`` (a stored in-between body; t = 0 and t = 1 reproduce the bodies exactly)."""

from __future__ import annotations

import numpy as np

from service.testing import glb_parts, validate_glb

JSON = {"Accept": "application/json"}


def _create(client, **body) -> dict:
    r = client.post("/v1/bodies", json=body)
    assert r.status_code == 201, r.text
    return r.json()


def _mesh(client, body_id: str) -> np.ndarray:
    r = client.get(f"/v1/bodies/{body_id}", headers=JSON)
    assert r.status_code == 200, r.text
    return np.asarray(r.json()["vertices"], dtype=np.float64)


def test_morph_glb(client, tmp_path, gltf_validator):
    ids = [
        _create(client, sex="female", height_m=1.58, weight_kg=55)["id"],
        _create(client, sex="male", height_m=1.86, weight_kg=95)["id"],
        _create(client, sex="male", seed=5)["id"],
    ]
    r = client.post("/v1/morphs", json={"bodies": ids})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "morph.glb"
    path.write_bytes(r.content)
    report = validate_glb(path)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(r.content)
    mesh = doc["meshes"][0]
    assert mesh["extras"]["targetNames"] == ids[1:]
    prim = mesh["primitives"][0]
    base = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
    assert np.abs(base - _mesh(client, ids[0])).max() < 1e-6
    for tg, i in zip(prim["targets"], ids[1:], strict=True):
        dV = accessor(tg["POSITION"]).astype(np.float64)
        assert np.abs(base + dV - _mesh(client, i)).max() < 1e-4
        assert "NORMAL" in tg


def test_morph_errors(client, client_b):
    a = _create(client, sex="female", seed=1)["id"]
    r = client.post("/v1/morphs", json={"bodies": [a]})
    assert r.status_code == 422 and r.json()["error"]["code"] == "validation_error", r.text
    r = client.post("/v1/morphs", json={"bodies": [a] * 17})
    assert r.status_code == 422, r.text
    r = client.post("/v1/morphs", json={"bodies": [a, a]})
    assert r.status_code == 422 and "at most once" in r.json()["error"]["message"], r.text
    r = client_b.post("/v1/morphs", json={"bodies": [a, a]})  # another tenant's: not found
    assert r.status_code in (404, 422), r.text
    b = _create(client_b, sex="male", seed=2)["id"]
    r = client.post("/v1/morphs", json={"bodies": [a, b]})
    assert r.status_code == 404, r.text


def test_stored_in_between_body(client):
    a = _create(client, sex="female", height_m=1.60, weight_kg=58)
    b = _create(client, sex="male", height_m=1.85, weight_kg=90)
    Va, Vb = _mesh(client, a["id"]), _mesh(client, b["id"])
    for t, want in ((0.0, Va), (1.0, Vb)):
        out = _create(client, morph={"from": a["id"], "to": b["id"], "t": t})
        assert np.array_equal(_mesh(client, out["id"]), want)
    out = _create(client, morph={"from": a["id"], "to": b["id"], "t": 0.3})
    assert out["source"] == "morph" and out["sex"] == "female"
    assert out["derived_from"] == a["id"]
    assert out["params"]["morph"] == {"from": a["id"], "to": b["id"], "t": 0.3}
    np.testing.assert_allclose(_mesh(client, out["id"]), 0.7 * Va + 0.3 * Vb, atol=1e-12)
    h = out["features"]["height_m"]
    assert a["features"]["height_m"] < h < b["features"]["height_m"]
    out = _create(client, morph={"from": a["id"], "to": b["id"], "t": 0.8})
    assert out["sex"] == "male"
    bad = [
        {"morph": {"from": a["id"], "to": b["id"], "t": 1.5}},
        {"morph": {"from": a["id"], "to": b["id"], "t": 0.5}, "seed": 3},
        {"morph": {"from": a["id"], "to": b["id"], "t": 0.5}, "height_m": 1.7},
    ]
    for body in bad:
        r = client.post("/v1/bodies", json=body)
        assert r.status_code == 422, (body, r.text)
    r = client.post("/v1/bodies", json={"morph": {"from": a["id"], "to": "bdy_nope", "t": 0.5}})
    assert r.status_code == 404, r.text
    r = client.post("/v1/bodies", json={"height_m": 1.7})
    assert r.status_code == 422 and r.json()["error"]["details"]["field"] == "sex", r.text
