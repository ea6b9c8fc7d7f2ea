"""A coloured scan over HTTP against a real ``bodyspace serve``: the upload keeps its colours,
the fit's GLB carries them baked into a texture on the template UV layout (validator-clean; the
PNG also downloadable) and its PLY per-vertex colours, and a body made from the fit -- and its
pose -- carry them as ``COLOR_0`` (GLB and JSON). A textured scan uploaded as a ZIP bundle
(OBJ + MTL + PNG) or as a GLB is accepted and read with its colours; a texture bomb is a 422."""

from __future__ import annotations

import numpy as np

from core.io import read_mesh, write_markers_csv, write_ply
from core.io.images import decode_image, sample_image
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template
from core.transfer.texture import (
    bake_texture,
    load_uv_layout,
    textured_glb,
    write_textured_obj,
)
from service.testing import glb_parts, validate_glb, wait_state
from tests.core.test_io_textured import _png_header_only, _zip, with_document
from tests.core.test_transfer_colour import paint

JSON = {"Accept": "application/json"}


def _colour(data: bytes) -> np.ndarray:
    doc, accessor = glb_parts(data)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    return accessor(attrs["COLOR_0"])[:, :3]


def test_coloured_scan_fit_and_body(client, tmp_path, gltf_validator):
    tpl = load_template()
    rng = np.random.default_rng(21)
    body = random_body(rng, sex="female")
    C = paint(tpl.V)
    sim = simulate_scan(body.V, tpl.F, rng, config=ScanConfig.small(), colors=C)
    write_ply(tmp_path / "scan.ply", sim.V_scan, sim.F_scan, colors=sim.colors)
    write_markers_csv(tmp_path / "m.csv", sim.markers)
    files = {
        "scan": ("scan.ply", (tmp_path / "scan.ply").read_bytes(), "application/octet-stream"),
        "markers": ("m.csv", (tmp_path / "m.csv").read_bytes(), "text/csv"),
    }
    r = client.post("/v1/scans", files=files)
    assert r.status_code == 201, r.text
    r = client.post("/v1/fits", json={"scan_id": r.json()["id"], "options": {"schedule": "fast"}})
    assert r.status_code == 202, r.text
    fit_id = r.json()["id"]
    assert wait_state(client, fit_id)["state"] == "succeeded"

    assert client.get(f"/v1/fits/{fit_id}").json()["result_formats"][-1] == "png"
    r = client.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"})
    assert r.status_code == 200
    (tmp_path / "fit.glb").write_bytes(r.content)
    report = validate_glb(tmp_path / "fit.glb")
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(r.content)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    uv = accessor(attrs["TEXCOORD_0"])
    np.testing.assert_array_equal(uv, load_uv_layout().uv)
    png = client.get(f"/v1/fits/{fit_id}/result", params={"format": "png"})
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    baked = sample_image(decode_image(png.content), uv[: len(tpl.V)])
    assert np.abs(baked - C).mean() / 0.8 < 0.05
    r = client.get(f"/v1/fits/{fit_id}/result", params={"format": "ply"})
    (tmp_path / "fit.ply").write_bytes(r.content)
    rgb = read_mesh(tmp_path / "fit.ply").colors
    assert np.abs(rgb / 255.0 - baked).mean() < 0.005  # the texture is the PLY's colours baked

    r = client.post("/v1/bodies", json={"fit_id": fit_id, "sex": "female"})
    assert r.status_code == 201, r.text
    bid = r.json()["id"]
    r = client.get(f"/v1/bodies/{bid}")
    np.testing.assert_array_equal(_colour(r.content), rgb)
    assert client.get(f"/v1/bodies/{bid}", headers=JSON).json()["colors"] == rgb.tolist()
    r = client.get(f"/v1/bodies/{bid}", params={"rig": "true"})
    (tmp_path / "rig.glb").write_bytes(r.content)
    assert validate_glb(tmp_path / "rig.glb")["errors"] == 0
    np.testing.assert_array_equal(_colour(r.content), rgb)
    r = client.post(f"/v1/bodies/{bid}/pose", json={"posture": "seated"})
    assert r.status_code == 201, r.text
    np.testing.assert_array_equal(_colour(r.content), rgb)
    # an in-between body of two coloured bodies (the fit's body and an edit of it: one fit,
    # so one set of colours) carries their blend; the morph GLB the first body's colours
    r = client.post(f"/v1/bodies/{bid}/edit", json={"delta": {"weight_kg": 6}}, headers=JSON)
    assert r.status_code == 201, r.text
    edit = r.json()["id"]
    r = client.post("/v1/bodies", json={"morph": {"from": bid, "to": edit, "t": 0.4}})
    assert r.status_code == 201 and r.json()["params"]["colors"] == "blended", r.text
    mid = r.json()["id"]
    np.testing.assert_array_equal(_colour(client.get(f"/v1/bodies/{mid}").content), rgb)
    assert client.get(f"/v1/bodies/{mid}", headers=JSON).json()["colors"] == rgb.tolist()
    r = client.post("/v1/morphs", json={"bodies": [mid, bid, edit]})
    assert r.status_code == 200, r.text
    (tmp_path / "morph.glb").write_bytes(r.content)
    report = validate_glb(tmp_path / "morph.glb")
    assert report["errors"] == 0 and report["warnings"] == 0, report
    np.testing.assert_array_equal(_colour(r.content), rgb)
    # an uncoloured body has no colours, nor a blend with it, nor a morph GLB based on it
    other = client.post("/v1/bodies", json={"sex": "male", "seed": 1}).json()["id"]
    assert "colors" not in client.get(f"/v1/bodies/{other}", headers=JSON).json()
    r = client.post("/v1/bodies", json={"morph": {"from": bid, "to": other, "t": 0.5}})
    assert r.status_code == 201 and "colors" not in r.json()["params"], r.text
    assert "colors" not in client.get(f"/v1/bodies/{r.json()['id']}", headers=JSON).json()
    r = client.post("/v1/morphs", json={"bodies": [other, bid]})
    assert "COLOR_0" not in glb_parts(r.content)[0]["meshes"][0]["primitives"][0]["attributes"]
    # ... but wears the fit's texture on request: the same UV layout, the same image
    r = client.get(f"/v1/bodies/{other}", params={"texture_from": fit_id})
    assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary", r.text
    (tmp_path / "other.glb").write_bytes(r.content)
    report = validate_glb(tmp_path / "other.glb")
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(r.content)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    np.testing.assert_array_equal(accessor(attrs["TEXCOORD_0"]), uv)
    V_other = np.asarray(client.get(f"/v1/bodies/{other}", headers=JSON).json()["vertices"])
    np.testing.assert_allclose(accessor(attrs["POSITION"])[: len(tpl.V)], V_other, atol=1e-6)
    assert png.content in r.content  # the fit's PNG, embedded as it is
    r = client.get(f"/v1/bodies/{other}", params={"texture_from": "fit_nosuch"})
    assert r.status_code == 404, r.text
    r = client.get(f"/v1/bodies/{other}", params={"texture_from": fit_id, "rig": "true"})
    assert r.status_code == 200, r.text  # skinned and textured: seam copies share the skin
    (tmp_path / "other_rig.glb").write_bytes(r.content)
    report = validate_glb(tmp_path / "other_rig.glb")
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(r.content)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    joints, weights = accessor(attrs["JOINTS_0"]), accessor(attrs["WEIGHTS_0"])
    L = load_uv_layout()
    assert len(joints) == len(L.uv) and len(doc["skins"][0]["joints"]) == 163
    np.testing.assert_array_equal(joints, joints[L.vertex])
    np.testing.assert_array_equal(weights, weights[L.vertex])


def _upload(client, name: str, data: bytes):
    return client.post("/v1/scans", files={"scan": (name, data, "application/octet-stream")})


def test_textured_uploads(client, tmp_path):
    """A ZIP bundle (OBJ + MTL + PNG) is accepted as a scan and its fit's GLB and PNG carry the
    texture's colours; a GLB with an embedded texture is accepted; a bundle whose texture
    declares 2.5 G pixels, one missing its texture, and a GLB needing Draco are refused (422)."""
    tpl = load_template()
    C = paint(tpl.V)
    img = bake_texture(C, size=256)
    L = load_uv_layout()
    write_textured_obj(tmp_path / "body.obj", tpl.V, img)
    files = {n: (tmp_path / n).read_bytes() for n in ("body.obj", "body.mtl", "body.png")}
    markers = {k: tpl.V[i] for k, i in tpl.landmarks.items()}
    write_markers_csv(tmp_path / "m.csv", markers)
    r = client.post(
        "/v1/scans",
        files={
            "scan": ("body.zip", _zip(files), "application/zip"),
            "markers": ("m.csv", (tmp_path / "m.csv").read_bytes(), "text/csv"),
        },
    )
    assert r.status_code == 201, r.text
    assert r.json()["format"] == "zip" and r.json()["n_vertices"] == len(tpl.V)
    # fitted by the worker: the textured OBJ's colours come out baked in the fit's GLB
    r = client.post("/v1/fits", json={"scan_id": r.json()["id"], "options": {"schedule": "fast"}})
    assert r.status_code == 202, r.text
    fit_id = r.json()["id"]
    assert wait_state(client, fit_id)["state"] == "succeeded"
    g = client.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"}).content
    doc, _ = glb_parts(g)
    prim = doc["meshes"][0]["primitives"][0]
    assert prim["material"] == 0 and "TEXCOORD_0" in prim["attributes"]
    png = client.get(f"/v1/fits/{fit_id}/result", params={"format": "png"}).content
    rgb = sample_image(decode_image(png), L.uv[: len(tpl.V)])
    assert np.abs(rgb - C).mean() / 0.8 < 0.05, np.abs(rgb - C).mean() / 0.8
    notes = client.get(f"/v1/fits/{fit_id}/result", params={"format": "json"}).json()["notes"]
    assert any("at full resolution" in n for n in notes), notes  # texel by texel
    glb = textured_glb(None, tpl.V, img)
    r = _upload(client, "body.glb", glb)
    assert r.status_code == 201, r.text
    assert r.json()["format"] == "glb" and r.json()["n_vertices"] == len(L.uv)
    bomb = {**files, "body.png": _png_header_only(50_000, 50_000)}
    r = _upload(client, "bomb.zip", _zip(bomb))
    assert r.status_code == 422, r.text
    assert r.json()["error"]["code"] == "invalid_file" and "limit" in r.json()["error"]["message"]
    r = _upload(client, "partial.zip", _zip({"body.obj": files["body.obj"]}))
    assert r.status_code == 422 and "body.mtl" in r.json()["error"]["message"], r.text
    doc, _ = glb_parts(glb)
    doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    r = _upload(client, "draco.glb", with_document(glb, doc))
    assert r.status_code == 422 and "KHR_draco" in r.json()["error"]["message"], r.text
