"""Backpressure and fairness in distributed mode: real Redis, PostgreSQL and Celery worker."""

from __future__ import annotations

import secrets
import subprocess
import sys

import httpx

from service.testing import free_port, start_server, upload_scan, wait_state

FAST = {"schedule": "fast"}


def _key(env: dict[str, str], tenant: str) -> str:
    out = subprocess.run(
        [sys.executable, "-m", "service.commands", "keys", "create", "--tenant", tenant],
        env=env, capture_output=True, text=True, check=True,
    )  # fmt: skip
    return out.stdout.split()[-1]


def test_tenant_limit_429_and_queue_limit_503(env, client, sim, tmp_path):
    # no worker consumes this queue: the fits stay queued, the counts are exact
    limits = dict(
        env,
        BODYSPACE_QUEUE_NAME=f"bodyspace-test-{secrets.token_hex(4)}",
        BODYSPACE_TENANT_MAX_ACTIVE_FITS="2",
        BODYSPACE_MAX_QUEUED_FITS="3",
    )
    a_key, b_key = (
        _key(limits, f"a-{secrets.token_hex(3)}"),
        _key(limits, f"b-{secrets.token_hex(3)}"),
    )
    port = free_port()
    api = start_server(limits, port, tmp_path / "api-limits.log")
    url = f"http://127.0.0.1:{port}"
    try:
        with (
            httpx.Client(base_url=url, headers={"X-API-Key": a_key}, timeout=60) as a,
            httpx.Client(base_url=url, headers={"X-API-Key": b_key}, timeout=60) as b,
        ):
            scan_a, scan_b = upload_scan(a, sim).json()["id"], upload_scan(b, sim).json()["id"]
            fit_a = {"scan_id": scan_a, "options": FAST}
            ids = [a.post("/v1/fits", json=fit_a) for _ in range(2)]
            assert [r.status_code for r in ids] == [202, 202], [r.text for r in ids]
            r = a.post("/v1/fits", json=fit_a)
            assert r.status_code == 429, r.text
            err = r.json()["error"]
            assert err["code"] == "too_many_active_fits" and "limit is 2" in err["message"]
            assert err["details"] == {"active": 2, "limit": 2}
            assert int(r.headers["Retry-After"]) > 0
            # another tenant is not limited by A's fits, only by the global queue
            assert b.post("/v1/fits", json={"scan_id": scan_b, "options": FAST}).status_code == 202
            r = b.post("/v1/fits", json={"scan_id": scan_b, "options": FAST})
            assert r.status_code == 503, r.text
            assert r.json()["error"]["code"] == "queue_full" and int(r.headers["Retry-After"]) > 0
            # a finished (here: deleted) fit frees the tenant's slot
            assert a.delete(f"/v1/fits/{ids[0].json()['id']}").status_code == 204
            assert a.post("/v1/fits", json=fit_a).status_code == 202
            for c in (a, b):  # leave nothing queued
                for f in c.get("/v1/fits").json()["items"]:
                    c.delete(f"/v1/fits/{f['id']}")
    finally:
        api.stop()


def test_other_tenants_fit_runs_before_a_burst_on_one_worker(env, client, api, workers, sim):
    """Six fits of tenant A, then one of tenant B, all waiting in Redis when the worker starts:
    B's fit (priority = its rank among its tenant's active fits: 0) runs after at most one of
    A's (A's ranks are 0..5)."""
    b_key = _key(env, f"b-{secrets.token_hex(3)}")
    with httpx.Client(base_url=api, headers={"X-API-Key": b_key}, timeout=60) as b:
        scan_a, scan_b = upload_scan(client, sim).json()["id"], upload_scan(b, sim).json()["id"]
        burst = [
            client.post("/v1/fits", json={"scan_id": scan_a, "options": FAST}).json()["id"]
            for _ in range(6)
        ]
        fit_b = b.post("/v1/fits", json={"scan_id": scan_b, "options": FAST}).json()["id"]
        w = workers("wfair")
        done = wait_state(b, fit_b, timeout=240)
        assert done["state"] == "succeeded", (done, w.output()[-3000:])
        b_start = done["timings"]["started_at"]
        ahead = [
            i for i in burst
            if (client.get(f"/v1/fits/{i}").json()["timings"]["started_at"] or b_start) < b_start
        ]  # fmt: skip
        assert len(ahead) <= 1, ahead
        for i in burst:  # the rest is not needed: deleted fits are skipped by the worker
            client.delete(f"/v1/fits/{i}")
