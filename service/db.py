"""Database engine, sessions and migrations (SQLite embedded, PostgreSQL when configured)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from functools import lru_cache
from pathlib import Path

from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.orm import Session, sessionmaker

from service.settings import Settings, get_settings

MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"
_PG_MIGRATION_LOCK = 0x626F6479  # advisory lock id ("body")


def aware(dt: datetime | None) -> datetime | None:
    """Attach UTC to a naive datetime (SQLite returns naive values)."""
    if dt is not None and dt.tzinfo is None:
        return dt.replace(tzinfo=UTC)
    return dt


def _make_engine(url: str) -> Engine:
    if url.startswith("sqlite"):
        path = url.split("///", 1)[-1]
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url, connect_args={"timeout": 30, "check_same_thread": False})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record) -> None:  # WAL: readers never block the one writer
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA secure_delete=ON")  # deleted rows are zeroed (personal data)
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

        return engine
    return create_engine(url, pool_pre_ping=True, pool_size=5, max_overflow=5)


@lru_cache(maxsize=4)
def _engine_for(url: str, pid: int) -> Engine:
    return _make_engine(url)


def get_engine(settings: Settings | None = None) -> Engine:
    """The engine for the configured database (one per process: safe after fork)."""
    return _engine_for((settings or get_settings()).resolved_database_url, os.getpid())


@lru_cache(maxsize=4)
def _sessionmaker(url: str, pid: int) -> sessionmaker[Session]:
    return sessionmaker(_engine_for(url, pid), expire_on_commit=False)


@contextmanager
def session_scope(settings: Settings | None = None) -> Iterator[Session]:
    """A session that commits on success and rolls back on error."""
    url = (settings or get_settings()).resolved_database_url
    session = _sessionmaker(url, os.getpid())()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


def ping(settings: Settings | None = None) -> None:
    """Raise if the database is unreachable."""
    with get_engine(settings).connect() as conn:
        conn.execute(text("SELECT 1"))


def alembic_config(url: str):
    """An Alembic ``Config`` for ``url`` using the packaged migrations."""
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def migrate(settings: Settings | None = None) -> None:
    """Upgrade the database to the newest migration (serialised across processes on PostgreSQL)."""
    from alembic import command

    settings = settings or get_settings()
    url = settings.resolved_database_url
    engine = get_engine(settings)
    cfg = alembic_config(url)
    with engine.begin() as conn:
        if conn.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_MIGRATION_LOCK})
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
