"""Fair dispatch in embedded mode: one tenant's burst of 40 fits does not starve another's fit.

Measured with a real server and pool: the second tenant's fit waits at most the one fit that is
in the pool when it arrives (FIFO dispatch made it wait for all 40: issue 11's 45 s)."""

from __future__ import annotations

import subprocess
import sys

import httpx

from service.testing import free_port, service_env, sim_files, start_server, upload_scan, wait_state

KEY = "test-key-fairness"
FAST = {"schedule": "fast"}
#: process handoff after the fit ahead finished: callback, dispatch, pool pickup, claim (s)
HANDOFF_S = 0.5


def test_second_tenant_waits_at_most_one_fit_behind_a_40_fit_burst(tmp_path):
    sim = sim_files(tmp_path / "sim", seed=9)
    env = service_env(
        {
            "BODYSPACE_DATA_DIR": str(tmp_path / "data"),
            "BODYSPACE_API_KEY": KEY,
            "BODYSPACE_TENANT_MAX_ACTIVE_FITS": "50",  # the burst is accepted, to be dispatched
        }
    )
    port = free_port()
    server = start_server(env, port, tmp_path / "server.log")
    try:
        out = subprocess.run(
            [sys.executable, "-m", "service.commands", "keys", "create", "--tenant", "b"],
            env=env, capture_output=True, text=True, check=True,
        )  # fmt: skip
        url = f"http://127.0.0.1:{port}"
        with (
            httpx.Client(base_url=url, headers={"X-API-Key": KEY}, timeout=60) as a,
            httpx.Client(base_url=url, headers={"X-API-Key": out.stdout.split()[-1]}) as b,
        ):
            scan_a = upload_scan(a, sim).json()["id"]
            scan_b = upload_scan(b, sim).json()["id"]
            # steady state: the pool process is started and warm
            warm = a.post("/v1/fits", json={"scan_id": scan_a, "options": FAST}).json()["id"]
            assert wait_state(a, warm, timeout=180)["state"] == "succeeded"
            burst = []
            for _ in range(40):
                r = a.post("/v1/fits", json={"scan_id": scan_a, "options": FAST})
                assert r.status_code == 202, r.text
                burst.append(r.json()["id"])
            r = b.post("/v1/fits", json={"scan_id": scan_b, "options": FAST})
            assert r.status_code == 202, r.text
            done = wait_state(b, r.json()["id"], timeout=240)
            assert done["state"] == "succeeded", (done, server.output()[-3000:])
            fits_a = [a.get(f"/v1/fits/{i}").json() for i in burst]
            ran = [f for f in fits_a if f["timings"]["run_s"] is not None]
            assert ran, "no fit of the burst finished before the other tenant's"
            b_start = done["timings"]["started_at"]
            ahead = [f for f in fits_a if (f["timings"]["started_at"] or b_start) < b_start]
            longest = max(f["timings"]["run_s"] for f in ran)
            waited = done["timings"]["queued_s"]
            print(
                f"tenant B waited {waited:.2f} s behind a 40-fit burst; {len(ahead)} fit(s) of "
                f"A started before; A's fits ran {longest:.2f} s at most"
            )
            assert len(ahead) <= 1, ahead
            assert waited <= longest + HANDOFF_S, (waited, longest)
    finally:
        server.stop()
