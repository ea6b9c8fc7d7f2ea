"""Fixtures: a real ``bodyspace serve`` subprocess (embedded mode) on a free port, temp DATA_DIR."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from service.testing import (
    SimFiles,
    ensure_gltf_validator,
    free_port,
    service_env,
    sim_files,
    start_server,
)

KEY_A = "test-key-tenant-a"
MAX_UPLOAD = 3_000_000


@pytest.fixture(scope="session")
def sim(tmp_path_factory: pytest.TempPathFactory) -> SimFiles:
    return sim_files(tmp_path_factory.mktemp("sim"), seed=0)


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    data = tmp_path_factory.mktemp("data")
    port = free_port()
    env = service_env(
        {
            "BODYSPACE_DATA_DIR": str(data),
            "BODYSPACE_API_KEY": KEY_A,
            "BODYSPACE_MAX_UPLOAD_BYTES": str(MAX_UPLOAD),
            "BODYSPACE_PROGRESS_INTERVAL_S": "0.2",
            "BODYSPACE_MAX_VERTICES": "100000",
            "BODYSPACE_HEARTBEAT_INTERVAL_S": "0.5",
            # one server for the whole session: fits of many tests add up (the limits have
            # their own tests with their own servers)
            "BODYSPACE_TENANT_MAX_ACTIVE_FITS": "100",
        }
    )
    proc = start_server(env, port, data / "server.log")
    # a second tenant, created as an operator would (`bodyspace keys create --tenant other`)
    out = subprocess.run(
        [sys.executable, "-m", "service.commands", "keys", "create", "--tenant", "other"],
        env=env, capture_output=True, text=True, check=True,
    )  # fmt: skip
    key_b = out.stdout.split()[-1]
    try:
        yield {"url": f"http://127.0.0.1:{port}", "data": data, "key_b": key_b, "proc": proc}
    finally:
        proc.stop()


@pytest.fixture()
def client(server: dict) -> Iterator[httpx.Client]:
    with httpx.Client(
        base_url=server["url"], headers={"Authorization": f"Bearer {KEY_A}"}, timeout=60
    ) as c:
        yield c


@pytest.fixture()
def client_b(server: dict) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server["url"], headers={"X-API-Key": server["key_b"]}) as c:
        yield c


@pytest.fixture(scope="session")
def gltf_validator() -> Path:
    """``validate.js`` of the Khronos validator (npm-installed if missing)."""
    return ensure_gltf_validator()
