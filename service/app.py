"""The FastAPI application: ``create_app()``; ``uvicorn service.app:app`` serves it.

On start it migrates the database, registers the local API key (embedded mode: one is created and
printed on the first start unless ``BODYSPACE_API_KEY`` gives it), and starts the job runner.
"""

from __future__ import annotations

import fcntl
import gc
import logging
import os
import time
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager

from fastapi import FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute

from service import errors
from service.auth import ensure_local_key
from service.blobs import make_store
from service.body_routes import router as bodies_router
from service.db import migrate, ping, session_scope
from service.fastpath import SynthesizeFastPath
from service.jobs import JobRunner, make_runner
from service.limits import BodyLimit
from service.privacy import PrivateHeaders, install_access_log_redaction
from service.routes import router
from service.runtime import tune_malloc
from service.schemas import ErrorResponse, Health
from service.settings import Settings, get_settings
from service.shape_routes import router as models_router

log = logging.getLogger("bodyspace.service")
API_VERSION = "1.0.0"
#: In ``DATA_DIR`` (embedded mode): serialises the start of API processes sharing the folder.
STARTUP_LOCK = "startup.lock"


def _operation_id(route: APIRoute) -> str:
    return route.name


@contextmanager
def _startup_lock(settings: Settings) -> Iterator[None]:
    """Embedded mode: one API process at a time migrates the SQLite database and creates the
    local key (``bodyspace serve --workers N`` starts N at once; a key is created and printed
    once). PostgreSQL serialises migrations itself (advisory lock)."""
    if not settings.resolved_database_url.startswith("sqlite"):
        yield
        return
    fd = os.open(settings.data_dir / STARTUP_LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _startup(settings: Settings) -> None:
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    with _startup_lock(settings):
        migrate(settings)
        with session_scope(settings) as s:
            key = ensure_local_key(s, settings.api_key) if not settings.distributed else None
            if settings.distributed and settings.api_key:
                ensure_local_key(s, settings.api_key)
    if key:  # printed once on stdout, never logged (logs are kept and shipped)
        log.warning("created the first key of tenant 'local' (printed once on stdout, not logged)")
        print(
            f"bodyspace: created the local API key (shown once; tenant 'local'): {key}", flush=True
        )


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    tune_malloc()  # service/runtime.py: no page faults per request for large buffers
    await run_in_threadpool(_startup, settings)
    app.state.store = make_store(settings)
    runner = make_runner(settings)
    await run_in_threadpool(runner.start)
    app.state.runner = runner
    # Everything imported and built so far lives as long as the process: keep it out of the
    # collector's generations, so that a full collection later scans only what requests made
    # (measured: 148 000 tracked objects, full collections of 30-70 ms stalling the loop).
    gc.collect()
    gc.freeze()
    mode = "distributed" if settings.distributed else "embedded"
    log.info("bodyspace API ready (%s mode)", mode)
    try:
        yield
    finally:
        runner.shutdown()


def _readiness(st: Settings, runner: JobRunner) -> tuple[bool, dict[str, str]]:
    """(ready, checks): the database answers, jobs can be enqueued; ``checks["workers"]`` says
    why fits would wait (distributed mode without a live worker)."""
    checks: dict[str, str] = {}
    ok = True
    for name, fn in (("database", lambda: ping(st)), ("jobs", runner.check)):
        try:
            warning = fn()
            checks[name] = "ok"
            if name == "jobs" and st.distributed:
                checks["workers"] = warning or "ok"
        except Exception as e:
            ok = False
            checks[name] = f"{type(e).__name__}: {e}"[:300]
    return ok, checks


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app (settings default to :func:`get_settings`)."""
    app = FastAPI(
        title="bodyspace",
        version=API_VERSION,
        summary="Fit a template body to raw 3D body scans.",
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
    )
    app.state.settings = settings or get_settings()
    errors.install(app)
    app.add_middleware(SynthesizeFastPath)  # GLB synthesis without the routing machinery
    app.add_middleware(PrivateHeaders)  # also on the short path's answers
    install_access_log_redaction()
    origins = app.state.settings.cors_origin_list
    if origins:  # closed by default; outermost: preflights are answered before anything else
        app.add_middleware(
            CORSMiddleware,
            allow_origins=origins,
            allow_methods=["GET", "POST", "DELETE"],
            allow_headers=["Authorization", "X-API-Key", "Content-Type", "Accept"],
            expose_headers=["Location", "Retry-After"],
            allow_credentials=False,  # keys travel in headers, never in cookies
            max_age=600,
        )
    # outermost: no JSON body above the limit reaches the app (nor the short path)
    app.add_middleware(BodyLimit, limit=app.state.settings.max_json_bytes)
    app.include_router(router)
    app.include_router(models_router)
    app.include_router(bodies_router)

    @app.get("/healthz", response_model=Health, tags=["health"])
    def healthz() -> Health:
        """Liveness: the process answers."""
        return Health(status="ok")

    @app.get(
        "/readyz",
        response_model=Health,
        responses={503: {"model": ErrorResponse, "description": "a dependency is down"}},
        tags=["health"],
    )
    def readyz(request: Request) -> Health | JSONResponse:
        """Readiness: the database and the broker (or the local pool) are reachable and jobs
        can be enqueued (else 503 ``not_ready``); ``degraded`` (200) when fits are accepted but
        no worker consumes the queue. The answer is reused for ``BODYSPACE_READY_CACHE_S``."""
        st: Settings = request.app.state.settings
        cached = getattr(request.app.state, "ready", None)
        if cached is not None and time.monotonic() - cached[0] < st.ready_cache_s:
            ok, checks = cached[1], cached[2]
        else:
            ok, checks = _readiness(st, request.app.state.runner)
            request.app.state.ready = (time.monotonic(), ok, checks)
        if not ok:
            body = errors.error_body("not_ready", "a dependency is not reachable", checks)
            return JSONResponse(body, 503)
        mode = "distributed" if st.distributed else "embedded"
        status = "ok" if all(v == "ok" for v in checks.values()) else "degraded"
        return Health(status=status, mode=mode, checks=checks)

    return app


app = create_app()
