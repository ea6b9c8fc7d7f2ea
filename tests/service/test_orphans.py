"""An embedded server killed with SIGKILL mid-fit leaves no process behind (issue 15), and the
restarted server re-runs the job once: one result, no duplicate writes."""

from __future__ import annotations

import os
import signal
import sqlite3
import time
from pathlib import Path

import httpx

from service.testing import free_port, service_env, sim_files, start_server, upload_scan, wait_state

KEY = "test-key-orphans"


def _group(pgid: int) -> dict[int, str]:
    """Live (not zombie) processes of process group ``pgid``: pid -> command line."""
    out: dict[int, str] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            out[int(d.name)] = cmd
    return out


def _wait_running(c: httpx.Client, fit_id: str) -> None:
    t_end = time.monotonic() + 120
    while True:  # mid-fit: the pool process is iterating
        body = c.get(f"/v1/fits/{fit_id}").json()
        if body["state"] == "running" and body["progress"].get("phase") == "fitting":
            return
        assert body["state"] in ("queued", "running"), body
        assert time.monotonic() < t_end, body
        time.sleep(0.05)


def _gone_within(pgid: int, seconds: float) -> float:
    """Seconds until process group ``pgid`` has no live process; fails after ``seconds``."""
    t0 = time.monotonic()
    while (left := _group(pgid)) and time.monotonic() - t0 < seconds:
        time.sleep(0.05)
    assert not left, f"left behind after {seconds} s: {left}"
    return time.monotonic() - t0


def test_sigkill_mid_fit_leaves_no_process_and_the_job_reruns_once(tmp_path):
    sim = sim_files(tmp_path / "sim", seed=7)
    data = tmp_path / "data"
    env = service_env({"BODYSPACE_DATA_DIR": str(data), "BODYSPACE_API_KEY": KEY})
    headers = {"Authorization": f"Bearer {KEY}"}
    port = free_port()
    server = start_server(env, port, tmp_path / "first.log")
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=headers, timeout=60) as c:
            scan = upload_scan(c, sim).json()
            fit_id = c.post(
                "/v1/fits", json={"scan_id": scan["id"], "options": {"schedule": "fast"}}
            ).json()["id"]
            _wait_running(c, fit_id)
        group = _group(server.pid)
        assert len(group) >= 2, group  # the server and its pool process
        os.kill(server.pid, signal.SIGKILL)  # the server only, as a supervisor or the OOM killer
        server.p.wait(timeout=10)
        print(f"process group gone {_gone_within(server.pid, 5):.2f} s after the SIGKILL")
    finally:
        server.stop()  # kills what is left of the group, if anything
    port = free_port()
    server = start_server(env, port, tmp_path / "second.log")
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=headers, timeout=60) as c:
            done = wait_state(c, fit_id, timeout=180)
            assert done["state"] == "succeeded", (done, server.output()[-3000:])
            assert done["attempts"] == 2  # re-run once by the new server
            assert c.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"}).status_code == 200
    finally:
        server.stop()
    with sqlite3.connect(data / "bodyspace.db") as db:
        kinds = [k for (k,) in db.execute("SELECT kind FROM blobs WHERE fit_id = ?", (fit_id,))]
    assert sorted(kinds) == ["result.glb", "result.json", "result.obj", "result.ply"], kinds
    files = [p for p in (data / "blobs").rglob("*") if p.is_file() and fit_id in str(p)]
    assert len(files) == 4, files  # one result, nothing half-written by the killed run


def test_sigkill_of_serve_workers_supervisor_stops_its_api_and_pool_processes(tmp_path):
    """``serve --workers 2``: the API processes stop (SIGTERM, graceful) when the supervising
    process is killed, and take their pool processes with them."""
    import sys

    from service.testing import Proc, wait_ready

    sim = sim_files(tmp_path / "sim", seed=8)
    env = service_env({"BODYSPACE_DATA_DIR": str(tmp_path / "data"), "BODYSPACE_API_KEY": KEY})
    port = free_port()
    args = [sys.executable, "-m", "service.commands", "serve", "--port", str(port)]
    proc = Proc([*args, "--workers", "2", "--log-level", "warning"], env, tmp_path / "api.log")
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(proc, url, path="/readyz", timeout=90, poll=0.2)
        headers = {"Authorization": f"Bearer {KEY}"}
        with httpx.Client(base_url=url, headers=headers, timeout=60) as c:
            scan = upload_scan(c, sim).json()
            fast = {"scan_id": scan["id"], "options": {"schedule": "fast"}}
            _wait_running(c, c.post("/v1/fits", json=fast).json()["id"])
        group = _group(proc.pid)
        assert len(group) >= 4, group  # supervisor, 2 API processes, a pool process
        os.kill(proc.pid, signal.SIGKILL)
        proc.p.wait(timeout=10)
        print(f"serve --workers 2: gone {_gone_within(proc.pid, 10):.2f} s after the SIGKILL")
    finally:
        proc.stop()
