"""Routes under ``/v1``: scans (upload, list, get, delete) and fits (create, list, get, result)."""

from __future__ import annotations

import base64
import json
import logging
from datetime import datetime
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, StreamingResponse
from sqlalchemy import and_, delete, func, or_, select
from sqlalchemy.orm import Session

from core.io.frame import UNITS_OPTIONS
from service.blobs import BlobStore, sha256_file
from service.db import aware, session_scope
from service.deps import (
    Cursor,
    RunnerDep,
    SessionDep,
    SettingsDep,
    StoreDep,
    TenantId,
    require_json,
)
from service.errors import ApiError, clip
from service.fit_job import RESULT_FORMATS, TEXTURE_FORMAT, result_key
from service.models import Blob, Fit, Scan, Tenant, new_id, utcnow
from service.privacy import scrub_deleted
from service.schemas import (
    ErrorResponse,
    FitCreate,
    FitOut,
    FitPage,
    FullFit,
    MarkerlessFit,
    MarkersOnlyFit,
    MeasurementsFit,
    ScanOut,
    ScanPage,
    Timings,
)
from service.settings import Settings
from service.uploads import Form, parse_multipart

log = logging.getLogger("bodyspace.service")

ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorResponse, "description": "missing or invalid API key"},
    404: {"model": ErrorResponse, "description": "not found (or another tenant's)"},
    422: {"model": ErrorResponse, "description": "invalid input"},
}
router = APIRouter(prefix="/v1", responses=ERRORS)

UPS = ("auto", "+x", "-x", "+y", "-y", "+z", "-z")
SCAN_EXT = {".ply": "ply", ".obj": "obj", ".stl": "stl", ".npz": "npz", ".xyz": "xyz",
            ".pts": "pts", ".txt": "xyz", ".asc": "xyz", ".glb": "glb",
            ".zip": "zip"}  # fmt: skip


@lru_cache(maxsize=1)
def landmark_names() -> tuple[str, ...]:
    from core.template import load_template

    return tuple(sorted(load_template().landmarks))


# ----------------------------------------------------------------------------- helpers


def _encode_cursor(created_at: datetime, id_: str) -> str:
    raw = f"{aware(created_at).isoformat()}|{id_}".encode()  # type: ignore[union-attr]
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def _decode_cursor(cursor: str) -> tuple[datetime, str]:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        ts, id_ = raw.split("|", 1)
        return datetime.fromisoformat(ts), id_
    except Exception:
        raise ApiError("validation_error", "invalid cursor", field="cursor") from None


def _page(session: Session, model: Any, where: list[Any], limit: int, cursor: str | None):
    q = select(model).where(*where)
    if cursor:
        ts, id_ = _decode_cursor(cursor)
        q = q.where(or_(model.created_at < ts, and_(model.created_at == ts, model.id < id_)))
    rows = list(
        session.scalars(q.order_by(model.created_at.desc(), model.id.desc()).limit(limit + 1))
    )
    nxt = (
        _encode_cursor(rows[limit - 1].created_at, rows[limit - 1].id)
        if len(rows) > limit
        else None
    )
    return rows[:limit], nxt


def _scan_out(s: Scan) -> ScanOut:
    return ScanOut(
        id=s.id,
        filename=s.filename,
        format=s.format,
        size_bytes=s.size_bytes,
        n_vertices=s.n_vertices,
        n_faces=s.n_faces,
        units=s.units,
        up=s.up,
        marker_names=sorted(s.markers or {}),
        created_at=aware(s.created_at),  # type: ignore[arg-type]
    )


def _seconds(a: datetime | None, b: datetime | None) -> float | None:
    if a is None or b is None:
        return None
    return round((aware(b) - aware(a)).total_seconds(), 3)  # type: ignore[operator]


def _fit_out(f: Fit) -> FitOut:
    return FitOut(
        id=f.id,
        mode=f.mode or "full",  # type: ignore[arg-type]
        scan_id=f.scan_id,
        state=f.state,  # type: ignore[arg-type]
        options=f.options or {},
        progress=f.progress,  # type: ignore[arg-type]
        timings=Timings(
            created_at=aware(f.created_at),  # type: ignore[arg-type]
            started_at=aware(f.started_at),
            finished_at=aware(f.finished_at),
            queued_s=_seconds(f.created_at, f.started_at),
            run_s=_seconds(f.started_at, f.finished_at) if f.finished_at else None,
            fit_s=f.fit_seconds,
        ),
        error=f.error,  # type: ignore[arg-type]
        attempts=f.attempts,
        result_formats=(
            [*RESULT_FORMATS, *(["png"] if (f.report or {}).get("texture") else [])]
            if f.state == "succeeded"
            else []
        ),
        quality=(f.report or {}).get("quality") if f.state == "succeeded" else None,
        warnings=list((f.report or {}).get("warnings") or []) if f.state == "succeeded" else [],
        removed=dict((f.report or {}).get("removed") or {}) if f.state == "succeeded" else {},
    )


def _own(session: Session, model: Any, id_: str, tenant: str, what: str) -> Any:
    row = session.get(model, id_)
    if row is None or row.tenant_id != tenant:
        raise ApiError("not_found", f"no {what} with id {clip(id_)!r}", id=clip(id_))
    return row


def _validate_scan(form: Form, settings: Settings) -> dict[str, Any]:
    """Check the uploaded scan (and markers) before anything is stored; returns scan facts."""
    from core.io import detect_frame, inspect_mesh_header, read_markers, read_mesh

    scan = form.files.get("scan")
    if scan is None:
        raise ApiError("missing_field", "missing required field: scan (a file part)", field="scan")
    units = form.fields.get("units", "auto").strip().lower() or "auto"
    up = form.fields.get("up", "auto").strip().lower() or "auto"
    if units not in UNITS_OPTIONS:
        raise ApiError("validation_error", f"units must be one of {UNITS_OPTIONS}", field="units")
    if up not in UPS:
        raise ApiError("validation_error", f"up must be one of {UPS}", field="up")
    fmt = SCAN_EXT.get(Path(scan.filename).suffix.lower())
    head = inspect_mesh_header(
        scan.path, fmt, max_vertices=settings.max_vertices, max_faces=settings.max_faces,
        name=scan.filename,
    )  # fmt: skip
    markers = pts = None
    mfile = form.files.get("markers")
    if mfile is not None:
        mfmt = {".csv": "csv", ".json": "json"}.get(Path(mfile.filename).suffix.lower())
        pts = read_markers(mfile.path, mfmt, valid_names=landmark_names(), name=mfile.filename)
        markers = {k: [float(x) for x in v] for k, v in pts.items()}
    # small uploads are parsed whole (a ZIP bundle by what it inflates to)
    if max(scan.size, head.get("inflated_bytes", 0)) <= settings.full_validation_max_bytes:
        raw = read_mesh(
            scan.path, head["format"], max_vertices=settings.max_vertices,
            max_faces=settings.max_faces, name=scan.filename, sidecar_files=False,
        )  # fmt: skip
        detect_frame(raw.surface()[0], units=units, up=up, markers=pts)
    return {"head": head, "units": units, "up": up, "markers": markers}


# ----------------------------------------------------------------------------- scans

SCAN_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["scan"],
                    "properties": {
                        "scan": {"type": "string", "format": "binary",
                                 "description": "PLY, OBJ, GLB (an embedded base colour "
                                 "texture is read), ZIP (one OBJ with its MTL and PNG/JPEG "
                                 "textures), STL, NPZ or XYZ scan"},
                        "markers": {"type": "string", "format": "binary",
                                    "description": "CSV name,x,y,z or JSON {name: [x,y,z]}"},
                        "units": {"type": "string", "enum": list(UNITS_OPTIONS), "default": "auto"},
                        "up": {"type": "string", "enum": list(UPS), "default": "auto"},
                    },
                }
            }
        },
    }
}  # fmt: skip


@router.post(
    "/scans",
    status_code=201,
    response_model=ScanOut,
    openapi_extra=SCAN_BODY,
    responses={
        413: {"model": ErrorResponse, "description": "upload too large"},
        415: {"model": ErrorResponse, "description": "not multipart/form-data"},
    },
    tags=["scans"],
)
async def create_scan(
    request: Request, response: Response, tenant: TenantId, settings: SettingsDep, store: StoreDep
) -> ScanOut:
    """Upload a scan (multipart: ``scan`` file, optional ``markers`` file, ``units``, ``up``).

    The upload streams to disk and is validated (size, header, counts, marker names; small files
    are parsed whole) before it is accepted.
    """
    form = await parse_multipart(
        request, store, {"scan": settings.max_upload_bytes, "markers": settings.max_marker_bytes}
    )
    try:
        facts = await run_in_threadpool(_validate_scan, form, settings)
        out = await run_in_threadpool(_store_scan, form, facts, tenant, settings, store)
    finally:
        form.cleanup()
    response.headers["Location"] = f"/v1/scans/{out.id}"
    return out


def _store_scan(
    form: Form, facts: dict[str, Any], tenant: str, settings: Settings, store: BlobStore
) -> ScanOut:
    up = form.files["scan"]
    head = facts["head"]
    scan_id = new_id("scn")
    key = f"{tenant}/scans/{scan_id}/scan.{head['format']}"
    digest = sha256_file(up.path)
    store.commit_file(up.path, key)
    try:
        with session_scope(settings) as s:
            row = Scan(
                id=scan_id,
                tenant_id=tenant,
                filename=up.filename[:255],
                format=head["format"],
                size_bytes=up.size,
                n_vertices=int(head["n_vertices"]),
                n_faces=int(head["n_faces"]),
                units=facts["units"],
                up=facts["up"],
                markers=facts["markers"],
                blob_key=key,
            )
            s.add(row)
            s.flush()
            s.add(
                Blob(
                    key=key,
                    tenant_id=tenant,
                    scan_id=scan_id,
                    kind="scan",
                    content_type=up.content_type or "application/octet-stream",
                    size_bytes=up.size,
                    sha256=digest,
                )
            )
    except BaseException:
        store.delete_prefix(f"{tenant}/scans/{scan_id}")
        raise
    return _scan_out(row)


@router.get("/scans", response_model=ScanPage, tags=["scans"])
def list_scans(
    tenant: TenantId,
    session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    cursor: Cursor = None,
) -> ScanPage:
    """The caller's scans, newest first (``next_cursor`` pages on)."""
    rows, nxt = _page(session, Scan, [Scan.tenant_id == tenant], limit, cursor)
    return ScanPage(items=[_scan_out(r) for r in rows], next_cursor=nxt)


@router.get("/scans/{scan_id}", response_model=ScanOut, tags=["scans"])
def get_scan(scan_id: str, tenant: TenantId, session: SessionDep) -> ScanOut:
    """One scan's metadata."""
    return _scan_out(_own(session, Scan, scan_id, tenant, "scan"))


@router.delete("/scans/{scan_id}", status_code=204, tags=["scans"])
def delete_scan(
    scan_id: str, tenant: TenantId, session: SessionDep, store: StoreDep, settings: SettingsDep
) -> Response:
    """Delete a scan, its fits and all their blobs (scans are personal data)."""
    _own(session, Scan, scan_id, tenant, "scan")
    fit_ids = list(session.scalars(select(Fit.id).where(Fit.scan_id == scan_id)))
    session.execute(delete(Blob).where(or_(Blob.scan_id == scan_id, Blob.fit_id.in_(fit_ids))))
    session.execute(delete(Fit).where(Fit.scan_id == scan_id))
    session.execute(delete(Scan).where(Scan.id == scan_id))
    session.commit()
    store.delete_prefix(f"{tenant}/scans/{scan_id}")
    for fid in fit_ids:
        store.delete_prefix(f"{tenant}/fits/{fid}")
    scrub_deleted(settings)
    return Response(status_code=204)


# ----------------------------------------------------------------------------- fits


@router.post(
    "/fits",
    status_code=202,
    response_model=FitOut,
    dependencies=[Depends(require_json)],
    responses={
        415: {"model": ErrorResponse, "description": "not application/json"},
        429: {"model": ErrorResponse, "description": "too many active fits (Retry-After)"},
        503: {"model": ErrorResponse, "description": "queue full or unreachable (Retry-After)"},
    },
    tags=["fits"],
)
def create_fit(
    body: FitCreate,
    response: Response,
    tenant: TenantId,
    session: SessionDep,
    runner: RunnerDep,
    settings: SettingsDep,
    store: StoreDep,
) -> FitOut:
    """Start a fit job: ``202`` with the job and its ``Location``; poll ``GET /v1/fits/{id}``.

    ``mode``: ``full`` (scan + markers, the default), ``markerless`` (scan only; markers are
    ignored), ``markers_only`` (markers only; ``scan_id`` optional) or ``measurements`` (``sex``
    and tape ``measurements``; no scan). Inputs are validated before the job is accepted (a
    markers-only request's markers: known names, at least 3, not collinear, body-sized in the
    given units; a markerless scan: size and proportions of a standing body; measurements:
    known names, plausible values).
    """
    scan = None if body.scan_id is None else _own(session, Scan, body.scan_id, tenant, "scan")
    options = body.options.model_dump(exclude_none=True)
    markers = None
    if body.markers is not None and body.mode != "markerless":  # markerless ignores them
        markers = _read_inline_markers(body.markers)
    if isinstance(body, FullFit) and not (markers or scan.markers):
        raise ApiError("markers_required")
    if isinstance(body, MarkersOnlyFit):
        options.update(_check_markers_only(scan, markers, body))
    elif isinstance(body, MarkerlessFit):
        _check_markerless_scan(scan, settings, store)
    elif isinstance(body, MeasurementsFit):
        options = _check_measurements(body, options)
    _admit(session, tenant, settings)
    fit = Fit(
        id=new_id("fit"),
        tenant_id=tenant,
        scan_id=None if scan is None else scan.id,
        mode=body.mode,
        state="queued",
        options=options,
        markers=markers,
        enqueued_at=utcnow(),
    )
    session.add(fit)
    session.commit()  # the row is the source of truth: committed before it is enqueued
    try:
        runner.submit(fit.id)
    except Exception as e:
        # Not accepted: a 202 would promise a job that runs only when some worker's recovery
        # sweep finds the row (up to REQUEUE_AFTER_S later). The row goes; a message that did
        # reach the broker finds no row and is skipped by the worker.
        log.warning("enqueue of %s failed: %s: answered 503", fit.id, e)
        session.delete(fit)
        session.commit()
        raise ApiError("queue_unavailable", retry_after=5) from None
    response.headers["Location"] = f"/v1/fits/{fit.id}"
    return _fit_out(fit)


#: Retry-After (s) of a refused fit: about one fit's time, when a slot may be free again.
RETRY_AFTER_FIT_S = 10


def _admit(session: Session, tenant: str, settings: Settings) -> None:
    """Backpressure: at most ``tenant_max_active_fits`` queued + running fits per tenant (429),
    at most ``max_queued_fits`` queued fits in all (503); both with ``Retry-After``."""
    # PostgreSQL: the tenant's row lock serialises its admissions (no two requests both see
    # the last free slot); SQLite serialises writers itself.
    session.execute(select(Tenant.id).where(Tenant.id == tenant).with_for_update())
    limit = settings.tenant_max_active_fits
    active = session.scalar(
        select(func.count())
        .select_from(Fit)
        .where(Fit.tenant_id == tenant, Fit.state.in_(("queued", "running")))
    )
    if active >= limit:
        raise ApiError(
            "too_many_active_fits",
            f"{active} fits of this API key's tenant are queued or running (the limit is "
            f"{limit}): retry when one has finished (see GET /v1/fits?state=running)",
            retry_after=RETRY_AFTER_FIT_S,
            active=active,
            limit=limit,
        )
    queued = session.scalar(select(func.count()).select_from(Fit).where(Fit.state == "queued"))
    if queued >= settings.max_queued_fits:
        raise ApiError(
            "queue_full",
            f"{queued} fits are waiting for a worker (the limit is {settings.max_queued_fits}): "
            "retry later",
            retry_after=3 * RETRY_AFTER_FIT_S,
        )


def _read_inline_markers(given: dict[str, list[float]]) -> dict[str, list[float]]:
    from core.io import read_markers

    pts = read_markers(json.dumps(given).encode(), "json", valid_names=landmark_names())
    return {k: [float(x) for x in v] for k, v in pts.items()}


def _check_markers_only(
    scan: Scan | None, markers: dict[str, list[float]] | None, body: MarkersOnlyFit
) -> dict[str, Any]:
    """Validate a markers-only request; returns the options to store (the markers' frame)."""
    import numpy as np

    from core.errors import MarkerError
    from core.io import detect_frame
    from core.matching.markers_only import check_markers

    given = markers if markers is not None else (scan.markers if scan is not None else None)
    if not given:
        msg = "a markers-only fit needs markers: give them in the request" + (
            " or upload them with the scan" if scan is not None else ""
        )
        raise ApiError("markers_required", msg)
    if len(given) < 3:
        raise MarkerError(
            f"need at least 3 markers named after template landmarks; got {len(given)} "
            f"({', '.join(given)})",
            n_markers=len(given),
        )
    if scan is not None:  # in the scan's frame: converted with it by the worker
        return {}
    pts = {k: np.asarray(v, dtype=np.float64) for k, v in given.items()}
    frame = detect_frame(
        np.array(list(pts.values())), units=body.units or "m", up=body.up or "+y", markers=pts
    )
    check_markers({k: frame.to_canonical(v[None])[0] for k, v in pts.items()})
    return {"units": frame.units, "up": frame.up}


def _check_markerless_scan(scan: Scan, settings: Settings, store: BlobStore) -> None:
    """Refuse a scan whose size or proportions rule out a standing body (``not_a_body``) or
    whose frame cannot be told without markers (``ambiguous_units``) before a markerless fit.

    Cheap checks on the scan as the job will read it; files larger than
    ``full_validation_max_bytes`` are left to the job (which runs the same checks first), and
    so are ZIP bundles (what they inflate to is not stored; up to 20x their size).
    """
    from core.io import detect_frame, read_mesh
    from core.matching.body_check import check_body_shape

    if scan.size_bytes > settings.full_validation_max_bytes or scan.format == "zip":
        return
    with store.local_copy(scan.blob_key) as path:
        raw = read_mesh(
            path, scan.format, max_vertices=settings.max_vertices, max_faces=settings.max_faces,
            name=scan.filename, sidecar_files=False,
        )  # fmt: skip
    V, F = raw.surface()
    frame = detect_frame(V, units=scan.units, up=scan.up)
    how = {k: "as uploaded" if v != "auto" else "detected" for k, v in
           (("units", scan.units), ("up", scan.up))}  # fmt: skip
    check_body_shape(
        frame.to_canonical(V), F,
        frame=f"units {frame.units} ({how['units']}), up {frame.up} ({how['up']})",
    )  # fmt: skip


def _check_measurements(body: MeasurementsFit, options: dict[str, Any]) -> dict[str, Any]:
    """Validate a measurements request; returns the options to store (sex, measurements)."""
    from core.matching.from_measurements import check_measurements
    from core.shapespace import default_model

    values = check_measurements(body.sex, body.measurements, model=default_model())
    out = {k: v for k, v in options.items() if k == "calibrate"}  # schedules concern scans
    return {**out, "sex": body.sex, "measurements": values}


@router.get("/fits", response_model=FitPage, tags=["fits"])
def list_fits(
    tenant: TenantId,
    session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    cursor: Cursor = None,
    scan_id: str | None = None,
    state: Literal["queued", "running", "succeeded", "failed"] | None = None,
    mode: Literal["full", "markerless", "markers_only", "measurements"] | None = None,
) -> FitPage:
    """The caller's fits (with or without a scan), newest first; filter by ``scan_id``,
    ``state`` and ``mode``."""
    where = [Fit.tenant_id == tenant]
    if scan_id:
        where.append(Fit.scan_id == scan_id)
    if state:
        where.append(Fit.state == state)
    if mode:
        where.append(Fit.mode == mode)
    rows, nxt = _page(session, Fit, where, limit, cursor)
    return FitPage(items=[_fit_out(r) for r in rows], next_cursor=nxt)


@router.get("/fits/{fit_id}", response_model=FitOut, tags=["fits"])
def get_fit(fit_id: str, tenant: TenantId, session: SessionDep) -> FitOut:
    """A fit job: state, progress, timings, error."""
    return _fit_out(_own(session, Fit, fit_id, tenant, "fit"))


@router.delete("/fits/{fit_id}", status_code=204, tags=["fits"])
def delete_fit(
    fit_id: str, tenant: TenantId, session: SessionDep, store: StoreDep, settings: SettingsDep
) -> Response:
    """Delete one fit (of any mode) and its result blobs; its scan, if any, is kept.

    A markers-only fit without a scan is deleted only this way. A running fit is abandoned by
    its worker, which leaves no result behind.
    """
    _own(session, Fit, fit_id, tenant, "fit")
    session.execute(delete(Blob).where(Blob.fit_id == fit_id))
    session.execute(delete(Fit).where(Fit.id == fit_id))
    session.commit()
    store.delete_prefix(f"{tenant}/fits/{fit_id}")
    scrub_deleted(settings)
    return Response(status_code=204)


@router.get(
    "/fits/{fit_id}/result",
    response_class=FileResponse,
    responses={
        200: {
            "description": "the fitted body (template vertex order, metres, +Y up) or the report",
            "content": {t.split(";")[0]: {} for t in (*RESULT_FORMATS.values(), TEXTURE_FORMAT[1])},
        },
        409: {"model": ErrorResponse, "description": "the fit has not succeeded"},
    },
    tags=["fits"],
)
def get_fit_result(
    fit_id: str,
    tenant: TenantId,
    session: SessionDep,
    store: StoreDep,
    format: Literal["glb", "ply", "obj", "json", "png"] = "glb",
) -> Response:
    """Download a succeeded fit as GLB, PLY, OBJ or its JSON report; ``png``: the texture
    baked on the template UV layout (fits of coloured or textured scans only; their GLB
    carries it as its base colour texture)."""
    fit = _own(session, Fit, fit_id, tenant, "fit")
    if fit.state != "succeeded":
        raise ApiError("fit_not_ready", f"fit {fit_id} is {fit.state}", state=fit.state)
    if format == "png" and not (fit.report or {}).get("texture"):
        raise ApiError(
            "not_found", f"fit {fit_id} has no texture: its scan had no colours", format="png"
        )
    key = result_key(tenant, fit_id, format)
    size = store.size(key)
    if size is None:
        log.error("result %s of %s is missing from storage", key, fit_id)
        raise ApiError("not_found", f"the {format} result of fit {fit_id} is missing from storage")
    name = f"{fit_id}.{format}" if format != "json" else f"{fit_id}.report.json"
    media = dict([TEXTURE_FORMAT], **RESULT_FORMATS)[format].split(";")[0]
    path = store.local_path(key)
    if path is not None:
        return FileResponse(path, media_type=media, filename=name)
    headers = {"Content-Length": str(size), "Content-Disposition": f'attachment; filename="{name}"'}
    return StreamingResponse(store.iter_chunks(key), media_type=media, headers=headers)
