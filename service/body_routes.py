"""Routes under ``/v1/bodies``: stored bodies — synthesised from a shape model, taken from a
succeeded fit, or edited from another body — their meshes and measurements.

A body's vertices (template order, metres, +Y up) are stored at full precision as a float64
``.npy`` blob; its row (``service.models.Body``) holds the model, sex, how it was made and the
model's features of it. ``GET /v1/bodies/{id}`` and ``POST /v1/bodies/{id}/edit`` answer with
the mesh as GLB, or with ``Accept: application/json`` as metadata + vertices + faces (like
``POST /v1/models/{model}/synthesize``). A body made from a fit, and every body edited from it,
is derived personal data: it is deleted with its fit, hence with its scan (see ``Body``).
"""

from __future__ import annotations

import json
import logging
import math
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, Query, Request, Response
from sqlalchemy import delete
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from service.blobs import BlobStore
from service.db import aware
from service.deps import Cursor, SessionDep, SettingsDep, StoreDep, TenantId, require_json
from service.errors import ApiError, clip
from service.models import Blob, Body, Fit, new_id
from service.privacy import scrub_deleted
from service.routes import _own, _page
from service.schemas import (
    BodyCreate,
    BodyEdit,
    BodyMeasurements,
    BodyMesh,
    BodyOut,
    BodyPage,
    BodyPose,
    BodySource,
    ErrorResponse,
    FitBody,
    MeasurementValue,
    MorphBody,
    MorphRequest,
)
from service.shape_routes import (
    GLB,
    MODELS,
    _template_faces,
    _wants_json,
    body_glb,
    get_model,
    synthesize_body,
    warnings_header,
)

log = logging.getLogger("bodyspace.service")

router = APIRouter(
    prefix="/v1",
    responses={
        401: {"model": ErrorResponse, "description": "missing or invalid API key"},
        404: {"model": ErrorResponse, "description": "not found (or another tenant's)"},
        422: {"model": ErrorResponse, "description": "invalid input or out of the model's range"},
    },
)

BLOB_KIND = "body.npy"
MESH_RESPONSE: dict[str, Any] = {
    "description": "the body: GLB (default) or, with `Accept: application/json`, its metadata, "
    "vertices and faces (template order, metres, +Y up)",
    "model": BodyMesh,
    "content": {GLB: {"schema": {"type": "string", "format": "binary"}}},
}


# ----------------------------------------------------------------------------- helpers


def _warnings(b: Body) -> list[str]:
    """The model's extrapolation warnings for a stored body (see ``BodyOut.warnings``)."""
    m = get_model(b.model)
    names = m.space(b.sex).features.names
    if b.source == "model":
        src = b.params or {}
    else:
        src = {k: v for k, v in (b.features or {}).items() if k in ("height_m", "weight_kg")}
    feats = {k: float(v) for k, v in src.items() if k in names and isinstance(v, int | float)}
    return m.range_warnings(b.sex, feats)


def _body_out(b: Body) -> BodyOut:
    return BodyOut(
        id=b.id,
        model=b.model,
        sex=b.sex,  # type: ignore[arg-type]
        source=b.source,  # type: ignore[arg-type]
        fit_id=b.fit_id,
        derived_from=b.derived_from,
        params=b.params or {},
        features=b.features or {},
        warnings=_warnings(b),
        created_at=aware(b.created_at),  # type: ignore[arg-type]
    )


def _blob_prefix(tenant: str, body_id: str, fit_id: str | None) -> str:
    """Bodies from a fit live under the fit's prefix, so that deleting the fit (or its scan)
    removes them with its results."""
    if fit_id is not None:
        return f"{tenant}/fits/{fit_id}/bodies/{body_id}"
    return f"{tenant}/bodies/{body_id}"


def _features_of(model: str, sex: str, V: np.ndarray) -> dict[str, float]:
    f = get_model(model).features_of(sex, V)
    return {k: float(v) for k, v in f.items() if math.isfinite(v)}


def _store_body(
    session: Session,
    store: BlobStore,
    *,
    tenant: str,
    V: np.ndarray,
    model: str,
    sex: str,
    source: str,
    params: dict[str, Any],
    fit_id: str | None = None,
    derived_from: str | None = None,
    features: dict[str, float] | None = None,
) -> Body:
    """Write the vertices blob, then the rows (one transaction); the blob goes if the rows fail.
    ``features`` default to the model's features of ``V``."""
    from service.blobs import sha256_file

    body_id = new_id("bdy")
    prefix = _blob_prefix(tenant, body_id, fit_id)
    key = f"{prefix}/vertices.npy"
    if features is None:
        features = _features_of(model, sex, V)
    tmp = store.temp_file(".npy")
    try:
        with open(tmp, "wb") as f:
            np.save(f, np.ascontiguousarray(V, dtype=np.float64), allow_pickle=False)
        size, digest = tmp.stat().st_size, sha256_file(tmp)
        store.commit_file(tmp, key)
    finally:
        tmp.unlink(missing_ok=True)
    row = Body(
        id=body_id,
        tenant_id=tenant,
        model=model,
        sex=sex,
        source=source,
        fit_id=fit_id,
        derived_from=derived_from,
        params=params,
        features=features,
        blob_key=key,
    )
    try:
        session.add(row)
        session.flush()
        session.add(
            Blob(
                key=key,
                tenant_id=tenant,
                fit_id=fit_id,
                kind=BLOB_KIND,
                content_type="application/octet-stream",
                size_bytes=size,
                sha256=digest,
            )
        )
        session.commit()
    except IntegrityError:  # the fit (or source body) was deleted meanwhile
        session.rollback()
        store.delete_prefix(prefix)
        raise ApiError("not_found", "the fit or body it was made from has been deleted") from None
    except BaseException:
        session.rollback()
        store.delete_prefix(prefix)
        raise
    return row


def _load_vertices(store: BlobStore, key: str) -> np.ndarray:
    try:
        with store.local_copy(key) as p:
            return np.load(p, allow_pickle=False)
    except FileNotFoundError:
        log.error("body blob %s is missing from storage", key)
        raise ApiError("not_found", "the body's vertices are missing from storage") from None


def _fit_vertices(store: BlobStore, tenant: str, fit: Fit) -> np.ndarray:
    """The fitted body of a succeeded fit, at full precision (its PLY result holds doubles)."""
    from core.io import read_mesh
    from core.template import load_template
    from service.fit_job import result_key

    if fit.state != "succeeded":
        raise ApiError("fit_not_ready", f"fit {fit.id} is {fit.state}", state=fit.state)
    key = result_key(tenant, fit.id, "ply")
    try:
        with store.local_copy(key) as p:
            V = read_mesh(p, "ply").V
    except FileNotFoundError:
        log.error("result %s of %s is missing from storage", key, fit.id)
        raise ApiError("not_found", f"the result of fit {fit.id} is missing from storage") from None
    n = load_template().n_vertices
    if V.shape != (n, 3):
        raise ApiError("validation_error", f"fit {fit.id} has {len(V)} vertices, expected {n}")
    return V


def _body_colors(store: BlobStore, b: Body) -> np.ndarray | None:
    """(13380, 3) uint8 colours of a body from a fit of a coloured scan (its edits and poses
    too: same vertices; a stored blend of two coloured bodies: they share that fit, so the
    blend of their colours is the fit's), read from the fit's PLY result; None for every other
    body (a blend with an uncoloured body included)."""
    from core.io import read_mesh
    from service.fit_job import result_key

    if b.fit_id is None or b.source not in ("fit", "edit", "pose", "morph"):
        return None
    if b.source == "morph" and (b.params or {}).get("colors") != "blended":
        return None
    try:
        with store.local_copy(result_key(b.tenant_id, b.fit_id, "ply")) as p:
            C = read_mesh(p, "ply").colors
    except FileNotFoundError:
        return None
    return C if C is not None and len(C) == int(_template_faces().max()) + 1 else None


def _fit_texture(store: BlobStore, session: Session, tenant: str, fit_id: str) -> bytes:
    """The PNG texture baked for the caller's fit ``fit_id`` (template UV layout)."""
    from service.fit_job import result_key

    fit = _own(session, Fit, fit_id, tenant, "fit")
    if fit.state != "succeeded":
        raise ApiError("fit_not_ready", f"fit {fit.id} is {fit.state}", state=fit.state)
    if not (fit.report or {}).get("texture"):
        raise ApiError("not_found", f"fit {fit.id} has no texture: its scan had no colours")
    key = result_key(tenant, fit.id, "png")
    try:
        with store.local_copy(key) as p:
            png = p.read_bytes()
    except FileNotFoundError:
        log.error("result %s of %s is missing from storage", key, fit.id)
        raise ApiError(
            "not_found", f"the texture of fit {fit.id} is missing from storage"
        ) from None
    return png


def _mesh_response(
    request: Request,
    b: Body,
    V: np.ndarray,
    status: int = 200,
    colors: np.ndarray | None = None,
    **headers: str,
) -> Response:
    F = _template_faces()
    meta = _body_out(b)
    if _wants_json(request):
        out = meta.model_dump(mode="json")
        out["vertices"] = V.tolist()
        out["faces"] = F.tolist()
        if colors is not None:
            out["colors"] = colors.tolist()
        return Response(
            json.dumps(out, separators=(",", ":")),
            status_code=status,
            media_type="application/json",
            headers=headers,
        )
    if colors is not None:
        from core.io import write_glb

        data = write_glb(None, V, F, colors=colors)
    else:
        data = body_glb(V)
    return Response(
        data,
        status_code=status,
        media_type=GLB,
        headers={**headers, **warnings_header(meta.warnings)},
    )


# ----------------------------------------------------------------------------- routes


@router.post(
    "/bodies",
    status_code=201,
    response_model=BodyOut,
    dependencies=[Depends(require_json)],
    responses={
        409: {"model": ErrorResponse, "description": "the fit has not succeeded"},
        415: {"model": ErrorResponse, "description": "not application/json"},
    },
    tags=["bodies"],
)
def create_body(
    body: BodyCreate, response: Response, tenant: TenantId, session: SessionDep, store: StoreDep
) -> BodyOut:
    """Store a body synthesised from a shape model (``{model?, sex, height_m?, weight_kg?, age?,
    <measurement>?}``, ``{model?, sex, pca}`` or ``{model?, sex, seed}``, as in
    ``POST /v1/models/{model}/synthesize``) or the fitted body of a succeeded fit
    (``{fit_id, sex}``; a scan carries no sex, so it is required): ``201`` + ``Location``."""
    if body.model not in MODELS:
        raise ApiError(
            "validation_error",
            f"no model {body.model!r}; models: {', '.join(MODELS)}",
            field="model",
        )
    if isinstance(body, MorphBody):
        row = _create_morph(body, tenant, session, store)
    elif isinstance(body, FitBody):
        m = get_model(body.model)
        m.space(body.sex)  # the model has this sex (else out_of_range)
        fit = _own(session, Fit, body.fit_id, tenant, "fit")
        row = _store_body(
            session, store, tenant=tenant, V=_fit_vertices(store, tenant, fit), model=body.model,
            sex=body.sex, source="fit", params={"fit_id": fit.id}, fit_id=fit.id,
        )  # fmt: skip
    else:
        V, _ = synthesize_body(get_model(body.model), body)  # its warnings: BodyOut.warnings
        params = body.model_dump(exclude={"model", "sex"}, exclude_none=True)
        row = _store_body(
            session, store, tenant=tenant, V=V, model=body.model, sex=body.sex,
            source="model", params=params,
        )  # fmt: skip
    response.headers["Location"] = f"/v1/bodies/{row.id}"
    return _body_out(row)


def _create_morph(body: MorphBody, tenant: str, session: Session, store: BlobStore) -> Body:
    """Store ``(1 - t) from + t to``; model and sex of the nearer body (``sex`` may override);
    coloured (the blend of the two bodies' colours) when both are."""
    from core.transfer import morph

    spec = body.morph
    a = _own(session, Body, spec.from_, tenant, "body")
    b = _own(session, Body, spec.to, tenant, "body")
    fits = {f for f in (a.fit_id, b.fit_id) if f is not None}
    if len(fits) > 1:
        raise ApiError(
            "validation_error",
            "the two bodies come from different fits: a stored blend could not be deleted with "
            "both scans; send them to POST /v1/morphs instead",
            field="morph",
        )
    near = a if spec.t < 0.5 else b
    sex = body.sex or near.sex
    get_model(near.model).space(sex)  # the model has this sex (else out_of_range)
    V = morph(_load_vertices(store, a.blob_key), _load_vertices(store, b.blob_key), spec.t)
    params: dict[str, Any] = {"morph": {"from": a.id, "to": b.id, "t": spec.t}}
    if _body_colors(store, a) is not None and _body_colors(store, b) is not None:
        params["colors"] = "blended"  # one fit's colours (else 422 above): their blend is them
    return _store_body(
        session, store, tenant=tenant, V=V, model=near.model, sex=sex, source="morph",
        params=params, fit_id=next(iter(fits), None), derived_from=a.id,
    )  # fmt: skip


@router.post(
    "/morphs",
    response_class=Response,
    dependencies=[Depends(require_json)],
    responses={
        200: {
            "description": "GLB: the first body as the mesh, one morph target (POSITION and "
            "NORMAL deltas) per other body, named by body id in `mesh.extras.targetNames`",
            "content": {GLB: {"schema": {"type": "string", "format": "binary"}}},
        },
        415: {"model": ErrorResponse, "description": "not application/json"},
    },
    tags=["bodies"],
)
def create_morph(
    req: MorphRequest, tenant: TenantId, session: SessionDep, store: StoreDep
) -> Response:
    """2-16 of your bodies as one GLB with morph targets: any glTF viewer slides between
    them (target weight 1 = that body); ``COLOR_0``: the first body's colours, if it has
    them."""
    from core.transfer import morph_glb

    if len(set(req.bodies)) != len(req.bodies):
        raise ApiError("validation_error", "bodies: each body at most once", field="bodies")
    rows = [_own(session, Body, i, tenant, "body") for i in req.bodies]
    Vs = [_load_vertices(store, r.blob_key) for r in rows]
    colors = _body_colors(store, rows[0])
    data = morph_glb(Vs, names=[r.id for r in rows], F=_template_faces(), colors=colors)
    return Response(data, media_type=GLB)


@router.get("/bodies", response_model=BodyPage, tags=["bodies"])
def list_bodies(
    tenant: TenantId,
    session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    cursor: Cursor = None,
    fit_id: str | None = None,
    source: BodySource | None = None,
) -> BodyPage:
    """The caller's bodies, newest first (``next_cursor`` pages on); filter by ``fit_id`` and
    ``source``."""
    where = [Body.tenant_id == tenant]
    if fit_id:
        where.append(Body.fit_id == fit_id)
    if source:
        where.append(Body.source == source)
    rows, nxt = _page(session, Body, where, limit, cursor)
    return BodyPage(items=[_body_out(r) for r in rows], next_cursor=nxt)


@router.get(
    "/bodies/{body_id}", response_class=Response, responses={200: MESH_RESPONSE}, tags=["bodies"]
)
def get_body(
    body_id: str,
    request: Request,
    tenant: TenantId,
    session: SessionDep,
    store: StoreDep,
    rig: Annotated[
        bool,
        Query(
            description="a skinned GLB: the standard rig's 163 joints placed on this body, "
            "inverse bind matrices, 4 skin weights per vertex (always GLB)"
        ),
    ] = False,
    texture_from: Annotated[
        str | None,
        Query(
            max_length=64,
            description="a fit of yours whose scan had colours or a texture: this body as a "
            "textured GLB wearing that fit's texture (every body shares the template UV layout; "
            "always GLB; with rig=true skinned too)",
        ),
    ] = None,
) -> Response:
    """A body's mesh: GLB, or with ``Accept: application/json`` its metadata, vertices and
    faces; ``?rig=true``: a skinned GLB that poses in any glTF viewer (a joint node's rotation
    is the rig's local rotation: the bind pose has none); ``?texture_from=FIT``: a textured GLB
    of this body wearing the fit's baked texture (rigged too with ``rig=true``)."""
    b = _own(session, Body, body_id, tenant, "body")
    V = _load_vertices(store, b.blob_key)
    png = None if texture_from is None else _fit_texture(store, session, tenant, texture_from)
    if png is not None and not rig:
        from core.transfer.texture import textured_glb

        return Response(textured_glb(None, V, png), media_type=GLB)
    if rig:
        from core.transfer.rig import rig_glb

        if b.source == "pose":
            raise ApiError(
                "validation_error",
                "this body is posed; rig the body it was posed from (derived_from)",
                field="rig",
            )
        colors = None if png is not None else _body_colors(store, b)
        return Response(rig_glb(V, colors=colors, texture=png), media_type=GLB)
    return _mesh_response(request, b, V, colors=_body_colors(store, b))


@router.get("/bodies/{body_id}/measurements", response_model=BodyMeasurements, tags=["bodies"])
def get_body_measurements(
    body_id: str, tenant: TenantId, session: SessionDep, store: StoreDep
) -> BodyMeasurements:
    """The body's ANSUR II measurements (ISO 7250-1 definitions, ``core.measure``): metres, and
    ``weightkg`` = volume x the model's calibrated density for the body's sex."""
    from core.measure import MEASUREMENTS, measure

    b = _own(session, Body, body_id, tenant, "body")
    V = _load_vertices(store, b.blob_key)
    density = float(get_model(b.model).space(b.sex).density)
    values = measure(V, density=density)
    out = {
        k: MeasurementValue(
            value=float(v) if math.isfinite(v) else None,
            unit=MEASUREMENTS[k].unit if k in MEASUREMENTS else "m",
        )
        for k, v in values.items()
    }
    return BodyMeasurements(body_id=b.id, sex=b.sex, density_kg_m3=density, measurements=out)  # type: ignore[arg-type]


def _edit_delta(m: Any, sex: str, V: np.ndarray, edit: BodyEdit) -> dict[str, float]:
    """``delta`` plus the changes ``target`` asks for; unknown names and resulting values outside
    the model's ranges are 422 ``out_of_range`` (the core's errors)."""
    from core.shapespace import OutOfRangeError

    space = m.space(sex)
    names = space.features.names
    both = sorted(set(edit.delta) & set(edit.target))
    if both:
        raise ApiError(
            "validation_error", f"{', '.join(both)}: give either a delta or a target", field=both[0]
        )
    if not edit.delta and not edit.target:
        raise ApiError(
            "validation_error", "nothing to edit: give delta and/or target", field="delta"
        )
    for name in [*edit.delta, *edit.target]:
        if name not in names:
            raise OutOfRangeError(
                f"unknown feature {name!r}; this model edits {', '.join(names)}",
                feature=name,
                accepted=list(names),
            )
    now = m.features_of(sex, V)
    delta = {k: float(v) for k, v in edit.delta.items()}
    delta.update({k: float(v) - now[k] for k, v in edit.target.items()})
    for k, dv in delta.items():
        if k not in ("height_m", "weight_kg"):  # those two the core checks itself
            space.features.check_value(k, now[k] + dv)
    return delta


@router.post(
    "/bodies/{body_id}/edit",
    status_code=201,
    response_class=Response,
    dependencies=[Depends(require_json)],
    responses={
        201: MESH_RESPONSE,
        415: {"model": ErrorResponse, "description": "not application/json"},
    },
    tags=["bodies"],
)
def edit_body(
    body_id: str,
    edit: BodyEdit,
    request: Request,
    tenant: TenantId,
    session: SessionDep,
    store: StoreDep,
) -> Response:
    """Edit a body's features (``{"delta": {"weight_kg": 10}}``, ``{"target": {"height_m":
    1.8}}``): the individual residual is kept, face and hands stay in place (for a height change
    they keep their shape and shift with the body) unless ``keep`` says otherwise. The result
    is a new stored body (``201``, ``Location``, ``derived_from``), answered as GLB or, with
    ``Accept: application/json``, metadata + vertices + faces. Results outside the model's
    ranges are 422 ``out_of_range``."""
    from core.template import load_template

    src = _own(session, Body, body_id, tenant, "body")
    if src.source == "pose":
        raise ApiError(
            "validation_error",
            "a posed body cannot be edited (the shape model is in the rest pose): edit the body "
            "it was posed from (derived_from), then pose the result",
            field="body_id",
        )
    parts = load_template().part_names
    keep = (
        tuple(dict.fromkeys(edit.keep)) if edit.keep is not None else ("head", "hand_L", "hand_R")
    )
    bad = [clip(p) for p in keep if p not in parts]
    if bad:
        raise ApiError(
            "validation_error",
            f"keep: unknown part(s) {', '.join(map(repr, bad))}; parts: {', '.join(parts)}",
            field="keep",
            accepted=list(parts),
        )
    m = get_model(src.model)
    V = _load_vertices(store, src.blob_key)
    delta = _edit_delta(m, src.sex, V, edit)
    V2 = m.edit(src.sex, V, delta, keep=keep)
    params = {"delta": delta, "keep": list(keep)}
    if edit.target:
        params["target"] = dict(edit.target)
    row = _store_body(
        session, store, tenant=tenant, V=V2, model=src.model, sex=src.sex, source="edit",
        params=params, fit_id=src.fit_id, derived_from=src.id,
    )  # fmt: skip
    return _mesh_response(
        request, row, V2, 201, colors=_body_colors(store, row), Location=f"/v1/bodies/{row.id}"
    )


@router.post(
    "/bodies/{body_id}/pose",
    status_code=201,
    response_class=Response,
    dependencies=[Depends(require_json)],
    responses={
        201: MESH_RESPONSE,
        415: {"model": ErrorResponse, "description": "not application/json"},
    },
    tags=["bodies"],
)
def create_posed_body(
    body_id: str,
    req: BodyPose,
    request: Request,
    tenant: TenantId,
    session: SessionDep,
    store: StoreDep,
) -> Response:
    """Pose a body (``{"posture": "seated"}`` and/or ``{"rotations": {bone: [x, y, z]}}``) by
    linear blend skinning with the standard rig on the body's own joints and the skin of its
    rigged GLB (what a viewer shows), floor at y = 0. ``seated`` and ``driving`` rest on a flat
    seat (``seat_contact``, default on for them: the tissue under the buttocks compressed, its
    underside flattened on the seat; ``false`` for plain skinning). The result is a new stored
    body (``201``, ``Location``, ``source`` ``pose``, ``derived_from``; its features are those of
    the rest body), answered as GLB or, with ``Accept: application/json``, metadata + vertices +
    faces."""
    from core.transfer.rig import pose, posture, rotations_from_vectors
    from core.transfer.seat import SEATED_POSTURES

    src = _own(session, Body, body_id, tenant, "body")
    if src.source == "pose":
        raise ApiError(
            "validation_error",
            "this body is already posed; pose the body it was posed from (derived_from)",
            field="body_id",
        )
    if req.posture is None and not req.rotations:
        raise ApiError("validation_error", "give a posture and/or rotations", field="posture")
    try:
        rot = posture(req.posture) if req.posture else {}
        rot.update(rotations_from_vectors(req.rotations))
    except ValueError as e:
        raise ApiError("validation_error", str(e), field="rotations") from None
    contact = req.seat_contact
    if contact is None:
        contact = req.posture in SEATED_POSTURES
    try:
        V = pose(_load_vertices(store, src.blob_key), rot, seat_contact=contact)
    except ValueError as e:  # seat contact in a posture without a seat
        raise ApiError("validation_error", str(e), field="seat_contact") from None
    params: dict[str, Any] = {
        "posture": req.posture, "rotations": req.rotations, "seat_contact": contact,
    }  # fmt: skip
    row = _store_body(
        session, store, tenant=tenant, V=V, model=src.model, sex=src.sex, source="pose",
        params=params, fit_id=src.fit_id, derived_from=src.id, features=src.features or {},
    )  # fmt: skip
    return _mesh_response(
        request, row, V, 201, colors=_body_colors(store, row), Location=f"/v1/bodies/{row.id}"
    )


@router.delete("/bodies/{body_id}", status_code=204, tags=["bodies"])
def delete_body(
    body_id: str, tenant: TenantId, session: SessionDep, store: StoreDep, settings: SettingsDep
) -> Response:
    """Delete a body and its blob (bodies edited from it are kept; their ``derived_from``
    becomes null)."""
    b = _own(session, Body, body_id, tenant, "body")
    prefix = b.blob_key.rsplit("/", 1)[0]
    session.execute(delete(Blob).where(Blob.key == b.blob_key))
    session.execute(delete(Body).where(Body.id == b.id))
    session.commit()
    store.delete_prefix(prefix)
    scrub_deleted(settings)
    return Response(status_code=204)
