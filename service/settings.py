"""Service settings: one pydantic-settings class, env prefix ``BODYSPACE_``, cached.

Nothing else in ``service/`` or ``worker/`` reads ``os.environ``. Embedded mode (the default) needs
no settings at all: SQLite and the blob folder live under ``DATA_DIR`` and fits run in a local
process pool. Distributed mode sets ``DATABASE_URL`` (PostgreSQL) and ``BROKER_URL`` (Redis); the
blob folder (``BLOB_DIR``) must then be a shared mount at the same path on every machine.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """All service and worker settings (environment variables ``BODYSPACE_<NAME>``)."""

    model_config = SettingsConfigDict(env_prefix="BODYSPACE_", extra="ignore")

    data_dir: Path = Field(Path("bodyspace-data"), description="embedded database + blobs")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default SQLite in DATA_DIR")
    broker_url: str | None = Field(None, description="redis://… enables Celery (distributed mode)")
    blob_dir: Path | None = Field(None, description="blob folder; default DATA_DIR/blobs")
    blob_backend: Literal["folder", "database"] = Field(
        "folder", description="'folder' (BLOB_DIR, a shared mount when distributed) or 'database'"
    )
    api_key: str | None = Field(None, description="embedded mode: the local tenant's key")
    api_key_cache_ttl_s: float = Field(
        30.0,
        description="seconds an API key's lookup is reused in a process (a revoked or deleted "
        "key keeps working at most this long); 0 disables the cache",
    )
    api_key_cache_size: int = Field(10_000, description="API keys cached per process (LRU)")

    # limits
    max_upload_bytes: int = 200 * 1024 * 1024
    max_marker_bytes: int = 1024 * 1024
    max_json_bytes: int = Field(
        1024 * 1024, description="largest JSON request body (413 body_too_large above it)"
    )
    max_vertices: int = 5_000_000
    max_faces: int = 10_000_000
    full_validation_max_bytes: int = Field(
        32 * 1024 * 1024, description="uploads up to this size are fully parsed before acceptance"
    )
    page_size_max: int = 200

    cors_origins: str = Field(
        "",
        description="comma-separated origins (scheme://host[:port]) whose browser pages may call "
        "the API; empty (the default): no cross-origin access",
    )

    # backpressure
    tenant_max_active_fits: int = Field(
        8, description="fits queued + running per tenant; beyond: 429 with Retry-After"
    )
    max_queued_fits: int = Field(
        1000, description="queued fits of all tenants; beyond: 503 queue_full with Retry-After"
    )

    # jobs
    workers: int = Field(1, description="embedded mode: size of the local process pool")
    job_time_limit_s: float = 900.0
    progress_interval_s: float = 0.5
    heartbeat_interval_s: float = 5.0
    stale_after_s: float = 60.0
    sweep_interval_s: float = 30.0
    requeue_after_s: float = 600.0
    max_attempts: int = 3
    queue_name: str = "bodyspace"
    worker_beat_interval_s: float = Field(
        5.0, description="distributed: seconds between a worker's 'I consume the queue' beats"
    )
    worker_beat_ttl_s: float = Field(
        15.0, description="distributed: a worker without a beat for this long counts as gone"
    )
    ready_cache_s: float = Field(
        2.0, description="seconds /readyz reuses its answer (probes stay cheap)"
    )

    @property
    def resolved_database_url(self) -> str:
        """The SQLAlchemy URL (``postgresql://`` is mapped to the psycopg 3 driver)."""
        url = self.database_url or f"sqlite:///{(self.data_dir / 'bodyspace.db').resolve()}"
        for prefix in ("postgresql://", "postgres://"):
            if url.startswith(prefix):
                return "postgresql+psycopg://" + url[len(prefix) :]
        return url

    @property
    def resolved_blob_dir(self) -> Path:
        """Root folder of the blob store."""
        return (self.blob_dir or self.data_dir / "blobs").resolve()

    @property
    def cors_origin_list(self) -> list[str]:
        """:attr:`cors_origins` as a list (no trailing slashes, blanks dropped)."""
        return [o.strip().rstrip("/") for o in self.cors_origins.split(",") if o.strip()]

    @property
    def distributed(self) -> bool:
        """True when a broker is configured (fits run on Celery workers)."""
        return bool(self.broker_url)

    @property
    def visibility_timeout_s(self) -> int:
        """Broker visibility timeout, above the hard time limit: a running job is never re-sent."""
        return int(self.job_time_limit_s * 2 + 120)


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings (read once from the environment)."""
    return Settings()
