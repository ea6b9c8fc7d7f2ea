"""Request and response bodies of the HTTP API (pydantic)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

FitState = Literal["queued", "running", "succeeded", "failed"]


class ErrorInfo(BaseModel):
    code: str
    message: str
    details: dict[str, Any] = Field(default_factory=dict)


class ErrorResponse(BaseModel):
    """The one error shape of every 4xx/5xx answer."""

    error: ErrorInfo


class ScanOut(BaseModel):
    id: str
    filename: str
    format: str
    size_bytes: int
    n_vertices: int
    n_faces: int
    units: str
    up: str
    marker_names: list[str]
    created_at: datetime


class FitOptions(BaseModel):
    """Options of a fit (keyword options of ``core.registration.fit``)."""

    model_config = ConfigDict(extra="forbid")

    schedule: Literal["default", "fast", "paper"] = Field(
        "default",
        description="'default': body prior + full-resolution refinement (most accurate); "
        "'fast': a short preview; 'paper': Allen et al. 2003's four-stage schedule from the "
        "bare template",
    )
    shape_prior: bool | None = Field(
        None,
        description="override: personalise the template before the affine fit "
        "(default: on for 'default'/'fast', off for 'paper')",
    )
    max_distance_m: float | None = Field(
        None, gt=0, le=0.5, description="farthest compatible scan point, metres (default 0.10)"
    )


class FitCreate(BaseModel):
    """A fit request: a scan id, optional markers (else the scan's) and options."""

    model_config = ConfigDict(extra="forbid")

    scan_id: str
    markers: dict[str, list[float]] | None = Field(
        None, description="landmark name -> [x, y, z] in the scan file's units and axes"
    )
    options: FitOptions = Field(default_factory=FitOptions)


class Progress(BaseModel):
    model_config = ConfigDict(extra="allow")

    phase: str | None = None
    stage: int | None = None
    n_stages: int | None = None
    iteration: int | None = None
    resolution: str | None = None
    energy: dict[str, float | None] | None = None
    percent: float | None = None


class Timings(BaseModel):
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    queued_s: float | None = Field(None, description="created -> (last) start")
    run_s: float | None = Field(None, description="(last) start -> finished")
    fit_s: float | None = Field(None, description="time inside the core's fit")


class FitOut(BaseModel):
    id: str
    scan_id: str
    state: FitState
    options: dict[str, Any]
    progress: Progress | None = None
    timings: Timings
    error: ErrorInfo | None = None
    attempts: int
    result_formats: list[str] = Field(default_factory=list)


class ScanPage(BaseModel):
    items: list[ScanOut]
    next_cursor: str | None = None


class FitPage(BaseModel):
    items: list[FitOut]
    next_cursor: str | None = None


class Health(BaseModel):
    status: str
    mode: Literal["embedded", "distributed"] | None = None
    checks: dict[str, str] = Field(default_factory=dict)
