"""Personal data: private headers on /v1, deleted scans leave nothing readable in the SQLite
files, the first key is printed once and never logged, query-string keys are redacted from the
access log, keys can be listed and revoked (refused within the documented cache window)."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid

import httpx

from service.testing import Proc, free_port, service_env, wait_ready

SYN = "/v1/models/default/synthesize"


def _private(r: httpx.Response) -> bool:
    return (
        r.headers.get("cache-control") == "no-store"
        and r.headers.get("x-content-type-options") == "nosniff"
    )


def test_every_v1_response_is_private(client, sim):
    answers = [
        client.get("/v1/scans"),
        client.get("/v1/fits/fit_nope"),  # an error
        client.post(SYN, json={"sex": "female", "height_m": 1.65}),  # the synthesis short path
        client.post(SYN, json={"sex": "female", "height_m": 1.65}, params={"format": "json"}),
        httpx.get(str(client.base_url) + "/v1/scans"),  # no key: 401
    ]
    for r in answers:
        assert _private(r), (r.status_code, r.request.url, dict(r.headers))


def _db_files(data) -> bytes:
    return b"".join(p.read_bytes() for p in data.glob("bodyspace.db*") if p.is_file())


def test_deleted_scan_leaves_nothing_readable_in_the_database_files(client, server, sim):
    marker = f"person-{uuid.uuid4().hex}"  # stored as the scan's filename
    files = {
        "scan": (f"{marker}.ply", sim.scan.read_bytes(), "application/octet-stream"),
        "markers": ("markers.csv", sim.markers.read_bytes(), "text/csv"),
    }
    scan = client.post("/v1/scans", files=files)
    assert scan.status_code == 201, scan.text
    assert marker.encode() in _db_files(server["data"])  # the search finds it while it exists
    assert client.delete(f"/v1/scans/{scan.json()['id']}").status_code == 204
    assert marker.encode() not in _db_files(server["data"])


def test_keys_printed_once_never_logged_redacted_listed_and_revoked(tmp_path):
    data = tmp_path / "data"
    env = service_env({"BODYSPACE_DATA_DIR": str(data), "BODYSPACE_API_KEY_CACHE_TTL_S": "1"})
    port = free_port()
    args = [sys.executable, "-m", "service.commands", "serve", "--port", str(port)]
    proc = Proc([*args, "--log-level", "info"], env, tmp_path / "api.log")
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(proc, url, path="/readyz")
        out = proc.output()
        first = [ln.split()[-1] for ln in out.splitlines() if "bodyspace: created" in ln]
        assert len(first) == 1, out
        assert out.count(first[0]) == 1, out  # printed once, in no log line
        secret = f"bsk_{uuid.uuid4().hex}"
        r = httpx.get(f"{url}/v1/scans", params={"api_key": secret, "other": "1"})
        assert r.status_code == 401
        cli = [sys.executable, "-m", "service.commands", "keys"]
        made = subprocess.run(
            [*cli, "create", "--tenant", "clinic"], env=env, capture_output=True, text=True,
            check=True,
        )  # fmt: skip
        key = made.stdout.split()[-1]
        headers = {"Authorization": f"Bearer {key}"}
        assert httpx.get(f"{url}/v1/scans", headers=headers).status_code == 200  # cached now
        listed = subprocess.run([*cli, "list"], env=env, capture_output=True, text=True).stdout
        assert "clinic" in listed and key[:12] in listed and key not in listed, listed
        revoke = subprocess.run(
            [*cli, "revoke", key[:12]], env=env, capture_output=True, text=True, check=True
        )
        t0 = time.monotonic()
        assert "revoked" in revoke.stdout, revoke.stdout
        while httpx.get(f"{url}/v1/scans", headers=headers).status_code == 200:
            assert time.monotonic() - t0 < 1.0 + 1.0, "revoked key still accepted after TTL + 1 s"
            time.sleep(0.05)
        assert httpx.get(f"{url}/v1/scans", headers=headers).status_code == 401
        print(f"revoked key refused {time.monotonic() - t0:.2f} s after revoke (cache TTL 1 s)")
        listed = subprocess.run([*cli, "list"], env=env, capture_output=True, text=True).stdout
        row = next(ln for ln in listed.splitlines() if "clinic" in ln)
        assert not row.rstrip().endswith("-"), row  # a revocation time
    finally:
        proc.stop()
    log = proc.output()
    assert secret not in log and "api_key=REDACTED" in log and "other=1" in log, log[-2000:]
