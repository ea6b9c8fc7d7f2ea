"""docker-compose.yml and the Dockerfile describe the distributed deployment consistently."""

from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]


def test_compose_has_api_worker_redis_postgres_with_shared_settings():
    doc = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = doc["services"]
    assert set(services) == {"api", "worker", "redis", "postgres"}
    api, worker = services["api"], services["worker"]
    assert api["environment"] == worker["environment"]  # one set of settings
    env = api["environment"]
    assert env["BODYSPACE_DATABASE_URL"].startswith("postgresql://")
    assert env["BODYSPACE_BROKER_URL"].startswith("redis://")
    assert api["command"][:2] == ["bodyspace", "serve"]
    assert worker["command"][:2] == ["bodyspace", "worker"]
    # the blob folder is shared by the API and the workers
    assert api["volumes"] == worker["volumes"]
    assert any(v.endswith(":" + env["BODYSPACE_DATA_DIR"]) for v in api["volumes"])
    for name in ("api", "worker"):
        assert set(services[name]["depends_on"]) == {"redis", "postgres"}
    assert set(doc["volumes"]) >= {v.split(":")[0] for v in api["volumes"]}


def test_dockerfile_installs_the_package_and_serves():
    text = (ROOT / "Dockerfile").read_text()
    assert "pip install ." in text
    assert '"bodyspace", "serve"' in text
    for folder in ("core", "service", "worker"):
        assert f"COPY {folder} " in text
