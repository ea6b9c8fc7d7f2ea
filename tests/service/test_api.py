"""HTTP tests against a real ``bodyspace serve`` (embedded mode: SQLite + local process pool)."""

from __future__ import annotations

import numpy as np

from service.testing import glb_vertices, upload_scan, validate_glb, wait_state

FAST = {"schedule": "fast"}


def test_health_and_ready(client):
    assert client.get("/healthz").json()["status"] == "ok"
    r = client.get("/readyz")
    assert r.status_code == 200
    assert r.json()["checks"] == {"database": "ok", "jobs": "ok"}
    assert r.json()["mode"] == "embedded"


def test_end_to_end_fit_glb_validates_and_is_close_to_truth(client, sim, tmp_path, gltf_validator):
    r = upload_scan(client, sim)
    assert r.status_code == 201, r.text
    scan = r.json()
    assert r.headers["location"] == f"/v1/scans/{scan['id']}"
    assert scan["format"] == "ply" and scan["n_vertices"] == sim.n_vertices
    assert "Vertex" in scan["marker_names"]

    r = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST})
    assert r.status_code == 202, r.text
    fit = r.json()
    assert r.headers["location"] == f"/v1/fits/{fit['id']}"
    assert fit["state"] in ("queued", "running")

    seen_progress = False
    done = None
    for _ in range(1200):
        body = client.get(f"/v1/fits/{fit['id']}").json()
        if body["state"] == "running" and (body["progress"] or {}).get("stage") is not None:
            seen_progress = True
            assert 0 <= body["progress"]["percent"] <= 100
            assert "total" in body["progress"]["energy"]
        if body["state"] in ("succeeded", "failed"):
            done = body
            break
        import time

        time.sleep(0.1)
    assert done is not None and done["state"] == "succeeded", done
    assert seen_progress
    t = done["timings"]
    assert t["queued_s"] >= 0 and t["run_s"] > 0 and t["fit_s"] > 0
    assert done["result_formats"] == ["glb", "ply", "obj", "json"]

    r = client.get(f"/v1/fits/{fit['id']}/result", params={"format": "glb"})
    assert r.status_code == 200
    assert r.headers["content-type"] == "model/gltf-binary"
    glb = tmp_path / "fit.glb"
    glb.write_bytes(r.content)
    report = validate_glb(glb)
    assert report["errors"] == 0, report

    V = glb_vertices(r.content).astype(np.float64)
    assert V.shape == (13380, 3)
    err = np.linalg.norm(V - sim.truth, axis=1)
    assert err.mean() < 0.01, f"mean vertex error {err.mean() * 1000:.1f} mm"
    assert np.percentile(err, 95) < 0.03

    for fmt, ctype in [("ply", "application/octet-stream"), ("obj", "text/plain")]:
        r = client.get(f"/v1/fits/{fit['id']}/result", params={"format": fmt})
        assert r.status_code == 200 and r.headers["content-type"].startswith(ctype)
    rep = client.get(f"/v1/fits/{fit['id']}/result", params={"format": "json"}).json()
    assert rep["scan_to_fit_mean_m"] < 0.01 and rep["markers_used"]
    # the quality verdict: in the status and in the result JSON, every part measured
    q = done["quality"]
    assert q == rep["quality"]
    assert q["quality"] == "good", q["reasons"]
    assert set(q["parts"]) == {
        "head", "torso", "arm_L", "arm_R", "hand_L", "hand_R", "leg_L", "leg_R", "foot_L", "foot_R"
    }  # fmt: skip
    assert q["parts"]["head"]["scan_points"] > 0
    # the warnings and the points removed as not the body: in the status as in the result JSON
    assert done["warnings"] == rep["warnings"]
    assert done["removed"] == rep["removed"]
    assert not any(rep["removed"].values())  # a simulated scan has no floor or blobs


def test_fit_that_raises_fails_with_message_and_pool_keeps_serving(client, sim):
    scan = upload_scan(client, sim).json()
    # markers 1 m away from the scan: the core's fit raises FitError
    far = {"Vertex": [5.0, 5.0, 5.0], "Menton": [5.0, 4.8, 5.0], "Crotch": [5.0, 4.2, 5.0]}
    bad = client.post("/v1/fits", json={"scan_id": scan["id"], "markers": far, "options": FAST})
    assert bad.status_code == 202, bad.text
    good = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST})
    failed = wait_state(client, bad.json()["id"])
    assert failed["state"] == "failed"
    assert failed["error"]["code"] == "fit_failed"
    assert "markers" in failed["error"]["message"]
    r = client.get(f"/v1/fits/{bad.json()['id']}/result")
    assert r.status_code == 409 and r.json()["error"]["code"] == "fit_not_ready"
    assert wait_state(client, good.json()["id"])["state"] == "succeeded"


def test_listing_is_paginated_and_scoped(client, client_b, sim):
    ids = {upload_scan(client, sim).json()["id"] for _ in range(3)}
    seen: list[str] = []
    cursor = None
    while True:
        params = {"limit": 2} | ({"cursor": cursor} if cursor else {})
        page = client.get("/v1/scans", params=params).json()
        assert len(page["items"]) <= 2
        seen += [s["id"] for s in page["items"]]
        cursor = page["next_cursor"]
        if not cursor:
            break
    assert ids <= set(seen) and len(seen) == len(set(seen))
    assert client_b.get("/v1/scans").json()["items"] == []
    fits = client.get("/v1/fits", params={"limit": 1, "state": "succeeded"}).json()
    assert all(f["state"] == "succeeded" for f in fits["items"])


def test_delete_scan_removes_fits_and_blobs(client, server, sim):
    scan = upload_scan(client, sim).json()
    fit = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()
    assert wait_state(client, fit["id"])["state"] == "succeeded"
    blobs = server["data"] / "blobs"
    assert list(blobs.glob(f"*/scans/{scan['id']}/*")) and list(blobs.glob(f"*/fits/{fit['id']}/*"))

    assert client.delete(f"/v1/scans/{scan['id']}").status_code == 204
    assert client.get(f"/v1/scans/{scan['id']}").status_code == 404
    assert client.get(f"/v1/fits/{fit['id']}").status_code == 404
    assert client.get(f"/v1/fits/{fit['id']}/result").status_code == 404
    assert not list(blobs.glob(f"*/scans/{scan['id']}*"))
    assert not list(blobs.glob(f"*/fits/{fit['id']}*"))
    assert client.delete(f"/v1/scans/{scan['id']}").status_code == 404


def test_delete_scan_while_its_fit_runs_leaves_no_result_behind(client, server, sim):
    scan = upload_scan(client, sim).json()
    fit = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()
    assert wait_state(client, fit["id"], ("running", "succeeded", "failed"))["state"] == "running"
    assert client.delete(f"/v1/scans/{scan['id']}").status_code == 204
    # the pool has one process: once a later job is done, the deleted one has ended too
    other = upload_scan(client, sim).json()
    later = client.post("/v1/fits", json={"scan_id": other["id"], "options": FAST}).json()
    assert wait_state(client, later["id"])["state"] == "succeeded"
    blobs = server["data"] / "blobs"
    assert list(blobs.glob(f"*/fits/{later['id']}/*"))
    assert not list(blobs.glob(f"*/fits/{fit['id']}*")), list(blobs.glob(f"*/fits/{fit['id']}/*"))
    assert not list(blobs.glob(f"*/scans/{scan['id']}*"))
