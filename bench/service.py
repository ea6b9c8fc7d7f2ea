"""Service benchmark on loopback: queue overhead, fit throughput, large-upload handling.

    .venv/bin/python -m bench.service [--jobs 6] [--upload-mb 100]

- **queue overhead** per fit job, distributed (Celery + Redis + PostgreSQL) and embedded (local
  pool): submit -> start (``started_at - created_at``) and finish -> visible to a client polling
  every 10 ms (``first poll seeing succeeded - finished_at``), median over ``--jobs`` sequential
  jobs on a warm worker;
- **fit throughput** with 1 and 2 Celery workers (concurrency 1 each): ``--jobs`` fast-schedule
  fits submitted at once, jobs per minute from first submit to last finish;
- **upload** of a ~100 MB binary PLY to the embedded API: wall time, and the API process's peak
  RSS (``VmHWM``) before and after.

Needs the local Redis and PostgreSQL (as the integration tests do); a throwaway database is
created and dropped.
"""

from __future__ import annotations

import argparse
import os
import secrets
import statistics
import tempfile
import time
from datetime import datetime
from pathlib import Path

import httpx
import numpy as np

from service.testing import (
    free_port,
    service_env,
    sim_files,
    start_server,
    start_worker,
    upload_scan,
    wait_state,
)

PG_ADMIN = os.environ.get(
    "BODYSPACE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/postgres"
)
REDIS_URL = os.environ.get("BODYSPACE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
KEY = "bench-key"
FAST = {"schedule": "fast"}


def _ts(s: str) -> float:
    return datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()


def _vm_hwm_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _overhead(c: httpx.Client, scan_id: str, n: int) -> tuple[float, float]:
    """Median submit->start and finish->visible (ms) over ``n`` sequential jobs."""
    starts, visibles = [], []
    for _ in range(n):
        fid = c.post("/v1/fits", json={"scan_id": scan_id, "options": FAST}).json()["id"]
        while True:
            b = c.get(f"/v1/fits/{fid}").json()
            if b["state"] in ("succeeded", "failed"):
                seen = time.time()
                break
            time.sleep(0.01)
        assert b["state"] == "succeeded", b
        t = b["timings"]
        starts.append((_ts(t["started_at"]) - _ts(t["created_at"])) * 1000)
        visibles.append((seen - _ts(t["finished_at"])) * 1000)
    return statistics.median(starts), statistics.median(visibles)


def _throughput(c: httpx.Client, scan_id: str, n: int) -> float:
    t0 = time.monotonic()
    ids = [
        c.post("/v1/fits", json={"scan_id": scan_id, "options": FAST}).json()["id"]
        for _ in range(n)
    ]
    for fid in ids:
        assert wait_state(c, fid, timeout=600)["state"] == "succeeded"
    return n / (time.monotonic() - t0) * 60


def _big_ply(path: Path, sim_scan: Path, target_mb: float) -> int:
    """A binary PLY of ~``target_mb`` MB: copies of a simulated scan side by side."""
    from core.io import read_mesh, write_ply

    raw = read_mesh(sim_scan)
    k = max(1, round(target_mb * 1e6 / sim_scan.stat().st_size))
    V = np.concatenate([raw.V + np.array([0.002 * i, 0.0, 0.0]) for i in range(k)])
    F = np.concatenate([raw.F + i * len(raw.V) for i in range(k)])
    write_ply(
        path, V, F, normals=np.tile(raw.normals, (k, 1)), confidence=np.tile(raw.confidence, k)
    )
    return path.stat().st_size


def distributed(tmp: Path, n_jobs: int) -> None:
    import psycopg

    name = f"bodyspace_bench_{secrets.token_hex(4)}"
    admin = psycopg.connect(PG_ADMIN, autocommit=True)
    admin.execute(f'CREATE DATABASE "{name}"')
    procs = []
    try:
        env = service_env(
            {
                "BODYSPACE_DATABASE_URL": PG_ADMIN.rsplit("/", 1)[0] + "/" + name,
                "BODYSPACE_BROKER_URL": REDIS_URL,
                "BODYSPACE_DATA_DIR": str(tmp / "shared"),
                "BODYSPACE_API_KEY": KEY,
                "BODYSPACE_QUEUE_NAME": f"bench-{secrets.token_hex(4)}",
            }
        )
        port = free_port()
        procs.append(start_server(env, port, tmp / "api.log"))
        procs.append(start_worker(env, tmp / "w1.log", "b1"))
        sim = sim_files(tmp / "sim", seed=3)
        with httpx.Client(
            base_url=f"http://127.0.0.1:{port}", headers={"X-API-Key": KEY}, timeout=60
        ) as c:
            scan_id = upload_scan(c, sim).json()["id"]
            _overhead(c, scan_id, 1)  # warm-up
            s, v = _overhead(c, scan_id, n_jobs)
            print(f"distributed  queue overhead: submit->start {s:7.1f} ms, finish->visible "
                  f"{v:6.1f} ms (median of {n_jobs})")  # fmt: skip
            one = _throughput(c, scan_id, n_jobs)
            procs.append(start_worker(env, tmp / "w2.log", "b2"))
            time.sleep(3)
            _overhead(c, scan_id, 2)  # warm the second worker
            two = _throughput(c, scan_id, n_jobs)
            print(f"distributed  throughput: 1 worker {one:5.1f} fits/min, 2 workers {two:5.1f} "
                  f"fits/min ({os.cpu_count()} CPUs, fast schedule)")  # fmt: skip
    finally:
        for p in procs:
            p.stop()
        admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.close()


def embedded(tmp: Path, n_jobs: int, upload_mb: float) -> None:
    env = service_env(
        {
            "BODYSPACE_DATA_DIR": str(tmp / "embedded"),
            "BODYSPACE_API_KEY": KEY,
            "BODYSPACE_MAX_UPLOAD_BYTES": str(int(upload_mb * 3e6)),
        }
    )
    port = free_port()
    api = start_server(env, port, tmp / "embedded.log")
    try:
        sim = sim_files(tmp / "sim", seed=3)
        with httpx.Client(
            base_url=f"http://127.0.0.1:{port}", headers={"X-API-Key": KEY}, timeout=600
        ) as c:
            scan_id = upload_scan(c, sim).json()["id"]
            _overhead(c, scan_id, 1)
            s, v = _overhead(c, scan_id, n_jobs)
            print(f"embedded     queue overhead: submit->start {s:7.1f} ms, finish->visible "
                  f"{v:6.1f} ms (median of {n_jobs})")  # fmt: skip
            big = tmp / "big.ply"
            size = _big_ply(big, sim.scan, upload_mb)
            before = _vm_hwm_mb(api.pid)
            t0 = time.monotonic()
            with open(big, "rb") as fh:
                r = c.post("/v1/scans", files={"scan": ("big.ply", fh, "application/x-ply")})
            dt = time.monotonic() - t0
            assert r.status_code == 201, r.text
            after = _vm_hwm_mb(api.pid)
            print(f"embedded     upload {size / 1e6:.0f} MB ({r.json()['n_vertices']:,} vertices): "
                  f"{dt:.2f} s ({size / 1e6 / dt:.0f} MB/s); API peak RSS {before:.0f} MB before, "
                  f"{after:.0f} MB after")  # fmt: skip
    finally:
        api.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=6)
    ap.add_argument("--upload-mb", type=float, default=100.0)
    ap.add_argument("--skip-distributed", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bodyspace-bench-") as d:
        tmp = Path(d)
        embedded(tmp, args.jobs, args.upload_mb)
        if not args.skip_distributed:
            distributed(tmp, args.jobs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
