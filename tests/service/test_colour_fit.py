"""A coloured scan over HTTP against a real ``bodyspace serve``: the upload keeps its colours,
the fit's GLB has ``COLOR_0`` (validator-clean) and its PLY colours, and a body made from the fit
-- and its pose -- carry them (GLB and JSON)."""

from __future__ import annotations

import numpy as np

from core.io import read_mesh, write_markers_csv, write_ply
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template
from service.testing import glb_parts, validate_glb, wait_state
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

    r = client.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"})
    assert r.status_code == 200
    (tmp_path / "fit.glb").write_bytes(r.content)
    report = validate_glb(tmp_path / "fit.glb")
    assert report["errors"] == 0 and report["warnings"] == 0, report
    rgb = _colour(r.content)
    assert np.abs(rgb / 255.0 - C).mean() / 0.8 < 0.05
    r = client.get(f"/v1/fits/{fit_id}/result", params={"format": "ply"})
    (tmp_path / "fit.ply").write_bytes(r.content)
    np.testing.assert_array_equal(read_mesh(tmp_path / "fit.ply").colors, rgb)

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
    # an uncoloured body has no colours
    other = client.post("/v1/bodies", json={"sex": "male", "seed": 1}).json()["id"]
    assert "colors" not in client.get(f"/v1/bodies/{other}", headers=JSON).json()
