"""Distributed mode end to end and under faults: real Redis, PostgreSQL and Celery workers."""

from __future__ import annotations

import time

import numpy as np

from service.testing import glb_vertices, upload_scan, validate_glb, wait_state

FAST = {"schedule": "fast"}


def _waiting(redis_client, queue: str) -> int:
    """Messages waiting in ``queue`` (a Redis list per priority, service.celery_app)."""
    from service.celery_app import MAX_PRIORITY

    names = [queue] + [f"{queue}\x06\x16{p}" for p in range(1, MAX_PRIORITY + 1)]
    return sum(redis_client.llen(n) for n in names)


def _logs(*procs) -> str:
    return "\n".join(f"--- {p.log.name}\n{p.output()[-4000:]}" for p in procs)


def _ready(client, status: str, timeout: float = 30.0) -> dict:
    """Poll ``/readyz`` (200) until it says ``status``."""
    t_end = time.monotonic() + timeout
    while True:
        r = client.get("/readyz")
        assert r.status_code == 200, r.text
        if r.json()["status"] == status or time.monotonic() > t_end:
            return r.json()
        time.sleep(0.2)


def test_ready_says_degraded_without_a_worker_and_ok_with_one(client, workers):
    # no worker consumes the queue (a killed worker's beat expires after WORKER_BEAT_TTL_S)
    body = _ready(client, "degraded")
    assert body["status"] == "degraded" and body["mode"] == "distributed", body
    assert body["checks"]["database"] == "ok" and body["checks"]["jobs"] == "ok"
    assert "no worker consumes the queue" in body["checks"]["workers"], body
    w = workers("wr")
    body = _ready(client, "ok", timeout=60)
    assert body["checks"] == {"database": "ok", "jobs": "ok", "workers": "ok"}, (body, _logs(w))
    w.stop()  # a stopped worker deletes its beat: degraded again at once (+ the answer cache)
    t0 = time.monotonic()
    assert _ready(client, "degraded", timeout=10)["status"] == "degraded"
    assert time.monotonic() - t0 < 5


def test_end_to_end_on_a_celery_worker(client, workers, sim, tmp_path):
    w = workers("w1")
    scan = upload_scan(client, sim).json()
    r = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST})
    assert r.status_code == 202, r.text
    done = wait_state(client, r.json()["id"], timeout=180)
    assert done["state"] == "succeeded", (done, _logs(w))
    glb = client.get(f"/v1/fits/{done['id']}/result", params={"format": "glb"})
    assert glb.status_code == 200
    path = tmp_path / "fit.glb"
    path.write_bytes(glb.content)
    assert validate_glb(path)["errors"] == 0
    err = np.linalg.norm(glb_vertices(glb.content) - sim.truth, axis=1)
    assert err.mean() < 0.01, f"mean vertex error {err.mean() * 1000:.1f} mm"


def test_failing_fit_is_failed_and_worker_keeps_serving(client, workers, sim):
    w = workers("w1")
    scan = upload_scan(client, sim).json()
    far = {"Vertex": [5.0, 5.0, 5.0], "Menton": [5.0, 4.8, 5.0], "Crotch": [5.0, 4.2, 5.0]}
    bad = client.post("/v1/fits", json={"scan_id": scan["id"], "markers": far, "options": FAST})
    good = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST})
    failed = wait_state(client, bad.json()["id"], timeout=180)
    assert failed["state"] == "failed", _logs(w)
    assert failed["error"]["code"] == "fit_failed" and "markers" in failed["error"]["message"]
    assert failed["attempts"] == 1  # bad input is not retried
    assert wait_state(client, good.json()["id"], timeout=180)["state"] == "succeeded", _logs(w)
    assert w.alive()


def test_kill9_worker_mid_fit_then_a_new_worker_completes_it(client, workers, sim):
    w1 = workers("w1")
    scan = upload_scan(client, sim).json()
    fit_id = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()["id"]
    running = wait_state(client, fit_id, ("running", "succeeded", "failed"), timeout=120)
    assert running["state"] == "running", running
    w1.kill9()
    assert client.get(f"/v1/fits/{fit_id}").json()["state"] == "running"
    w2 = workers("w2")
    done = wait_state(client, fit_id, timeout=180)
    assert done["state"] == "succeeded", (done, _logs(w1, w2))
    assert done["attempts"] == 2


def test_flushed_broker_jobs_are_recovered_from_the_database(
    client, workers, sim, redis_client, queue
):
    scan = upload_scan(client, sim).json()
    ids = [
        client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()["id"]
        for _ in range(2)
    ]
    assert _waiting(redis_client, queue) == 2  # no worker runs: both wait in Redis
    redis_client.flushdb()
    assert _waiting(redis_client, queue) == 0
    w = workers("w3")  # on start it re-enqueues what the database says is queued
    for fit_id in ids:
        done = wait_state(client, fit_id, timeout=240)
        assert done["state"] == "succeeded", (done, _logs(w))


def test_broker_down_not_ready_and_fit_refused_with_503(env, client, sim, tmp_path):
    from service.testing import free_port, start_server

    down = dict(env, BODYSPACE_BROKER_URL="redis://127.0.0.1:1/0")  # nothing listens there
    port = free_port()
    api = start_server(down, port, tmp_path / "api-down.log")
    try:
        import httpx

        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=client.headers) as c:
            ready = c.get("/readyz")
            assert ready.status_code == 503 and ready.json()["error"]["code"] == "not_ready"
            assert "ConnectionError" in ready.json()["error"]["details"]["jobs"]
            scan = upload_scan(c, sim).json()
            before = {f["id"] for f in c.get("/v1/fits", params={"limit": 200}).json()["items"]}
            r = c.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST})
            assert r.status_code == 503, r.text  # not 202 for a job nothing will run
            assert r.json()["error"]["code"] == "queue_unavailable"
            assert int(r.headers["Retry-After"]) > 0
            after = {f["id"] for f in c.get("/v1/fits", params={"limit": 200}).json()["items"]}
            assert after == before  # nothing stored that a later recovery would run
    finally:
        api.stop()


def test_time_limit_fails_the_job(env, client, sim, tmp_path):
    from service.testing import start_worker

    w = start_worker(dict(env, BODYSPACE_JOB_TIME_LIMIT_S="1"), tmp_path / "w5.log", "w5")
    try:
        scan = upload_scan(client, sim).json()
        r = client.post("/v1/fits", json={"scan_id": scan["id"], "options": {"schedule": "paper"}})
        done = wait_state(client, r.json()["id"], timeout=180)
        assert done["state"] == "failed", (done, _logs(w))
        assert done["error"]["code"] == "time_limit_exceeded"
    finally:
        w.stop()


def _children(pid: int) -> list[int]:
    from pathlib import Path

    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


def test_kill9_pool_process_mid_fit_message_is_redelivered(client, workers, sim):
    import os
    import signal

    # no stale-heartbeat recovery here: only the broker's redelivery can bring the job back
    w = workers("w6", BODYSPACE_STALE_AFTER_S="600")
    scan = upload_scan(client, sim).json()
    fit_id = client.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()["id"]
    running = wait_state(client, fit_id, ("running", "succeeded", "failed"), timeout=120)
    assert running["state"] == "running", running
    (child,) = _children(w.pid)  # concurrency 1: the one pool process runs the fit
    os.kill(child, signal.SIGKILL)
    # task_reject_on_worker_lost: the worker puts the message back, a new pool process reruns it
    done = wait_state(client, fit_id, timeout=180)
    assert done["state"] == "succeeded", (done, _logs(w))
    assert done["attempts"] == 2 and w.alive()


def test_database_blob_backend_needs_no_shared_folder(env, workers, sim, tmp_path, redis_client):
    """API and worker with different data folders: scans and results travel through PostgreSQL."""
    import httpx
    import psycopg

    from service.testing import free_port, start_server

    db = dict(
        env,
        BODYSPACE_BLOB_BACKEND="database",
        BODYSPACE_QUEUE_NAME=env["BODYSPACE_QUEUE_NAME"] + "-db",
    )
    port = free_port()
    api = start_server(dict(db, BODYSPACE_DATA_DIR=str(tmp_path / "api")), port, tmp_path / "a.log")
    try:
        w = workers("w7", BODYSPACE_BLOB_BACKEND="database", BODYSPACE_DATA_DIR=str(tmp_path / "w"),
                    BODYSPACE_QUEUE_NAME=db["BODYSPACE_QUEUE_NAME"])  # fmt: skip
        headers = {"X-API-Key": env["BODYSPACE_API_KEY"]}
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=headers, timeout=60) as c:
            scan = upload_scan(c, sim).json()
            fit_id = c.post("/v1/fits", json={"scan_id": scan["id"], "options": FAST}).json()["id"]
            done = wait_state(c, fit_id, timeout=180)
            assert done["state"] == "succeeded", (done, _logs(w))
            glb = c.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"})
            assert glb.status_code == 200
            assert int(glb.headers["content-length"]) == len(glb.content)
            path = tmp_path / "fit.glb"
            path.write_bytes(glb.content)
            assert validate_glb(path)["errors"] == 0
            err = np.linalg.norm(glb_vertices(glb.content) - sim.truth, axis=1)
            assert err.mean() < 0.01
            assert not list((tmp_path / "api").rglob("*.glb"))  # nothing on the API's disk
            assert c.delete(f"/v1/scans/{scan['id']}").status_code == 204
        with psycopg.connect(env["BODYSPACE_DATABASE_URL"]) as conn:
            left = conn.execute(
                "SELECT count(*) FROM blob_data WHERE key LIKE %s OR key LIKE %s",
                (f"%/{scan['id']}/%", f"%/{fit_id}/%"),
            ).fetchone()[0]
        assert left == 0
    finally:
        api.stop()
