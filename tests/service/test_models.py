"""Shape-model endpoints against a real ``bodyspace serve``: list, synthesise (GLB and JSON)."""

from __future__ import annotations

import numpy as np
import pytest

from service.testing import glb_vertices, validate_glb

SYN = "/v1/models/default/synthesize"
JSON = {"Accept": "application/json"}


def _vertices(r) -> np.ndarray:
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("application/json")
    V = np.asarray(r.json()["vertices"], dtype=np.float64)
    assert V.shape == (13380, 3)
    return V


def test_list_models(client):
    r = client.get("/v1/models")
    assert r.status_code == 200, r.text
    items = r.json()["items"]
    assert [m["name"] for m in items] == ["default"]
    m = items[0]
    assert m["sexes"] == ["female", "male"]
    for sex in ("female", "male"):
        space = m["spaces"][sex]
        assert space["components"] > 0
        feats = space["features"]
        assert {"height_m", "weight_kg", "age"} <= set(feats)
        assert feats["height_m"]["range"] == [1.0, 2.5] and feats["height_m"]["unit"] == "m"
        lo, hi = feats["height_m"]["training_range"]
        assert 1.3 < lo < hi < 2.1
        assert feats["age"]["range"] == [17.0, 90.0]
        assert feats["weight_kg"]["unit"] == "kg"
    assert "ANSUR" in m["provenance"]
    assert client.get("/v1/models/default").json() == m


def test_synthesize_glb_validates(client, tmp_path, gltf_validator):
    body = {"sex": "female", "height_m": 1.68, "weight_kg": 62}
    r = client.post(SYN, json=body)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "body.glb"
    path.write_bytes(r.content)
    report = validate_glb(path)
    assert report["errors"] == 0, report
    V = glb_vertices(r.content).astype(np.float64)
    assert V.shape == (13380, 3)
    assert abs(V[:, 1].max() - V[:, 1].min() - 1.68) < 0.005


@pytest.mark.parametrize(
    ("sex", "height", "weight"), [("female", 1.60, 55.0), ("male", 1.85, 90.0)]
)
def test_synthesize_json_has_requested_height(client, sex, height, weight):
    r = client.post(SYN, json={"sex": sex, "height_m": height, "weight_kg": weight}, headers=JSON)
    V = _vertices(r)
    stature = V[:, 1].max() - V[:, 1].min()
    assert abs(stature - height) < 0.005, f"stature {stature:.4f} m, asked {height} m"
    body = r.json()
    F = np.asarray(body["faces"])
    assert F.ndim == 2 and F.shape[1] == 3 and F.min() == 0 and F.max() == 13379
    meas = body["measurements"]
    assert abs(meas["stature"] - height) < 0.02
    assert abs(meas["weightkg"] - weight) < 0.15 * weight


def test_synthesize_with_a_measurement_and_pca(client):
    r = client.post(
        SYN, json={"sex": "male", "height_m": 1.78, "waistcircumference": 0.9}, headers=JSON
    )
    _vertices(r)
    V0 = _vertices(client.post(SYN, json={"sex": "male", "pca": [0.0]}, headers=JSON))
    V1 = _vertices(client.post(SYN, json={"sex": "male", "pca": [5.0]}, headers=JSON))
    assert np.abs(V1 - V0).max() > 0.005


def test_seed_is_reproducible(client):
    a = _vertices(client.post(SYN, json={"sex": "male", "seed": 7}, headers=JSON))
    b = _vertices(client.post(SYN, json={"sex": "male", "seed": 7}, headers=JSON))
    c = _vertices(client.post(SYN, json={"sex": "male", "seed": 8}, headers=JSON))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.001
    g1 = client.post(SYN, json={"sex": "female", "seed": 3})
    g2 = client.post(SYN, json={"sex": "female", "seed": 3})
    assert g1.status_code == 200 and g1.content == g2.content


@pytest.mark.parametrize(
    ("body", "feature"),
    [
        ({"sex": "female", "height_m": 3.0}, "height_m"),
        ({"sex": "male", "weight_kg": 5}, "weight_kg"),
        ({"sex": "male", "pca": [100.0]}, "pca[0]"),
    ],
)
def test_out_of_range_is_422_naming_the_range(client, body, feature):
    r = client.post(SYN, json=body)
    assert r.status_code == 422, r.text
    err = r.json()["error"]
    assert err["code"] == "out_of_range"
    assert err["details"]["feature"] == feature
    lo, hi = err["details"]["supported"]
    assert lo < hi
    assert "support" in err["message"]
    if feature == "height_m":
        assert "1–2.5 m" in err["message"] and "training range is 1.41–1.86 m" in err["message"]


@pytest.mark.parametrize(
    ("body", "code"),
    [
        ({"height_m": 1.7}, "missing_field"),
        ({"sex": "robot", "height_m": 1.7}, "validation_error"),
        ({"sex": "female", "height_m": "tall"}, "validation_error"),
        ({"sex": "female", "seed": -1}, "validation_error"),
        ({"sex": "female", "pca": [0.1], "seed": 1}, "validation_error"),
        ({"sex": "female", "pca": [0.0] * 500}, "validation_error"),
        ({"sex": "female", "chestcircumference": "wide"}, "validation_error"),
        ({"sex": "female", "shoe_size": 42}, "out_of_range"),
    ],
)
def test_malformed_body_is_422(client, body, code):
    r = client.post(SYN, json=body)
    assert r.status_code == 422, r.text
    assert r.json()["error"]["code"] == code


def test_unknown_model_is_404(client):
    r = client.post("/v1/models/nope/synthesize", json={"sex": "female", "height_m": 1.7})
    assert r.status_code == 404
    assert r.json()["error"]["code"] == "not_found"
    assert client.get("/v1/models/nope").status_code == 404


def test_no_key_is_401(server):
    import httpx

    with httpx.Client(base_url=server["url"]) as c:
        assert c.get("/v1/models").status_code == 401
        r = c.post(SYN, json={"sex": "female", "height_m": 1.7})
        assert r.status_code == 401
        assert r.json()["error"]["code"] == "missing_api_key"


def test_the_141_kg_soldier_through_the_server(client):
    """Issue 12: the held-out ANSUR II soldier (male, 1.85 m, 141 kg) got 422 (the model
    stopped at 136 kg). Now: the body, with the warning in the GLB's header and the JSON."""
    import json

    body = {"sex": "male", "height_m": 1.85, "weight_kg": 141.0}
    r = client.post(SYN, json=body)
    assert r.status_code == 200, r.text
    (w,) = json.loads(r.headers["x-bodyspace-warnings"])
    assert w.startswith("weight_kg=141 kg is beyond the model's training range")
    V = glb_vertices(r.content).astype(np.float64)
    assert abs(V[:, 1].max() - V[:, 1].min() - 1.85) < 0.005
    js = client.post(SYN, json=body, headers=JSON)
    assert js.json()["warnings"] == [w]
    assert abs(js.json()["measurements"]["weightkg"] - 141.0) < 0.02 * 141.0
    np.testing.assert_allclose(_vertices(js), V, atol=1e-6)  # GLB floats are float32


def test_no_warning_inside_the_training_range(client):
    body = {"sex": "female", "height_m": 1.65, "weight_kg": 62.0, "age": 30}
    r = client.post(SYN, json=body)
    assert r.status_code == 200 and "x-bodyspace-warnings" not in r.headers
    assert client.post(SYN, json=body, headers=JSON).json()["warnings"] == []


@pytest.mark.parametrize(
    ("body", "feature", "text"),
    [
        ({"sex": "female", "height_m": 0.95}, "height_m", "supported range 1–2.5 m"),
        ({"sex": "male", "height_m": 2.6}, "height_m", "supported range 1–2.5 m"),
        ({"sex": "male", "height_m": 1.8, "weight_kg": 30}, "weight_kg", "9.3 kg/m²"),
        ({"sex": "male", "height_m": 1.8, "weight_kg": 270}, "weight_kg", "83.3 kg/m²"),
        ({"sex": "female", "age": 12}, "age", "supported range 17–90 years"),
        ({"sex": "female", "age": 95}, "age", "supported range 17–90 years"),
    ],
)
def test_meaningless_bodies_are_refused_naming_the_range(client, body, feature, text):
    r = client.post(SYN, json=body)
    assert r.status_code == 422, r.text
    err = r.json()["error"]
    assert err["code"] == "out_of_range" and err["details"]["feature"] == feature
    assert text in err["message"]
