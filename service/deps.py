"""FastAPI dependencies: settings, database session, blob store, job runner, the caller's tenant."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Query, Request, Security
from fastapi.concurrency import run_in_threadpool
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from service.auth import KeyCache, hash_key, tenant_for_hash
from service.blobs import BlobStore
from service.db import session_scope
from service.errors import ApiError
from service.jobs import JobRunner
from service.settings import Settings

_bearer = HTTPBearer(auto_error=False, description="Authorization: Bearer KEY")
_api_key = APIKeyHeader(name="X-API-Key", auto_error=False, description="X-API-Key: KEY")


def get_app_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> BlobStore:
    return request.app.state.store


def get_runner(request: Request) -> JobRunner:
    return request.app.state.runner


def get_session(request: Request) -> Iterator[Session]:
    with session_scope(request.app.state.settings) as s:
        yield s


def key_cache(request: Request) -> KeyCache:
    """The process's API-key cache (created on first use from the app's settings)."""
    state = request.app.state
    cache = getattr(state, "key_cache", None)
    if cache is None:
        st: Settings = state.settings
        cache = state.key_cache = KeyCache(st.api_key_cache_ttl_s, st.api_key_cache_size)
    return cache


def _lookup(settings: Settings, key_hash: str) -> str | None:
    with session_scope(settings) as s:
        return tenant_for_hash(s, key_hash)


async def get_tenant(
    request: Request,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)],
    api_key: Annotated[str | None, Security(_api_key)],
) -> str:
    """The tenant id of the request's API key (401 when missing or invalid).

    Answers from the process's :class:`~service.auth.KeyCache` when it can (no database session,
    no thread hop); otherwise looks the key up in a worker thread and caches the answer for
    ``BODYSPACE_API_KEY_CACHE_TTL_S``.
    """
    key = bearer.credentials if bearer is not None else api_key
    if not key:
        raise ApiError("missing_api_key")
    h = hash_key(key.strip())
    cache = key_cache(request)
    tenant = cache.get(h)
    if tenant is KeyCache.MISS:
        tenant = await run_in_threadpool(_lookup, request.app.state.settings, h)
        cache.put(h, tenant)
    if tenant is None:
        raise ApiError("invalid_api_key")
    return tenant  # type: ignore[return-value]


def require_json(request: Request) -> None:
    """415 unless the body is JSON."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json" and not ctype.endswith("+json"):
        raise ApiError(
            "unsupported_media_type", f"expected application/json, got {ctype or 'none'!r}"
        )


TenantId = Annotated[str, Depends(get_tenant)]
SessionDep = Annotated[Session, Depends(get_session)]
StoreDep = Annotated[BlobStore, Depends(get_store)]
RunnerDep = Annotated[JobRunner, Depends(get_runner)]
SettingsDep = Annotated[Settings, Depends(get_app_settings)]


#: The ``cursor`` query parameter of the list routes: a previous page's ``next_cursor``, as it is.
Cursor = Annotated[
    str | None,
    Query(
        pattern=r"^[A-Za-z0-9_-]+$",
        max_length=200,
        description="a previous page's `next_cursor`, as it is (opaque: base64url); any other "
        "value is refused (422 validation_error, field cursor)",
    ),
]
