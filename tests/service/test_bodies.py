"""Stored bodies against a real ``bodyspace serve``: create (from a model or a fit), mesh (GLB and
JSON), measurements, edit, tenancy, listing, deletion (also with the scan and fit they came from).

Bounds: a synthesised body's measured stature is within 5 mm of the request; +10 kg changes the
reported weight by 10 ± 0.5 kg and moves the face and hands (template parts head, hand_L,
hand_R — what ``ShapeModel.edit`` keeps by default) by < 2 mm.
"""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from core.io import read_mesh
from core.synth import random_body
from core.template import load_template
from service.testing import (
    free_port,
    glb_vertices,
    service_env,
    start_server,
    upload_scan,
    validate_glb,
    wait_state,
)

JSON = {"Accept": "application/json"}
FAST = {"schedule": "fast"}
KEPT = ("head", "hand_L", "hand_R")


def _create(client, **body) -> dict:
    r = client.post("/v1/bodies", json=body)
    assert r.status_code == 201, r.text
    out = r.json()
    assert r.headers["location"] == f"/v1/bodies/{out['id']}"
    return out


def _mesh(client, body_id: str) -> np.ndarray:
    r = client.get(f"/v1/bodies/{body_id}", headers=JSON)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("application/json")
    V = np.asarray(r.json()["vertices"], dtype=np.float64)
    assert V.shape == (13380, 3)
    return V


def _kept_mask() -> np.ndarray:
    tpl = load_template()
    return np.logical_or.reduce([tpl.part_mask(p) for p in KEPT])


def _error(r, code: str) -> dict:
    assert r.status_code == 422, r.text
    err = r.json()["error"]
    assert err["code"] == code, err
    assert err["message"]
    return err


def _db_rows(server, table: str, ids: list[str]) -> int:
    with sqlite3.connect(server["data"] / "bodyspace.db") as db:
        q = f"SELECT COUNT(*) FROM {table} WHERE id IN ({','.join('?' * len(ids))})"
        return db.execute(q, ids).fetchone()[0]


# ----------------------------------------------------------------------------- from a model


def test_create_from_features_has_requested_stature(client):
    out = _create(client, sex="female", height_m=1.72, weight_kg=70)
    assert out["id"].startswith("bdy_")
    assert out["model"] == "default" and out["sex"] == "female" and out["source"] == "model"
    assert out["fit_id"] is None and out["derived_from"] is None
    assert out["params"] == {"height_m": 1.72, "weight_kg": 70.0}
    assert abs(out["features"]["height_m"] - 1.72) < 0.005
    assert abs(out["features"]["weight_kg"] - 70) < 0.15 * 70
    assert {"age", "waistcircumference"} <= set(out["features"])

    r = client.get(f"/v1/bodies/{out['id']}/measurements")
    assert r.status_code == 200, r.text
    m = r.json()
    assert m["body_id"] == out["id"] and m["sex"] == "female" and m["density_kg_m3"] > 900
    meas = m["measurements"]
    assert len(meas) >= 20
    assert meas["stature"]["unit"] == "m" and meas["weightkg"]["unit"] == "kg"
    assert abs(meas["stature"]["value"] - 1.72) < 0.005, meas["stature"]
    assert abs(meas["weightkg"]["value"] - out["features"]["weight_kg"]) < 1e-6
    assert 0.5 < meas["waistcircumference"]["value"] < 1.3


def test_body_glb_validates_and_json_has_the_same_mesh(client, tmp_path, gltf_validator):
    out = _create(client, sex="male", seed=11)
    r = client.get(f"/v1/bodies/{out['id']}")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "body.glb"
    path.write_bytes(r.content)
    report = validate_glb(path)
    assert report["errors"] == 0, report

    j = client.get(f"/v1/bodies/{out['id']}", headers=JSON).json()
    assert {k: j[k] for k in out} == out  # the metadata of POST, plus the mesh
    V = np.asarray(j["vertices"])
    F = np.asarray(j["faces"])
    assert V.shape == (13380, 3) and F.ndim == 2 and F.shape[1] == 3
    assert F.min() == 0 and F.max() == 13379
    np.testing.assert_allclose(glb_vertices(r.content), V, atol=1e-6)
    # stored at full precision: the same body as the synthesis endpoint's (float64 JSON)
    syn = client.post(
        "/v1/models/default/synthesize", json={"sex": "male", "seed": 11}, headers=JSON
    )
    np.testing.assert_array_equal(np.asarray(syn.json()["vertices"]), V)


def test_create_from_pca(client):
    a = _mesh(client, _create(client, sex="female", pca=[0.0])["id"])
    b = _mesh(client, _create(client, sex="female", pca=[4.0, -1.0])["id"])
    assert np.abs(a - b).max() > 0.005


def test_edit_plus_10_kg_keeps_face_and_hands(client):
    src = _create(client, sex="female", height_m=1.65, weight_kg=60)
    V0 = _mesh(client, src["id"])
    r = client.post(f"/v1/bodies/{src['id']}/edit", json={"delta": {"weight_kg": 10}}, headers=JSON)
    assert r.status_code == 201, r.text
    new = r.json()
    assert r.headers["location"] == f"/v1/bodies/{new['id']}"
    assert new["id"] != src["id"] and new["source"] == "edit"
    assert new["derived_from"] == src["id"] and new["sex"] == "female"
    assert new["params"]["keep"] == list(KEPT)
    dw = new["features"]["weight_kg"] - src["features"]["weight_kg"]
    assert abs(dw - 10) < 0.5, f"weight changed by {dw:.2f} kg"
    V1 = np.asarray(new["vertices"])
    np.testing.assert_array_equal(V1, _mesh(client, new["id"]))  # stored as answered
    moved = np.linalg.norm(V1 - V0, axis=1) * 1000
    kept = _kept_mask()
    assert moved[kept].max() < 2.0, f"face/hands moved {moved[kept].max():.2f} mm"
    assert moved[~kept].max() > 10.0  # the rest of the body did change
    m = client.get(f"/v1/bodies/{new['id']}/measurements").json()["measurements"]
    assert abs(m["weightkg"]["value"] - new["features"]["weight_kg"]) < 1e-6
    # the source is unchanged
    np.testing.assert_array_equal(_mesh(client, src["id"]), V0)


def test_edit_glb_by_default_and_options(client, tmp_path, gltf_validator):
    src = _create(client, sex="male", height_m=1.80, weight_kg=80)
    V0 = _mesh(client, src["id"])
    r = client.post(f"/v1/bodies/{src['id']}/edit", json={"delta": {"height_m": 0.05}})
    assert r.status_code == 201, r.text
    assert r.headers["content-type"] == "model/gltf-binary"
    path = tmp_path / "edit.glb"
    path.write_bytes(r.content)
    assert validate_glb(path)["errors"] == 0
    new_id = r.headers["location"].rsplit("/", 1)[-1]
    V1 = _mesh(client, new_id)
    np.testing.assert_allclose(glb_vertices(r.content), V1, atol=1e-6)
    taller = client.get(f"/v1/bodies/{new_id}", headers=JSON).json()["features"]["height_m"]
    assert abs(taller - src["features"]["height_m"] - 0.05) < 0.002
    # face and hands keep their shape and follow the taller body (a rigid shift)
    tpl = load_template()
    for part in KEPT:
        D = (V1 - V0)[tpl.part_mask(part)]
        assert np.linalg.norm(D - D.mean(axis=0), axis=1).max() < 1e-6
    assert (V1 - V0)[tpl.part_mask("head"), 1].mean() > 0.04

    # keep=[]: the plain paper edit moves the head and hands too; a target is an absolute value
    r = client.post(
        f"/v1/bodies/{src['id']}/edit",
        json={"target": {"weight_kg": 90}, "keep": []},
        headers=JSON,
    )
    assert r.status_code == 201, r.text
    new = r.json()
    assert abs(new["features"]["weight_kg"] - 90) < 0.5
    assert new["params"]["keep"] == [] and new["params"]["target"] == {"weight_kg": 90.0}
    moved = np.linalg.norm(np.asarray(new["vertices"]) - V0, axis=1) * 1000
    assert moved[_kept_mask()].max() > 2.0


@pytest.mark.parametrize(
    ("edit", "code", "field"),
    [
        ({"delta": {"shoe_size": 1}}, "out_of_range", "shoe_size"),
        ({"target": {"shoe_size": 44}}, "out_of_range", "shoe_size"),
        ({"delta": {"weight_kg": 200}}, "out_of_range", "weight_kg"),
        ({"delta": {"height_m": 1.5}}, "out_of_range", "height_m"),
        ({"target": {"waistcircumference": 3.0}}, "out_of_range", "waistcircumference"),
        ({"delta": {"weight_kg": "ten"}}, "validation_error", None),
        ({"delta": {"weight_kg": True}}, "validation_error", None),
        ({"delta": {}}, "validation_error", "delta"),
        ({"delta": {"weight_kg": 1}, "target": {"weight_kg": 70}}, "validation_error", None),
        ({"delta": {"weight_kg": 1}, "keep": ["face"]}, "validation_error", "keep"),
        ({"delta": {"weight_kg": 1}, "colour": "red"}, "validation_error", None),
    ],
    ids=[
        "unknown-delta",
        "unknown-target",
        "too-heavy",
        "too-tall",
        "target-out-of-range",
        "string",
        "bool",
        "empty",
        "delta-and-target",
        "unknown-part",
        "extra-field",
    ],
)
def test_bad_edits_are_422(client, edit, code, field):
    src = _create(client, sex="female", height_m=1.65, weight_kg=60)
    before = client.get("/v1/bodies", params={"limit": 200}).json()["items"]
    err = _error(client.post(f"/v1/bodies/{src['id']}/edit", json=edit), code)
    d = err["details"]
    if field is not None:
        assert d.get("feature", d.get("field")) == field, err
    if code == "out_of_range" and field == "shoe_size":
        assert {"height_m", "weight_kg", "age"} <= set(d["accepted"])
        assert "weight_kg" in err["message"]  # the message lists the valid names
    elif code == "out_of_range":
        lo, hi = d["supported"]
        assert lo < hi and "supported range" in err["message"]
    if field == "keep":
        assert "head" in d["accepted"] and "hand_L" in err["message"]
    after = client.get("/v1/bodies", params={"limit": 200}).json()["items"]
    assert len(after) == len(before)  # nothing stored


@pytest.mark.parametrize(
    ("body", "code"),
    [
        ({"sex": "female", "height_m": 3.0}, "out_of_range"),
        ({"sex": "female", "shoe_size": 42}, "out_of_range"),
        ({"sex": "female", "pca": [0.1], "seed": 1}, "validation_error"),
        ({"height_m": 1.7}, "missing_field"),
        ({"sex": "female", "model": "nope"}, "validation_error"),
        ({"sex": "female", "fit_id": "fit_x", "height_m": 1.7}, "validation_error"),
        ({"fit_id": "fit_x"}, "missing_field"),
    ],
)
def test_bad_creates_are_422(client, body, code):
    _error(client.post("/v1/bodies", json=body), code)


def test_bad_json_and_content_type(client):
    src = _create(client, sex="male", seed=1)
    for url in ("/v1/bodies", f"/v1/bodies/{src['id']}/edit"):
        r = client.post(
            url, content=b'{"delta": {"weight_kg": 1', headers={"content-type": "application/json"}
        )
        _error(r, "validation_error")
        r = client.post(url, content=b"delta=1", headers={"content-type": "text/plain"})
        assert r.status_code == 415, r.text
        assert r.json()["error"]["code"] == "unsupported_media_type"


# ----------------------------------------------------------------------------- tenancy, listing


def test_other_tenant_sees_nothing(client, client_b):
    out = _create(client, sex="female", seed=5)
    bid = out["id"]
    for path in (f"/v1/bodies/{bid}", f"/v1/bodies/{bid}/measurements"):
        r = client_b.get(path)
        assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"
    r = client_b.post(f"/v1/bodies/{bid}/edit", json={"delta": {"weight_kg": 5}})
    assert r.status_code == 404
    assert client_b.delete(f"/v1/bodies/{bid}").status_code == 404
    assert bid not in [b["id"] for b in client_b.get("/v1/bodies").json()["items"]]
    assert client.get(f"/v1/bodies/{bid}").status_code == 200  # still there


def test_list_is_paginated(client):
    ids = {_create(client, sex="male", seed=s)["id"] for s in (21, 22, 23)}
    seen, cursor = [], None
    while True:
        params = {"limit": 2, **({"cursor": cursor} if cursor else {})}
        page = client.get("/v1/bodies", params=params).json()
        assert len(page["items"]) <= 2
        seen += [b["id"] for b in page["items"]]
        cursor = page["next_cursor"]
        if not cursor:
            break
    assert ids <= set(seen) and len(seen) == len(set(seen))
    models = client.get("/v1/bodies", params={"source": "model", "limit": 200}).json()["items"]
    assert models and all(b["source"] == "model" for b in models)
    r = client.get("/v1/bodies", params={"cursor": "###"})
    _error(r, "validation_error")


def test_delete_body(client, server):
    src = _create(client, sex="female", seed=9)
    child = client.post(
        f"/v1/bodies/{src['id']}/edit", json={"delta": {"weight_kg": 5}}, headers=JSON
    ).json()
    blobs = server["data"] / "blobs"
    assert list(blobs.glob(f"*/bodies/{src['id']}/vertices.npy"))
    assert client.delete(f"/v1/bodies/{src['id']}").status_code == 204
    assert client.get(f"/v1/bodies/{src['id']}").status_code == 404
    assert client.get(f"/v1/bodies/{src['id']}/measurements").status_code == 404
    assert not list(blobs.glob(f"*/bodies/{src['id']}*"))
    assert client.delete(f"/v1/bodies/{src['id']}").status_code == 404
    # a body edited from it stays, without its (gone) source
    kept = client.get(f"/v1/bodies/{child['id']}", headers=JSON).json()
    assert kept["derived_from"] is None and kept["source"] == "edit"


# ----------------------------------------------------------------------------- from a fit


def test_fit_body_edit_and_deletion_with_its_scan(client, client_b, server, sim):
    sex = random_body(np.random.default_rng(0), pose=False).sex  # the body of ``sim`` (seed 0)
    scan = upload_scan(client, sim).json()
    fit = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()
    assert wait_state(client, fit["id"])["state"] == "succeeded"

    # sex is required: a scan has none
    _error(client.post("/v1/bodies", json={"fit_id": fit["id"]}), "missing_field")
    assert client_b.post("/v1/bodies", json={"fit_id": fit["id"], "sex": sex}).status_code == 404
    body = _create(client, fit_id=fit["id"], sex=sex)
    assert body["source"] == "fit" and body["fit_id"] == fit["id"] and body["sex"] == sex
    assert body["params"] == {"fit_id": fit["id"]}
    truth_h = sim.truth[:, 1].max() - sim.truth[:, 1].min()
    assert abs(body["features"]["height_m"] - truth_h) < 0.01

    # the stored body is the fit's result at full precision
    ply = client.get(f"/v1/fits/{fit['id']}/result", params={"format": "ply"})
    V_fit = read_mesh(ply.content, "ply").V
    V0 = _mesh(client, body["id"])
    np.testing.assert_array_equal(V0, V_fit)

    r = client.post(
        f"/v1/bodies/{body['id']}/edit", json={"delta": {"weight_kg": 10}}, headers=JSON
    )
    assert r.status_code == 201, r.text
    edited = r.json()
    assert edited["fit_id"] == fit["id"] and edited["derived_from"] == body["id"]
    dw = edited["features"]["weight_kg"] - body["features"]["weight_kg"]
    assert abs(dw - 10) < 0.5, f"weight changed by {dw:.2f} kg"
    moved = np.linalg.norm(np.asarray(edited["vertices"]) - V0, axis=1) * 1000
    assert moved[_kept_mask()].max() < 2.0
    assert moved.max() > 10.0

    listed = client.get("/v1/bodies", params={"fit_id": fit["id"]}).json()["items"]
    assert {b["id"] for b in listed} == {body["id"], edited["id"]}

    # deleting the scan deletes the bodies made from its fits (derived personal data)
    blobs = server["data"] / "blobs"
    assert len(list(blobs.glob(f"*/fits/{fit['id']}/bodies/*/vertices.npy"))) == 2
    assert client.delete(f"/v1/scans/{scan['id']}").status_code == 204
    for bid in (body["id"], edited["id"]):
        assert client.get(f"/v1/bodies/{bid}").status_code == 404
    assert _db_rows(server, "bodies", [body["id"], edited["id"]]) == 0
    assert not list(blobs.glob(f"*/fits/{fit['id']}*"))
    assert client.get("/v1/bodies", params={"fit_id": fit["id"]}).json()["items"] == []


def test_fit_body_is_deleted_with_its_fit(client, server, sim):
    from core.io import read_markers

    names = load_template().landmarks
    markers = {
        k: list(map(float, v)) for k, v in read_markers(sim.markers, valid_names=names).items()
    }
    fit = client.post("/v1/fits", json={"mode": "markers_only", "markers": markers}).json()
    assert wait_state(client, fit["id"])["state"] == "succeeded"
    body = _create(client, fit_id=fit["id"], sex="male")
    assert client.delete(f"/v1/fits/{fit['id']}").status_code == 204
    assert client.get(f"/v1/bodies/{body['id']}").status_code == 404
    assert _db_rows(server, "bodies", [body["id"]]) == 0
    assert not list((server["data"] / "blobs").glob(f"*/fits/{fit['id']}*"))


def test_body_from_a_fit_that_did_not_succeed_is_409(client, sim):
    scan = upload_scan(client, sim).json()
    # markers 1 m away from the scan: the core's fit raises FitError
    far = {"Vertex": [5.0, 5.0, 5.0], "Menton": [5.0, 4.8, 5.0], "Crotch": [5.0, 4.2, 5.0]}
    fit = client.post("/v1/fits", json={"scan_id": scan["id"], "markers": far, "options": FAST})
    assert wait_state(client, fit.json()["id"])["state"] == "failed"
    r = client.post("/v1/bodies", json={"fit_id": fit.json()["id"], "sex": "female"})
    assert r.status_code == 409, r.text
    assert r.json()["error"]["code"] == "fit_not_ready"
    client.delete(f"/v1/scans/{scan['id']}")


# ----------------------------------------------------------------------------- database blobs


@pytest.fixture(scope="module")
def db_blob_server(tmp_path_factory):
    """A second server whose blobs live in the database (``BODYSPACE_BLOB_BACKEND=database``)."""
    data = tmp_path_factory.mktemp("dbblobs")
    env = service_env(
        {
            "BODYSPACE_DATA_DIR": str(data),
            "BODYSPACE_API_KEY": "k-db",
            "BODYSPACE_BLOB_BACKEND": "database",
        }
    )
    port = free_port()
    proc = start_server(env, port, data / "server.log")
    try:
        yield {"url": f"http://127.0.0.1:{port}", "data": data}
    finally:
        proc.stop()


def test_bodies_with_database_blobs(db_blob_server):
    import httpx

    with httpx.Client(
        base_url=db_blob_server["url"], headers={"X-API-Key": "k-db"}, timeout=60
    ) as c:
        src = _create(c, sex="female", height_m=1.60, weight_kg=55)
        V0 = _mesh(c, src["id"])
        syn = c.post(
            "/v1/models/default/synthesize",
            json={"sex": "female", "height_m": 1.60, "weight_kg": 55},
            headers=JSON,
        )
        np.testing.assert_array_equal(np.asarray(syn.json()["vertices"]), V0)
        r = c.post(f"/v1/bodies/{src['id']}/edit", json={"delta": {"weight_kg": -5}}, headers=JSON)
        assert r.status_code == 201, r.text
        assert abs(r.json()["features"]["weight_kg"] - src["features"]["weight_kg"] + 5) < 0.5
        db = db_blob_server["data"] / "bodyspace.db"
        like = f"%/bodies/{src['id']}/vertices.npy"
        with sqlite3.connect(db) as conn:
            assert (
                conn.execute("SELECT COUNT(*) FROM blob_data WHERE key LIKE ?", [like]).fetchone()[
                    0
                ]
                == 1
            )
        assert c.delete(f"/v1/bodies/{src['id']}").status_code == 204
        with sqlite3.connect(db) as conn:
            assert (
                conn.execute("SELECT COUNT(*) FROM blob_data WHERE key LIKE ?", [like]).fetchone()[
                    0
                ]
                == 0
            )
            assert (
                conn.execute("SELECT COUNT(*) FROM blobs WHERE key LIKE ?", [like]).fetchone()[0]
                == 0
            )
        assert c.get(f"/v1/bodies/{src['id']}").status_code == 404


def test_extrapolated_body_carries_its_warnings(client):
    """A stored body beyond the training range says so (metadata ``warnings``, the GLB's
    ``X-Bodyspace-Warnings``); one inside it does not, and an edit out of the range does."""
    import json

    b = _create(client, sex="male", height_m=1.85, weight_kg=141.0)
    (w,) = b["warnings"]
    assert w.startswith("weight_kg=141 kg is beyond the model's training range")
    r = client.get(f"/v1/bodies/{b['id']}")
    assert r.status_code == 200 and json.loads(r.headers["x-bodyspace-warnings"]) == [w]
    assert client.get(f"/v1/bodies/{b['id']}", headers=JSON).json()["warnings"] == [w]
    ok = _create(client, sex="male", height_m=1.80, weight_kg=80.0)
    assert ok["warnings"] == []
    r = client.post(f"/v1/bodies/{ok['id']}/edit", json={"target": {"weight_kg": 150}})
    assert r.status_code == 201, r.text
    (w2,) = json.loads(r.headers["x-bodyspace-warnings"])
    assert w2.startswith("weight_kg=150 kg is beyond")
