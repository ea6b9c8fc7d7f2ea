"""Request body limits for every non-multipart route (JSON bodies): ``BodyLimit``.

An ASGI middleware: a body larger than ``Settings.max_json_bytes`` is answered ``413``
``body_too_large`` -- at once when ``Content-Length`` says so, otherwise as soon as the bytes read
from the stream pass the limit (a chunked body is never trusted to be small). Bodies within the
limit are read here and replayed to the app unchanged, so the app never reads more than the limit.
Multipart uploads have their own streaming limits (:mod:`service.uploads`).
"""

from __future__ import annotations

import json
from typing import Any

from service.errors import API_ERRORS, error_body

#: After a refusal, read and discard at most this much of the rest so the client sees the answer.
DRAIN_LIMIT = 16 * 1024 * 1024
_METHODS = frozenset({"POST", "PUT", "PATCH"})


def _header(headers: list[tuple[bytes, bytes]], name: bytes) -> bytes | None:
    for k, v in headers:
        if k == name:
            return v
    return None


class BodyLimit:
    """ASGI middleware: see the module docstring. ``limit`` in bytes."""

    def __init__(self, app: Any, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["method"] not in _METHODS:
            return await self.app(scope, receive, send)
        headers = scope["headers"]
        ctype = (_header(headers, b"content-type") or b"").lower()
        if ctype.startswith(b"multipart/form-data"):
            return await self.app(scope, receive, send)
        declared = _header(headers, b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.limit:
            return await self._refuse(send, receive, int(declared))
        chunks: list[dict] = []
        size = 0
        while True:
            msg = await receive()
            chunks.append(msg)
            if msg["type"] != "http.request":
                break
            size += len(msg.get("body", b""))
            if size > self.limit:
                return await self._refuse(send, receive, None)
            if not msg.get("more_body", False):
                break

        async def replay() -> dict:
            return chunks.pop(0) if chunks else await receive()

        await self.app(scope, replay, send)

    async def _refuse(self, send: Any, receive: Any, declared: int | None) -> None:
        read = 0
        while read <= DRAIN_LIMIT:  # let the client finish sending, so it reads the answer
            msg = await receive()
            if msg["type"] != "http.request" or not msg.get("more_body", False):
                break
            read += len(msg.get("body", b""))
        status, _ = API_ERRORS["body_too_large"]
        size = f"{declared:,} bytes" if declared is not None else "larger than that"
        details: dict[str, Any] = {"limit_bytes": self.limit}
        if declared is not None:
            details["size_bytes"] = declared
        body = json.dumps(
            error_body(
                "body_too_large",
                f"the request body is {size}; the limit for JSON bodies is {self.limit:,} bytes "
                "(BODYSPACE_MAX_JSON_BYTES)",
                details,
            )
        ).encode()
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
