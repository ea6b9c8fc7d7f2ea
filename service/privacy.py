"""Personal data hygiene: response headers on ``/v1``, redacted access logs, deleted rows that
leave nothing readable in the SQLite files.

- :class:`PrivateHeaders` (ASGI middleware): ``Cache-Control: no-store`` and
  ``X-Content-Type-Options: nosniff`` on every ``/v1`` response (scans, bodies and measurements
  are personal data: no cache keeps them, no browser sniffs a download into something else).
- :class:`RedactQueryKeys` (logging filter on ``uvicorn.access``): the values of query
  parameters that look like credentials (``api_key``, ``key``, ``token``, …) are written as
  ``REDACTED``. The API reads keys from headers only, but a client may still put one in a URL.
- :func:`scrub_deleted`: after a DELETE, SQLite's write-ahead log is checkpointed and truncated;
  with ``PRAGMA secure_delete=ON`` (set on every connection, :mod:`service.db`) the deleted rows
  are overwritten with zeros in the database file, and the log keeps no copy of them.
"""

from __future__ import annotations

import logging
import re
from typing import Any

from service.settings import Settings

log = logging.getLogger("bodyspace.service")

_HEADERS = [(b"cache-control", b"no-store"), (b"x-content-type-options", b"nosniff")]
_NAMES = {b"cache-control", b"x-content-type-options"}


class PrivateHeaders:
    """Adds ``Cache-Control: no-store`` and ``X-Content-Type-Options: nosniff`` to ``/v1``."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or not scope["path"].startswith("/v1"):
            await self.app(scope, receive, send)
            return

        async def send_private(message: dict) -> None:
            if message["type"] == "http.response.start":
                headers = [h for h in message.get("headers", ()) if h[0].lower() not in _NAMES]
                message = {**message, "headers": headers + _HEADERS}
            await send(message)

        await self.app(scope, receive, send_private)


#: query parameters whose value is replaced in the access log
_SECRET_PARAM = re.compile(
    r"(?i)([?&](?:api[_-]?key|apikey|key|token|access[_-]?token|auth|authorization|password)=)"
    r"[^&#\s]*"
)


def redact_url(url: str) -> str:
    """``url`` with credential-like query values replaced by ``REDACTED``."""
    return _SECRET_PARAM.sub(r"\1REDACTED", url)


class RedactQueryKeys(logging.Filter):
    """Redacts credential-like query parameters in uvicorn's access log lines."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple) and record.args:
            record.args = tuple(redact_url(a) if isinstance(a, str) else a for a in record.args)
        return True


def install_access_log_redaction() -> None:
    """Add :class:`RedactQueryKeys` to ``uvicorn.access`` (once per process)."""
    logger = logging.getLogger("uvicorn.access")
    if not any(isinstance(f, RedactQueryKeys) for f in logger.filters):
        logger.addFilter(RedactQueryKeys())


def scrub_deleted(settings: Settings) -> None:
    """SQLite: checkpoint and truncate the write-ahead log after a DELETE, so that the deleted
    rows' pages are not left in ``bodyspace.db-wal`` (no-op on other databases)."""
    if not settings.resolved_database_url.startswith("sqlite"):
        return
    from service.db import get_engine

    try:
        with get_engine(settings).connect() as conn:
            busy = conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)").first()
        if busy and busy[0]:
            log.info("WAL checkpoint after a delete was busy (a reader): retried on the next one")
    except Exception as e:  # the delete itself succeeded
        log.warning("WAL checkpoint after a delete failed: %s", e)
