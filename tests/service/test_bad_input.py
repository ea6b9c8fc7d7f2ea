"""Bad input answers at once with the precise status and error code (one error shape)."""

from __future__ import annotations

import httpx
import pytest

from service.testing import upload_scan

MAX_UPLOAD = 3_000_000  # conftest's BODYSPACE_MAX_UPLOAD_BYTES


def _ascii_ply(rows: list[str], faces: int = 0) -> bytes:
    head = f"ply\nformat ascii 1.0\nelement vertex {len(rows)}\nproperty float x\n"
    head += "property float y\nproperty float z\n"
    head += f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    return (head + "\n".join(rows) + "\n").encode()


def _post_scan(client: httpx.Client, scan: bytes | None, markers: bytes | None, name="s.ply"):
    files = {}
    if scan is not None:
        files["scan"] = (name, scan, "application/octet-stream")
    if markers is not None:
        files["markers"] = ("m.csv", markers, "text/csv")
    return client.post("/v1/scans", files=files or None, data={"units": "auto"})


def _check(r: httpx.Response, status: int, code: str) -> dict:
    assert r.status_code == status, r.text
    body = r.json()
    assert set(body) == {"error"} and set(body["error"]) == {"code", "message", "details"}
    assert body["error"]["code"] == code, body
    assert body["error"]["message"]
    return body["error"]


def test_wrong_content_type_for_upload(client):
    _check(client.post("/v1/scans", json={"scan": "x"}), 415, "unsupported_media_type")


def test_wrong_content_type_for_fit(client):
    r = client.post("/v1/fits", data={"scan_id": "x"})
    _check(r, 415, "unsupported_media_type")


def test_oversized_upload(client, sim):
    big = sim.scan.read_bytes() * (MAX_UPLOAD // sim.scan.stat().st_size + 1)
    err = _check(_post_scan(client, big, None), 413, "upload_too_large")
    assert err["details"]["limit_bytes"] == MAX_UPLOAD


def test_oversized_marker_file(client, sim):
    big = b"name,x,y,z\n" + b"Vertex,0,1.7,0\n" * 100_000
    _check(_post_scan(client, sim.scan.read_bytes(), big), 413, "upload_too_large")


def test_too_many_vertices(client):
    n = 100_001  # conftest's BODYSPACE_MAX_VERTICES is 100000
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
    head += "property float x\nproperty float y\nproperty float z\nend_header\n"
    err = _check(_post_scan(client, head.encode() + bytes(12 * n), None), 422, "invalid_file")
    assert "100,000" in err["message"] or "100000" in err["message"], err


def test_truncated_binary_ply(client, sim):
    data = sim.scan.read_bytes()
    err = _check(_post_scan(client, data[: len(data) // 2], None), 422, "invalid_file")
    assert "truncated" in err["message"]


@pytest.mark.parametrize(
    "data",
    [b"\x00\x01garbage\xff" * 200, b"ply\nformat nonsense\nend_header\n", b""],
    ids=["garbage", "bad-header", "empty"],
)
def test_garbage_scan(client, data):
    _check(_post_scan(client, data, None), 422, "invalid_file")


def test_nan_vertices(client):
    rows = [f"{i * 0.01} {1.0 + i * 0.001} 0.1" for i in range(200)] + ["nan 1.0 0.2"]
    err = _check(_post_scan(client, _ascii_ply(rows), None), 422, "invalid_file")
    assert "non-finite" in err["message"].lower() or "nan" in err["message"].lower()


def test_unknown_markers(client, sim):
    markers = sim.markers.read_bytes() + b"Belly_button,0.0,1.0,0.1\n"
    err = _check(_post_scan(client, sim.scan.read_bytes(), markers), 422, "invalid_markers")
    assert "Belly_button" in err["message"]
    assert "Vertex" in err["details"]["valid"]


def test_unknown_inline_markers_on_fit(client, sim):
    scan = upload_scan(client, sim).json()
    r = client.post("/v1/fits", json={"scan_id": scan["id"], "markers": {"Nose": [0, 1.6, 0.1]}})
    _check(r, 422, "invalid_markers")


def test_missing_scan_part(client, sim):
    err = _check(_post_scan(client, None, sim.markers.read_bytes()), 422, "missing_field")
    assert err["details"]["field"] == "scan"


def test_missing_scan_id(client):
    err = _check(client.post("/v1/fits", json={"options": {}}), 422, "missing_field")
    assert "scan_id" in err["message"]


def test_unknown_fit_option(client, sim):
    scan = upload_scan(client, sim).json()
    r = client.post("/v1/fits", json={"scan_id": scan["id"], "options": {"turbo": True}})
    _check(r, 422, "validation_error")


def test_fit_without_markers(client, sim):
    r = client.post(
        "/v1/scans", files={"scan": ("scan.ply", sim.scan.read_bytes(), "application/x-ply")}
    )
    assert r.status_code == 201, r.text
    _check(client.post("/v1/fits", json={"scan_id": r.json()["id"]}), 422, "markers_required")


def test_bad_units_field(client, sim):
    _check(_post_scan_units(client, sim, "furlongs"), 422, "validation_error")


def _post_scan_units(client, sim, units):
    files = {"scan": ("scan.ply", sim.scan.read_bytes(), "application/octet-stream")}
    return client.post("/v1/scans", files=files, data={"units": units})


def test_other_tenants_ids_answer_404(client, client_b, sim):
    scan = upload_scan(client, sim).json()
    fit = client.post("/v1/fits", json={"scan_id": scan["id"], "options": {"schedule": "fast"}})
    fit_id = fit.json()["id"]
    _check(client_b.get(f"/v1/scans/{scan['id']}"), 404, "not_found")
    _check(client_b.delete(f"/v1/scans/{scan['id']}"), 404, "not_found")
    _check(client_b.post("/v1/fits", json={"scan_id": scan["id"]}), 404, "not_found")
    _check(client_b.get(f"/v1/fits/{fit_id}"), 404, "not_found")
    _check(client_b.get(f"/v1/fits/{fit_id}/result"), 404, "not_found")
    assert client_b.get("/v1/fits").json()["items"] == []
    _check(client.get("/v1/fits/fit_doesnotexist"), 404, "not_found")
    assert client.get(f"/v1/scans/{scan['id']}").status_code == 200


def test_no_key(server):
    r = httpx.get(f"{server['url']}/v1/scans")
    _check(r, 401, "missing_api_key")


@pytest.mark.parametrize(
    "headers",
    [{"Authorization": "Bearer nope"}, {"X-API-Key": "nope"}, {"Authorization": "Basic eDp5"}],
    ids=["bearer", "x-api-key", "basic"],
)
def test_invalid_key(server, headers):
    r = httpx.get(f"{server['url']}/v1/scans", headers=headers)
    code = "missing_api_key" if headers.get("Authorization", "").startswith("Basic") else None
    _check(r, 401, code or "invalid_api_key")


def test_unknown_route_and_bad_query(client):
    _check(client.get("/v1/nothing"), 404, "not_found")
    _check(client.get("/v1/scans", params={"limit": 0}), 422, "validation_error")
    _check(client.get("/v1/scans", params={"cursor": "%%%"}), 422, "validation_error")
    _check(client.get("/v1/fits/x/result", params={"format": "fbx"}), 422, "validation_error")
