"""The one error table: every error the API returns, and how ``core`` exceptions map to it.

Every error response has the shape ``{"error": {"code": str, "message": str, "details": {}}}``.
``core`` raises domain errors (``core.errors``) that carry their own stable ``code``; this module
decides their HTTP status. Service-side errors are raised as :class:`ApiError` with a code from
:data:`API_ERRORS`.
"""

from __future__ import annotations

import logging
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from core.errors import (
    BodyspaceError,
    FitError,
    InputFormatError,
    MarkerError,
    MeasurementError,
    NotABodyError,
    UnitsError,
)
from service.schemas import UNION_TAGS

log = logging.getLogger("bodyspace.service")

#: core exception class -> HTTP status (the code comes from the exception's ``code``).
CORE_ERRORS: dict[type[BodyspaceError], int] = {
    InputFormatError: 422,
    UnitsError: 422,
    MarkerError: 422,
    FitError: 422,
    NotABodyError: 422,  # not_a_body: a markerless scan that cannot be a standing body
    MeasurementError: 422,  # invalid_measurements: unknown names, non-numbers, wrong units
    BodyspaceError: 422,
}

#: service error code -> (HTTP status, default message).
API_ERRORS: dict[str, tuple[int, str]] = {
    "missing_api_key": (401, "send an API key: 'Authorization: Bearer KEY' or 'X-API-Key: KEY'"),
    "invalid_api_key": (401, "the API key is not valid"),
    "not_found": (404, "not found"),
    "method_not_allowed": (405, "method not allowed"),
    "fit_not_ready": (409, "the fit has not succeeded (yet): see its state"),
    "upload_too_large": (413, "the upload is larger than the limit"),
    "body_too_large": (413, "the JSON body is larger than the limit (BODYSPACE_MAX_JSON_BYTES)"),
    "too_many_parts": (413, "the multipart body has too many parts"),
    "unsupported_media_type": (415, "unsupported content type"),
    "missing_field": (422, "a required field is missing"),
    "markers_required": (422, "markers are required: upload them with the scan or the fit"),
    "validation_error": (422, "the request is not valid"),
    "bad_request": (400, "bad request"),
    "not_ready": (503, "a dependency is not reachable"),
    "too_many_active_fits": (429, "too many fits queued or running for this tenant"),
    "queue_full": (503, "the fit queue is full: retry later"),
    "queue_unavailable": (503, "the job queue cannot take the fit now: nothing was stored, retry"),
    "internal_error": (500, "internal error"),
}


ECHO_CHARS = 60  # characters of user input quoted in a message


def clip(value: object, n: int = ECHO_CHARS) -> str:
    """At most ``n`` characters of user input for an error message (``…`` marks a cut)."""
    s = str(value)
    return s if len(s) <= n else s[: n - 1] + "…"


#: codes of failed fits made by the job runner itself (not by ``core``) -> default message.
JOB_ERRORS: dict[str, str] = {
    "time_limit_exceeded": "the fit exceeded the time limit",
    "too_many_attempts": "the job was started too many times without finishing",
    "internal_error": "internal error",
}


def job_error(code: str, message: str | None = None) -> dict[str, Any]:
    """The stored error of a failed fit, for a code of :data:`JOB_ERRORS`."""
    return {"code": code, "message": message or JOB_ERRORS[code], "details": {}}


class ApiError(Exception):
    """An error answered with status and code from :data:`API_ERRORS`."""

    def __init__(
        self,
        code: str,
        message: str | None = None,
        *,
        retry_after: int | None = None,
        **details: Any,
    ) -> None:
        status, default = API_ERRORS[code]
        super().__init__(message or default)
        self.status = status
        self.code = code
        self.message = message or default
        self.details = details
        #: seconds, sent as ``Retry-After`` (429 / 503 answers)
        self.retry_after = retry_after


def error_body(code: str, message: str, details: dict[str, Any] | None = None) -> dict[str, Any]:
    """The one JSON error shape."""
    return {"error": {"code": code, "message": message, "details": details or {}}}


def core_error_status(exc: BodyspaceError) -> int:
    """HTTP status of a core domain error (nearest class in :data:`CORE_ERRORS`)."""
    for cls in type(exc).__mro__:
        if cls in CORE_ERRORS:
            return CORE_ERRORS[cls]
    return 422


def describe(exc: BaseException) -> dict[str, Any]:
    """``{"code", "message", "details"}`` for any exception (stored on failed fits)."""
    if isinstance(exc, ApiError):
        return {"code": exc.code, "message": exc.message, "details": _jsonable(exc.details)}
    if isinstance(exc, BodyspaceError):
        return {"code": exc.code, "message": exc.message, "details": _jsonable(exc.details)}
    # internal errors may carry paths or internal ids: the type only (the log has the rest)
    return job_error(
        "internal_error", f"internal error ({type(exc).__name__}); the server log has the details"
    )


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, str | int | float | bool) or v is None:
            out[k] = v
        elif isinstance(v, list | tuple):
            out[k] = [x if isinstance(x, str | int | float | bool) else str(x) for x in v]
        else:
            out[k] = str(v)
    return out


def _loc(e: dict[str, Any]) -> list[Any]:
    """An error's location without the tag of a discriminated union (``body.full.scan_id`` ->
    ``body.scan_id``): clients name fields, not schema variants."""
    loc = list(e.get("loc", ()))
    return loc[:1] + loc[2:] if len(loc) > 2 and loc[1] in UNION_TAGS else loc


def _field(loc: list[Any]) -> str | None:
    """The field an error names: the last name in its location (list indices skipped)."""
    names = [x for x in loc[1:] if isinstance(x, str) and not x.isdigit()]
    return names[-1] if names else None


_HTTP_CODES = {401: "invalid_api_key", 404: "not_found", 405: "method_not_allowed"}


def install(app: FastAPI) -> None:
    """Register the exception handlers that produce the one error shape."""

    @app.exception_handler(ApiError)
    async def _api(_: Request, exc: ApiError) -> JSONResponse:
        headers = None if exc.retry_after is None else {"Retry-After": str(exc.retry_after)}
        return JSONResponse(error_body(exc.code, exc.message, exc.details), exc.status, headers)

    @app.exception_handler(BodyspaceError)
    async def _core(_: Request, exc: BodyspaceError) -> JSONResponse:
        d = describe(exc)
        return JSONResponse(error_body(**d), core_error_status(exc))

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        raw = exc.errors()[:10]
        errors = [  # bounded: no input echoed, at most 10 errors, keys clipped
            {
                "loc": [clip(x) for x in _loc(e)],
                "msg": clip(e.get("msg"), 200),
                "type": e.get("type"),
            }
            for e in raw
        ]
        details: dict[str, Any] = {"errors": errors}
        fields = [f for e in errors if (f := _field(e["loc"])) is not None]
        if fields:  # the first problem's field, e.g. body.keep.0 -> keep, options.refine -> refine
            details["field"] = fields[0]
        if errors and all(e["type"] == "missing" for e in errors):
            msg = f"missing required field(s): {', '.join(e['loc'][-1] for e in errors)}"
            return JSONResponse(error_body("missing_field", msg, details), 422)
        first = errors[0] if errors else {"loc": [], "msg": "invalid", "type": None}
        ctx = (raw[0].get("ctx") or {}) if raw else {}
        if first["type"] == "union_tag_invalid":  # a discriminated union's tag, e.g. fit mode
            details["field"] = str(raw[0].get("ctx", {}).get("discriminator", "")).strip("'")
            details["accepted"] = re.findall(r"'([^']*)'", str(ctx.get("expected_tags", "")))
            msg = f"{details['field']}: must be one of {', '.join(details['accepted'])}"
            return JSONResponse(error_body("validation_error", msg, details), 422)
        msg = f"{'.'.join(first['loc'])}: {first['msg']}"
        expected = ctx.get("expected")
        if first.get("type") in ("literal_error", "enum") and isinstance(expected, str):
            details["accepted"] = re.findall(r"'([^']*)'", expected)
        return JSONResponse(error_body("validation_error", msg, details), 422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        if isinstance(exc.__cause__, RecursionError):  # FastAPI's body parsing: too deep
            msg = "the JSON body is nested too deeply"
            return JSONResponse(error_body("validation_error", msg), 422)
        if exc.status_code == 400 and exc.__cause__ is not None:  # FastAPI: unreadable body
            msg = "the body is not JSON (UTF-8 text) this route can read"
            return JSONResponse(error_body("validation_error", msg), 422)
        fallback = "bad_request" if exc.status_code < 500 else "internal_error"
        code = _HTTP_CODES.get(exc.status_code, fallback)
        headers = getattr(exc, "headers", None)  # e.g. a 405's Allow (RFC 9110)
        return JSONResponse(error_body(code, str(exc.detail)), exc.status_code, headers=headers)

    @app.exception_handler(Exception)
    async def _internal(_: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error")
        return JSONResponse(error_body("internal_error", "internal error"), 500)
