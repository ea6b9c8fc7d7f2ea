"""Embedded mode with several API processes on one data folder (``serve --workers N``).

Exactly one process runs the fits (the holder of ``DATA_DIR/runner.lock``); every process
accepts fits and sees every job; a fit accepted by a process that is then killed still runs; when
the fit-running process dies another takes over and re-runs its unfinished job.

Two ``bodyspace serve`` processes on two ports sharing one folder are the same arrangement as
``--workers 2`` (the lock does not care who started the processes), and let a test choose the
process a request goes to.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from service.testing import (
    Proc,
    free_port,
    service_env,
    sim_files,
    start_server,
    upload_scan,
    wait_ready,
    wait_state,
)

KEY = "test-key-embedded-workers"
SYN = "/v1/models/default/synthesize"
FAST = {"options": {"schedule": "fast"}}


def _env(data: Path, **extra: str) -> dict[str, str]:
    return service_env(
        {
            "BODYSPACE_DATA_DIR": str(data),
            "BODYSPACE_API_KEY": KEY,
            "BODYSPACE_HEARTBEAT_INTERVAL_S": "0.5",
            **extra,
        }
    )


def _client(port: int) -> httpx.Client:
    return httpx.Client(
        base_url=f"http://127.0.0.1:{port}",
        headers={"Authorization": f"Bearer {KEY}"},
        timeout=60,
    )


def _lock_holder(data: Path) -> int:
    return int((data / "runner.lock").read_text().strip())


def _parent_pid(pid: int) -> int | None:
    """The parent of a live process, None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[1])


def _wait_lock_holder(data: Path, not_pid: int | None = None, timeout: float = 30) -> int:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        try:
            pid = _lock_holder(data)
        except (OSError, ValueError):
            pid = None
        if pid is not None and pid != not_pid:
            return pid
        time.sleep(0.1)
    raise TimeoutError(f"no new runner lock holder in {timeout} s")


@pytest.fixture()
def two_servers(tmp_path: Path):
    """Servers A (started first: runs the fits) and B on one data folder."""
    data = tmp_path / "data"
    env = _env(data)
    pa, pb = free_port(), free_port()
    a = start_server(env, pa, tmp_path / "a.log")
    b = start_server(env, pb, tmp_path / "b.log")
    try:
        yield {"a": a, "b": b, "pa": pa, "pb": pb, "data": data, "env": env}
    finally:
        for p in (a, b):
            p.stop()


def test_one_process_runs_fits_and_a_fit_accepted_by_another_runs(two_servers, tmp_path):
    sim = sim_files(tmp_path / "sim", seed=3)
    s = two_servers
    assert _lock_holder(s["data"]) == s["a"].pid  # the first to start runs the fits
    with _client(s["pa"]) as ca, _client(s["pb"]) as cb:
        for c in (ca, cb):
            r = c.get("/readyz")
            assert r.status_code == 200 and r.json()["checks"]["jobs"] == "ok", r.text
        scan = upload_scan(cb, sim).json()
        assert ca.get(f"/v1/scans/{scan['id']}").status_code == 200  # A sees B's scan
        fit = cb.post("/v1/fits", json={"scan_id": scan["id"], **FAST})
        assert fit.status_code == 202, fit.text
        fit_id = fit.json()["id"]
        done = wait_state(cb, fit_id, timeout=180)
        assert done["state"] == "succeeded", (done, s["a"].output()[-3000:])
        # every process sees every job and its result
        assert ca.get(f"/v1/fits/{fit_id}").json()["state"] == "succeeded"
        assert fit_id in {f["id"] for f in ca.get("/v1/fits").json()["items"]}
        for c in (ca, cb):
            r = c.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"})
            assert r.status_code == 200 and r.content[:4] == b"glTF"
        # fits accepted by A run too
        fit2 = ca.post("/v1/fits", json={"scan_id": scan["id"], **FAST}).json()["id"]
        assert wait_state(cb, fit2, timeout=180)["state"] == "succeeded"
        # synthesis answers in both
        for c in (ca, cb):
            r = c.post(SYN, json={"sex": "male", "height_m": 1.8})
            assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary"
    assert "Traceback" not in s["a"].output() + s["b"].output()


def test_kill9_of_the_accepting_process_loses_no_fit(two_servers, tmp_path):
    sim = sim_files(tmp_path / "sim", seed=4)
    s = two_servers
    with _client(s["pb"]) as cb:
        scan = upload_scan(cb, sim).json()
        ids = [cb.post("/v1/fits", json={"scan_id": scan["id"], **FAST}).json()["id"]]
    s["b"].kill9()  # right after the 202: the job is a committed row, A runs it
    with _client(s["pa"]) as ca:
        done = wait_state(ca, ids[0], timeout=180)
        assert done["state"] == "succeeded", (done, s["a"].output()[-3000:])


def test_kill9_of_the_fit_running_process_hands_its_jobs_over(two_servers, tmp_path):
    sim = sim_files(tmp_path / "sim", seed=5)
    s = two_servers
    a_pid = s["a"].pid
    with _client(s["pb"]) as cb:
        scan = upload_scan(cb, sim).json()
        ids = [cb.post("/v1/fits", json={"scan_id": scan["id"], **FAST}).json()["id"] for _ in "12"]
        assert wait_state(cb, ids[0], ("running",), timeout=60)["state"] == "running"
        s["a"].kill9()  # the leader and its pool, mid-fit; the second fit still queued
        assert _wait_lock_holder(s["data"], not_pid=a_pid) == s["b"].pid
        for fit_id in ids:
            done = wait_state(cb, fit_id, timeout=240)
            assert done["state"] == "succeeded", (done, s["b"].output()[-3000:])
        # the interrupted fit ran again (a second attempt), not twice at once
        assert cb.get(f"/v1/fits/{ids[0]}").json()["attempts"] >= 2


def test_serve_workers_2_embedded(tmp_path):
    """``bodyspace serve --workers 2`` on a fresh folder: one key created and printed once,
    both processes serve, one runs the fits, a killed process is restarted."""
    sim = sim_files(tmp_path / "sim", seed=6)
    data = tmp_path / "data"
    env = {k: v for k, v in _env(data).items() if k != "BODYSPACE_API_KEY"}
    port = free_port()
    args = ["-m", "service.commands", "serve", "--port", str(port), "--workers", "2"]
    proc = Proc([sys.executable, *args, "--log-level", "warning"], env, tmp_path / "api.log")
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(proc, url, path="/readyz", timeout=90, poll=0.2)
        time.sleep(1.0)  # both processes started
        out = proc.output()
        keys = [line.split()[-1] for line in out.splitlines() if "bodyspace: created" in line]
        assert len(keys) == 1, out  # created and printed once (one process created it)
        children = subprocess.run(
            ["ps", "-ww", "--ppid", str(proc.pid), "-o", "pid=,args="],
            capture_output=True,
            text=True,
        ).stdout.splitlines()
        api = [int(c.split()[0]) for c in children if "spawn_main" in c]
        assert len(api) == 2, children
        leader = _lock_holder(data)
        assert leader in api
        headers = {"Authorization": f"Bearer {keys[0]}"}
        for i in range(8):  # a new connection each time
            r = httpx.post(
                url + SYN, json={"sex": "female", "height_m": 1.6 + 0.01 * i}, headers=headers,
                timeout=60,
            )  # fmt: skip
            assert r.status_code == 200, r.text
        # kill the process running the fits: it is restarted, and another process of this
        # server takes the fits over (the survivor or the replacement, whichever locks first)
        subprocess.run(["kill", "-9", str(leader)], check=True)
        holder = _wait_lock_holder(data, not_pid=leader)
        assert holder in api or _parent_pid(holder) == proc.pid, (holder, api)
        with httpx.Client(base_url=url, headers=headers, timeout=60) as c:
            scan = upload_scan(c, sim).json()
            fit_id = c.post("/v1/fits", json={"scan_id": scan["id"], **FAST}).json()["id"]
            done = wait_state(c, fit_id, timeout=180)
            assert done["state"] == "succeeded", (done, proc.output()[-3000:])
        t_end = time.monotonic() + 60
        while True:  # the killed process was replaced
            children = subprocess.run(
                ["ps", "-ww", "--ppid", str(proc.pid), "-o", "pid=,args="], capture_output=True,
                text=True,
            ).stdout.splitlines()  # fmt: skip
            now = [int(c.split()[0]) for c in children if "spawn_main" in c]
            if len(now) == 2 and leader not in now:
                break
            assert time.monotonic() < t_end, children
            time.sleep(0.2)
    finally:
        proc.stop()
    assert "Traceback" not in proc.output(), proc.output()
