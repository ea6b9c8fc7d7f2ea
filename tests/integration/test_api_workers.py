"""``bodyspace serve --workers N`` in distributed mode: several API processes on one port (embedded
mode: ``tests/service/test_embedded_workers.py``)."""

from __future__ import annotations

import os
import secrets
import subprocess
import sys
from pathlib import Path

import httpx
import psycopg
import pytest

from service.testing import Proc, free_port, service_env, wait_ready

PG_ADMIN = os.environ.get(
    "BODYSPACE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/postgres"
)
REDIS_URL = os.environ.get("BODYSPACE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
KEY = "test-key-api-workers"
SYN = "/v1/models/default/synthesize"


@pytest.fixture()
def fresh_db() -> str:
    """An empty database: both API processes race to register the configured key on it."""
    name = f"bodyspace_test_{secrets.token_hex(4)}"
    admin = psycopg.connect(PG_ADMIN, autocommit=True, connect_timeout=5)
    admin.execute(f'CREATE DATABASE "{name}"')
    try:
        yield PG_ADMIN.rsplit("/", 1)[0] + "/" + name
    finally:
        admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.close()


def test_two_api_processes_serve_synthesis(tmp_path: Path, fresh_db: str, redis_client):
    env = service_env(
        {
            "BODYSPACE_DATABASE_URL": fresh_db,
            "BODYSPACE_BROKER_URL": REDIS_URL,
            "BODYSPACE_DATA_DIR": str(tmp_path / "shared"),
            "BODYSPACE_API_KEY": KEY,
            "BODYSPACE_QUEUE_NAME": f"bodyspace-test-{secrets.token_hex(4)}",
        }
    )
    port = free_port()
    args = ["-m", "service.commands", "serve", "--port", str(port), "--workers", "2"]
    proc = Proc([sys.executable, *args], env, tmp_path / "api.log")
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(proc, url, path="/readyz", timeout=90, poll=0.2)
        children = subprocess.run(
            ["ps", "--ppid", str(proc.pid), "-o", "pid="], capture_output=True, text=True
        ).stdout.split()
        assert len(children) >= 2, children
        for i in range(12):  # a new connection each time: both processes answer
            r = httpx.post(
                url + SYN,
                json={"sex": "female" if i % 2 else "male", "height_m": 1.70 + 0.01 * i},
                headers={"Authorization": f"Bearer {KEY}"},
                timeout=60,
            )
            assert r.status_code == 200, r.text
            assert r.headers["content-type"] == "model/gltf-binary"
        assert "Traceback" not in proc.output(), proc.output()
    finally:
        proc.stop()
