"""Routes under ``/v1/models``: list the shape models and synthesise bodies from them.

Synthesis is synchronous (a few milliseconds): no job, nothing stored. Bodies come back as GLB
(default) or, with ``Accept: application/json``, as vertices, faces and measurements (template
order, metres, +Y up).
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np
from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool

from service.deps import TenantId
from service.errors import ApiError
from service.schemas import ErrorResponse, ModelList, ModelOut, SynthesizedBody, SynthesizeRequest

router = APIRouter(
    prefix="/v1",
    responses={
        401: {"model": ErrorResponse, "description": "missing or invalid API key"},
        404: {"model": ErrorResponse, "description": "no such model"},
        422: {"model": ErrorResponse, "description": "invalid input or out of the model's range"},
    },
)

GLB = "model/gltf-binary"
SEXES = ("female", "male")
#: Response header of a GLB answer whose body the model extrapolated: the warnings as a JSON
#: array of strings (ASCII, non-ASCII characters escaped); absent when there are none.
WARNINGS_HEADER = "X-Bodyspace-Warnings"


def warnings_header(warnings: list[str]) -> dict[str, str]:
    """``{WARNINGS_HEADER: JSON array}``, or ``{}`` when there are no warnings."""
    return {WARNINGS_HEADER: json.dumps(warnings, ensure_ascii=True)} if warnings else {}


def _default() -> Any:
    from core.shapespace import default_model

    return default_model()


#: model name -> loader (each loaded once per process and cached).
MODELS: dict[str, Callable[[], Any]] = {"default": _default}


@cache
def get_model(name: str) -> Any:
    """The :class:`core.shapespace.ShapeModel` called ``name`` (404 when unknown)."""
    loader = MODELS.get(name)
    if loader is None:
        raise ApiError("not_found", f"no model {name!r}; models: {', '.join(MODELS)}", model=name)
    return loader()


@cache
def _template_faces() -> np.ndarray:
    from core.template import load_template

    return np.ascontiguousarray(load_template().F, dtype=np.int64)


@cache
def _glb_encoder() -> Any:
    from core.io.glb import FixedTopologyGlb
    from core.template import load_template

    return FixedTopologyGlb(_template_faces(), load_template().n_vertices)


def body_glb(V: np.ndarray) -> bytes:
    """GLB of a body in template order: ``write_glb(None, V, template F)`` with the index
    buffer, normal accumulation and JSON chunk precomputed once (normals summed in float32,
    within 1e-5 of write_glb's; see :mod:`core.io.glb`)."""
    return _glb_encoder().encode(V)


@cache
def model_info(name: str) -> ModelOut:
    d = get_model(name).describe()
    return ModelOut(
        name=name,
        sexes=[s for s in SEXES if s in d["spaces"]],
        spaces=d["spaces"],
        metadata=d["metadata"],
        provenance=d["provenance"],
    )


@router.get("/models", response_model=ModelList, tags=["models"])
def list_models(tenant: TenantId) -> ModelList:
    """The shape models: sexes, features with their supported ranges and units, PCA components
    and provenance."""
    return ModelList(items=[model_info(n) for n in MODELS])


@router.get("/models/{model}", response_model=ModelOut, tags=["models"])
def get_shape_model(model: str, tenant: TenantId) -> ModelOut:
    """One shape model (as in the list)."""
    get_model(model)
    return model_info(model)


def _features(body: SynthesizeRequest) -> dict[str, float]:
    feats = {k: v for k in ("height_m", "weight_kg", "age") if (v := getattr(body, k)) is not None}
    for k, v in (body.model_extra or {}).items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ApiError(
                "validation_error", f"{k}: must be a finite number (metres), got {v!r}", field=k
            )
        feats[k] = float(v)
    return feats


def _wants_json(request: Request) -> bool:
    accept = request.headers.get("accept", "").lower()
    return "application/json" in accept and GLB not in accept


@router.post(
    "/models/{model}/synthesize",
    response_class=Response,
    responses={
        200: {
            "description": "the body: GLB (default) or, with `Accept: application/json`, "
            "vertices, faces and measurements (template order, metres, +Y up)",
            "model": SynthesizedBody,
            "content": {GLB: {"schema": {"type": "string", "format": "binary"}}},
        },
    },
    tags=["models"],
)
async def synthesize(
    model: str, body: SynthesizeRequest, request: Request, tenant: TenantId
) -> Response:
    """Synthesise a body from ``{sex, height_m?, weight_kg?, age?, <measurements>?}``, from
    ``{sex, pca}`` or from ``{sex, seed}`` (synchronous). Values outside the model's accepted
    ranges answer 422 ``out_of_range`` naming the range (see ``GET /v1/models``: ``range``);
    values beyond its ``training_range`` (or an unusual combination) give an extrapolated
    body with warnings: the ``X-Bodyspace-Warnings`` header (a JSON array of strings) of a
    GLB answer, ``warnings`` in a JSON one."""
    # The GLB answer costs ~2 ms of CPU: it runs on the event loop, without a thread hop (less
    # CPU per request and a lower p50 at 32 concurrent clients than the threadpool:
    # bench/synthesis_load.py). Loading a model (first use) and the JSON answer (measurements
    # and a 1.4 MB JSON text, ~150 ms) run in a worker thread so they never stall the loop.
    if model not in _warm:
        await run_in_threadpool(_warm_up, model)
    if _wants_json(request):
        return await run_in_threadpool(_synthesize_json, model, body)
    V, warnings = synthesize_body(get_model(model), body)
    # the 483 kB buffer is sent as it is (no copy into bytes)
    return Response(
        memoryview(_glb_encoder().encode_buffer(V)),
        media_type=GLB,
        headers=warnings_header(warnings),
    )


_warm: set[str] = set()
_warm_lock = threading.Lock()


def _warm_up(model: str) -> None:
    """Load ``model`` and the GLB encoder once per process (404 for an unknown model); the
    first burst of concurrent requests waits for one load instead of loading in every thread."""
    with _warm_lock:
        get_model(model)
        _glb_encoder()
        _warm.add(model)


def _synthesize_json(model: str, body: SynthesizeRequest) -> Response:
    from core.measure import measure

    m = get_model(model)
    V, warnings = synthesize_body(m, body)
    density = m.space(body.sex).density
    meas = {
        k: (float(v) if math.isfinite(v) else None) for k, v in measure(V, density=density).items()
    }
    out = {
        "vertices": V.tolist(),
        "faces": _template_faces().tolist(),
        "measurements": meas,
        "warnings": warnings,
    }
    return Response(json.dumps(out, separators=(",", ":")), media_type="application/json")


def synthesize_body(m: Any, body: SynthesizeRequest) -> tuple[np.ndarray, list[str]]:
    """(13380, 3) body of ``m`` for a synthesis request (features, ``pca`` or ``seed``), after
    the checks the request needs beyond its schema (422 ``validation_error`` /
    ``out_of_range``), and the model's warnings where it extrapolates (empty inside its
    training range). Shared by ``POST /v1/models/{model}/synthesize`` (route and
    :mod:`service.fastpath`) and ``POST /v1/bodies``."""
    feats = _features(body)
    if body.pca is not None:
        if feats or body.seed is not None:
            raise ApiError(
                "validation_error", "give either pca weights, or features and/or a seed",
                field="pca",
            )  # fmt: skip
        k = m.space(body.sex).pca.k
        if len(body.pca) > k:
            raise ApiError(
                "validation_error", f"pca has {len(body.pca)} weights; this model has {k} "
                f"components for {body.sex}", field="pca", components=k,
            )  # fmt: skip
        if not all(math.isfinite(w) for w in body.pca):
            raise ApiError("validation_error", "pca weights must be finite numbers", field="pca")
        return m.synthesize(body.sex, pca=np.asarray(body.pca, dtype=np.float64)), []
    V = m.synthesize(body.sex, feats or None, seed=body.seed)
    return V, m.range_warnings(body.sex, feats)
