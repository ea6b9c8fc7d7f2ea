"""Real parts: Redis, PostgreSQL (a throwaway database per session), ``bodyspace serve`` in
distributed mode and ``bodyspace worker`` (Celery) subprocesses. No eager mode, no mocks.

``BODYSPACE_TEST_POSTGRES_URL`` (an admin connection, default the local ``postgres`` database) and
``BODYSPACE_TEST_REDIS_URL`` (default Redis database 15) say where they are.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable, Iterator

import httpx
import psycopg
import pytest
import redis

from service.testing import Proc, SimFiles, free_port, service_env, sim_files, start_server
from service.testing import start_worker as _start_worker

KEY = "test-key-integration"
PG_ADMIN = os.environ.get(
    "BODYSPACE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/postgres"
)
REDIS_URL = os.environ.get("BODYSPACE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")


@pytest.fixture(scope="session")
def pg_url() -> Iterator[str]:
    """A new PostgreSQL database for this session, dropped afterwards."""
    name = f"bodyspace_test_{secrets.token_hex(4)}"
    try:
        admin = psycopg.connect(PG_ADMIN, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as e:
        pytest.fail(f"PostgreSQL is not reachable at {PG_ADMIN} (.ci/run starts it): {e}")
    admin.execute(f'CREATE DATABASE "{name}"')
    base = PG_ADMIN.rsplit("/", 1)[0]
    try:
        yield f"{base}/{name}"
    finally:
        admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.close()


@pytest.fixture(scope="session")
def redis_client() -> redis.Redis:
    r = redis.Redis.from_url(REDIS_URL)
    try:
        r.ping()
    except redis.ConnectionError as e:
        pytest.fail(f"Redis is not reachable at {REDIS_URL} (.ci/run starts it): {e}")
    return r


@pytest.fixture(scope="session")
def env(tmp_path_factory, pg_url, redis_client) -> dict[str, str]:
    """Settings shared by the API and the workers (same database, broker and blob folder)."""
    queue = f"bodyspace-test-{secrets.token_hex(4)}"
    return service_env(
        {
            "BODYSPACE_DATABASE_URL": pg_url,
            "BODYSPACE_BROKER_URL": REDIS_URL,
            "BODYSPACE_DATA_DIR": str(tmp_path_factory.mktemp("shared")),
            "BODYSPACE_API_KEY": KEY,
            "BODYSPACE_QUEUE_NAME": queue,
            "BODYSPACE_PROGRESS_INTERVAL_S": "0.2",
            "BODYSPACE_HEARTBEAT_INTERVAL_S": "0.5",
            "BODYSPACE_STALE_AFTER_S": "6",
            "BODYSPACE_SWEEP_INTERVAL_S": "1",
            # one server for the whole session: fits of many tests add up (the limits have
            # their own tests with their own servers)
            "BODYSPACE_TENANT_MAX_ACTIVE_FITS": "100",
        }
    )


@pytest.fixture(scope="session")
def api(env, tmp_path_factory) -> Iterator[str]:
    port = free_port()
    proc = start_server(env, port, tmp_path_factory.mktemp("logs") / "api.log")
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        proc.stop()


@pytest.fixture()
def client(api) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=api, headers={"Authorization": f"Bearer {KEY}"}, timeout=60) as c:
        yield c


@pytest.fixture()
def workers(env, tmp_path) -> Iterator[Callable[..., Proc]]:
    """Start Celery workers (``bodyspace worker``); all are stopped after the test."""
    started: list[Proc] = []

    def start(name: str, **extra: str) -> Proc:
        p = _start_worker(dict(env, **extra), tmp_path / f"{name}.log", name)
        started.append(p)
        return p

    yield start
    for p in started:
        p.stop()


@pytest.fixture(scope="session")
def sim(tmp_path_factory) -> SimFiles:
    return sim_files(tmp_path_factory.mktemp("sim"), seed=1)


@pytest.fixture(scope="session")
def queue(env) -> str:
    return env["BODYSPACE_QUEUE_NAME"]
