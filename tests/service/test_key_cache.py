"""API-key cache: answers reused for BODYSPACE_API_KEY_CACHE_TTL_S, revocation and deletion take
effect within it, invalid keys cannot grow it; against a real ``bodyspace serve`` too."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator

import httpx
import pytest

from service.auth import KeyCache, hash_key
from service.settings import Settings
from service.testing import free_port, service_env, start_server

TTL_S = 3.0


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_hit_within_ttl_then_expires():
    clock = Clock()
    c = KeyCache(ttl_s=30, clock=clock)
    h = hash_key("k")
    assert c.get(h) is KeyCache.MISS
    c.put(h, "ten_1")
    clock.t += 29.9
    assert c.get(h) == "ten_1"  # using it does not extend the entry
    clock.t += 0.2
    assert c.get(h) is KeyCache.MISS
    assert len(c) == 0


def test_invalid_keys_are_cached_in_their_own_bounded_lru():
    clock = Clock()
    c = KeyCache(ttl_s=30, maxsize=4, max_invalid=8, clock=clock)
    valid = [hash_key(f"good{i}") for i in range(4)]
    for i, h in enumerate(valid):
        c.put(h, f"ten_{i}")
    for i in range(10_000):  # a flood of made-up keys
        c.put(hash_key(f"bad{i}"), None)
    assert len(c) == 4 + 8
    assert [c.get(h) for h in valid] == ["ten_0", "ten_1", "ten_2", "ten_3"]
    assert c.get(hash_key("bad9999")) is None  # known invalid (recent)
    assert c.get(hash_key("bad0")) is KeyCache.MISS  # evicted
    c.put(hash_key("bad9999"), "ten_x")  # became valid: the invalid entry goes
    assert c.get(hash_key("bad9999")) == "ten_x"
    assert len(c) == 4 + 7  # moved over; the oldest valid key made room


def test_valid_lru_evicts_least_recently_used():
    c = KeyCache(ttl_s=30, maxsize=2, clock=Clock())
    a, b, d = hash_key("a"), hash_key("b"), hash_key("d")
    c.put(a, "A")
    c.put(b, "B")
    assert c.get(a) == "A"  # a is now the most recent
    c.put(d, "D")
    assert c.get(b) is KeyCache.MISS and c.get(a) == "A" and c.get(d) == "D"


def test_ttl_zero_disables():
    c = KeyCache(ttl_s=0)
    c.put(hash_key("k"), "ten")
    assert c.get(hash_key("k")) is KeyCache.MISS and len(c) == 0


def test_settings_default_and_env(monkeypatch):
    assert Settings().api_key_cache_ttl_s == 30.0
    monkeypatch.setenv("BODYSPACE_API_KEY_CACHE_TTL_S", "1.5")
    monkeypatch.setenv("BODYSPACE_API_KEY_CACHE_SIZE", "7")
    s = Settings()
    assert (s.api_key_cache_ttl_s, s.api_key_cache_size) == (1.5, 7)


# ---------------------------------------------------------------- through a real server


@pytest.fixture(scope="module")
def short_ttl_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    data = tmp_path_factory.mktemp("keycache")
    port = free_port()
    env = service_env(
        {
            "BODYSPACE_DATA_DIR": str(data),
            "BODYSPACE_API_KEY": "key-cache-local-key",
            "BODYSPACE_API_KEY_CACHE_TTL_S": str(TTL_S),
        }
    )
    proc = start_server(env, port, data / "server.log")
    try:
        yield {"url": f"http://127.0.0.1:{port}", "env": env, "db": data / "bodyspace.db"}
    finally:
        proc.stop()


def _new_key(server: dict, tenant: str) -> str:
    out = subprocess.run(
        [sys.executable, "-m", "service.commands", "keys", "create", "--tenant", tenant],
        env=server["env"], capture_output=True, text=True, check=True,
    )  # fmt: skip
    return out.stdout.split()[-1]


def _sql(server: dict, statement: str, key: str) -> None:
    with sqlite3.connect(server["db"], timeout=30) as db:
        assert db.execute(statement, (hash_key(key),)).rowcount == 1


def _status(server: dict, key: str) -> int:
    return httpx.get(server["url"] + "/v1/models", headers={"X-API-Key": key}).status_code


@pytest.mark.parametrize(
    "statement",
    [
        "UPDATE api_keys SET revoked_at = CURRENT_TIMESTAMP WHERE key_hash = ?",
        "DELETE FROM api_keys WHERE key_hash = ?",
    ],
    ids=["revoked", "deleted"],
)
def test_revoked_or_deleted_key_stops_working_within_ttl(short_ttl_server, statement):
    key = _new_key(short_ttl_server, "cache-test")
    t0 = time.monotonic()
    assert _status(short_ttl_server, key) == 200  # looked up and cached
    _sql(short_ttl_server, statement, key)
    if time.monotonic() - t0 < TTL_S - 0.5:
        assert _status(short_ttl_server, key) == 200  # still cached: the documented window
    while _status(short_ttl_server, key) == 200:
        assert time.monotonic() - t0 < TTL_S + 2.0, "key still accepted long after the TTL"
        time.sleep(0.1)
    assert _status(short_ttl_server, key) == 401


def test_invalid_keys_are_rejected(short_ttl_server):
    for i in range(200):
        assert _status(short_ttl_server, f"made-up-{i}") == 401
    r = httpx.get(short_ttl_server["url"] + "/v1/models", headers={"X-API-Key": "made-up-0"})
    assert r.status_code == 401 and r.json()["error"]["code"] == "invalid_api_key"
    assert _status(short_ttl_server, "key-cache-local-key") == 200
