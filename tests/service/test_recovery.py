"""Embedded mode: a job interrupted by a crash of the whole server completes after a restart."""

from __future__ import annotations

import httpx

from service.testing import free_port, service_env, sim_files, start_server, upload_scan, wait_state


def test_killed_server_resumes_running_and_queued_jobs(tmp_path):
    sim = sim_files(tmp_path / "sim", seed=2)
    env = service_env({"BODYSPACE_DATA_DIR": str(tmp_path / "data")})
    port = free_port()
    srv = start_server(env, port, tmp_path / "server1.log")
    # no key configured: the first embedded start creates one and prints it
    out = srv.output()
    key = next(line.split()[-1] for line in out.splitlines() if "local API key" in line)
    headers = {"Authorization": f"Bearer {key}"}
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=headers, timeout=60) as c:
            scan = upload_scan(c, sim).json()
            ids = [
                c.post(
                    "/v1/fits", json={"scan_id": scan["id"], "options": {"schedule": "fast"}}
                ).json()["id"]
                for _ in range(2)
            ]
            assert wait_state(c, ids[0], ("running",), timeout=60)["state"] == "running"
    finally:
        srv.kill9()  # server and its pool processes, mid-fit
        srv.stop()
    srv = start_server(env, port, tmp_path / "server2.log")
    try:
        assert "local API key" not in srv.output()  # created once only
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=headers, timeout=60) as c:
            for fit_id in ids:
                done = wait_state(c, fit_id, timeout=180)
                assert done["state"] == "succeeded", (done, srv.output()[-3000:])
    finally:
        srv.stop()
