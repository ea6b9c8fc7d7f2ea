"""A short path for the hot request: ``POST /v1/models/{model}/synthesize`` answered as GLB.

Through FastAPI the GLB answer costs ~0.4 ms of CPU in routing, middleware, dependency
resolution and the response classes on top of synthesis and encoding (~1.2 ms) --
measured in-process, ``bench/synthesis_load.py`` for the whole server. :class:`SynthesizeFastPath`
(an ASGI middleware around the app) answers the plain case itself, with the same code and
result as the route (:func:`service.shape_routes.synthesize`):

- ``Content-Type: application/json``, an ``Accept`` that does not ask for JSON, a body up to
  :data:`MAX_BODY` bytes;
- an API key whose tenant is in the process's key cache (:class:`service.auth.KeyCache`);
- a model already loaded in this process;
- a body that parses (``json.loads``, as FastAPI) and validates as
  :class:`~service.schemas.SynthesizeRequest` (as FastAPI), and a synthesis that succeeds.

Everything else -- any error, a key not cached, the first request of a model, JSON answers,
other content types -- goes to the app unchanged (the body, if already read, is replayed), so
that errors, their shapes and every other behaviour stay the route's own. The answer's headers
are those of the route's ``Response``: ``content-length``, ``content-type`` and, for a body the
model extrapolated, ``x-bodyspace-warnings`` (:func:`service.shape_routes.warnings_header`).
"""

from __future__ import annotations

import json
import re
from typing import Any

from service.auth import KeyCache, hash_key
from service.deps import key_cache

PATH = re.compile(r"/v1/models/([^/]+)/synthesize")
#: Larger bodies (a long ``pca`` list, say) take the app's path.
MAX_BODY = 16 * 1024


def _header(headers: list[tuple[bytes, bytes]], name: bytes) -> bytes | None:
    for k, v in headers:
        if k.lower() == name:
            return v
    return None


class SynthesizeFastPath:
    """ASGI middleware: see the module docstring. ``app`` is the FastAPI application (its
    ``state`` holds the settings and the key cache)."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["method"] != "POST":
            return await self.app(scope, receive, send)
        m = PATH.fullmatch(scope["path"])
        if m is None or scope.get("root_path"):
            return await self.app(scope, receive, send)
        answer, extra, chunks = await self._try(m.group(1), scope, receive)
        if answer is None:
            return await self.app(scope, _replay(chunks, receive), send)
        await send(
            {
                "type": "http.response.start",
                "status": 200,
                "headers": [
                    *extra,
                    (b"content-length", str(len(answer)).encode()),
                    (b"content-type", b"model/gltf-binary"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": answer})

    async def _try(
        self, model: str, scope: dict, receive: Any
    ) -> tuple[memoryview | None, list[tuple[bytes, bytes]], list[dict]]:
        """The GLB and its extra headers, or None (and the messages read so far) when the app
        must answer."""
        from service import shape_routes as sr

        chunks: list[dict] = []
        headers = scope["headers"]
        ctype = _header(headers, b"content-type")
        if ctype is None or ctype.strip().lower() != b"application/json":
            return None, [], chunks
        accept = (_header(headers, b"accept") or b"").decode("latin-1").lower()
        if "application/json" in accept and sr.GLB not in accept:
            return None, [], chunks
        if model not in sr._warm:
            return None, [], chunks
        key = _api_key(headers)
        if not key:
            return None, [], chunks
        request = _StateOnly(scope)
        tenant = key_cache(request).get(hash_key(key))  # type: ignore[arg-type]
        if tenant is KeyCache.MISS or tenant is None:
            return None, [], chunks
        raw = bytearray()
        while True:
            msg = await receive()
            chunks.append(msg)
            if msg["type"] != "http.request":
                return None, [], chunks
            raw += msg.get("body", b"")
            if len(raw) > MAX_BODY:
                return None, [], chunks
            if not msg.get("more_body", False):
                break
        try:
            body = sr.SynthesizeRequest.model_validate(json.loads(raw))
            V = sr.synthesize_vertices(sr.get_model(model), body)
            return memoryview(sr._glb_encoder().encode_buffer(V)), chunks
        except Exception:  # the app answers (and reports) it the route's way
            return None, [], chunks


def _api_key(headers: list[tuple[bytes, bytes]]) -> str | None:
    """The key as :func:`service.deps.get_tenant` reads it (Bearer first, else X-API-Key)."""
    auth = _header(headers, b"authorization")
    if auth is not None:
        scheme, _, cred = auth.decode("latin-1").partition(" ")
        if scheme.lower() == "bearer" and cred.strip():
            return cred.strip()
        return None  # something else: let the app decide
    key = _header(headers, b"x-api-key")
    return key.decode("latin-1").strip() if key else None


class _StateOnly:
    """What :func:`service.deps.key_cache` needs of a request: ``app.state``."""

    def __init__(self, scope: dict) -> None:
        self.app = scope["app"]


def _replay(chunks: list[dict], receive: Any) -> Any:
    """``receive`` that first returns the messages already read."""
    pending = list(chunks)

    async def replayed() -> dict:
        if pending:
            return pending.pop(0)
        return await receive()

    return replayed
