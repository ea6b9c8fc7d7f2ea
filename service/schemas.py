"""Request and response bodies of the HTTP API (pydantic)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    StrictBool,
    StrictFloat,
    Tag,
    ValidationInfo,
    field_validator,
)

FitState = Literal["queued", "running", "succeeded", "failed"]
FitMode = Literal["full", "markerless", "markers_only", "measurements"]
#: ``core.io.frame.UNITS_OPTIONS`` (a test holds them equal)
MarkerUnits = Literal["auto", "m", "cm", "mm", "in"]
Sex = Literal["female", "male"]
MarkerUp = Literal["auto", "+x", "-x", "+y", "-y", "+z", "-z"]


def _keys_from(load: Callable[[], Iterable[str]], **items: Any) -> Callable[[dict], None]:
    """A field's JSON-schema extra: the object's keys are among ``load()`` (read when the
    document is built, not at import), ``items`` added to the schema of its values (e.g.
    ``minItems``). Documents what the route checks itself (with its own error code)."""

    def extra(schema: dict[str, Any]) -> None:
        schema["propertyNames"] = {"enum": sorted(set(load()))}
        for option in schema.get("anyOf", [schema]):  # X | None: the object branch
            if option.get("type") == "object" and items:
                option["additionalProperties"] = {**option["additionalProperties"], **items}

    return extra


def _landmarks() -> Iterable[str]:
    from core.template import load_template

    return load_template().landmarks


def _measurements() -> Iterable[str]:
    from core.measure import MEASUREMENTS

    return MEASUREMENTS


def _bones() -> Iterable[str]:
    from core.rig import load_rig

    return load_rig().names


def _edit_features() -> Iterable[str]:
    from service.shape_routes import MODELS, get_model

    return {
        f
        for name in MODELS
        for key, sp in get_model(name).spaces.items()
        if key != "joint"
        for f in sp.features.names
    }


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


class ScanFitOptions(BaseModel):
    """Options of a fit (keyword options of ``core.registration.fit``)."""

    model_config = ConfigDict(extra="forbid")

    schedule: Literal["default", "fast", "paper"] = Field(
        "default",
        description="'default': body prior + full-resolution refinement (most accurate); "
        "'fast': a short preview; 'paper': Allen et al. 2003's four-stage schedule from the "
        "bare template",
    )
    shape_prior: StrictBool | None = Field(
        None,
        description="override: personalise the template before the affine fit "
        "(default: on for 'default'/'fast', off for 'paper')",
    )
    max_distance_m: float | None = Field(
        None,
        gt=0,
        le=0.5,
        strict=True,
        description="farthest compatible scan point, metres (default 0.10)",
    )


class MarkerlessOptions(ScanFitOptions):
    """Options of a markerless fit: it starts from the shape space (body prior), so no 'paper'
    schedule and no ``shape_prior: false``."""

    schedule: Literal["default", "fast"] = Field(  # type: ignore[assignment]
        "default",
        description="'default': body prior + full-resolution refinement (most accurate); "
        "'fast': a short preview ('paper' starts from the bare template: not markerless)",
    )
    shape_prior: Literal[True] | None = Field(  # type: ignore[assignment]
        None, description="always on for a markerless fit (the start is the shape space)"
    )
    refine: StrictBool | None = Field(
        None,
        description="follow the shape-space fit with the per-vertex affine refinement of the "
        "schedule (default true); false returns the shape-space body",
    )


class MeasurementsOptions(ScanFitOptions):
    """Options of a measurements fit (``schedule``, ``shape_prior`` and ``max_distance_m``
    concern scans: accepted and ignored)."""

    calibrate: StrictBool | None = Field(
        None,
        description="the values are tape measurements as ANSUR II takes them (default true; "
        "the body's own measurements plus the model's calibration offsets are matched); "
        "false: they follow bodyspace's measurement definitions (e.g. the measurements of a "
        "synthesised body) and are matched as they are",
    )


Markers = dict[str, list[StrictFloat]]
_MARKERS_DOC = "landmark name -> [x, y, z] in the scan file's units and axes"
_MARKER_KEYS = _keys_from(_landmarks, minItems=3, maxItems=3)


class _FitBase(BaseModel):
    model_config = ConfigDict(extra="forbid")


class FullFit(_FitBase):
    """``full`` (the default mode): scan + markers, given here or uploaded with the scan."""

    mode: Literal["full"] = Field("full", description="scan + markers (the default)")
    scan_id: str = Field(description="the scan to fit")
    markers: Markers | None = Field(
        None, description=_MARKERS_DOC + " (else the scan's)", json_schema_extra=_MARKER_KEYS
    )
    options: ScanFitOptions = Field(default_factory=ScanFitOptions)


class MarkerlessFit(_FitBase):
    """``markerless``: a scan without markers (markers are ignored)."""

    mode: Literal["markerless"]
    scan_id: str = Field(description="the scan to fit")
    markers: Markers | None = Field(None, description="ignored in this mode")
    options: MarkerlessOptions = Field(default_factory=MarkerlessOptions)


class MarkersOnlyFit(_FitBase):
    """``markers_only``: the most likely body from markers alone. Without ``scan_id`` the
    markers must be given here, in metres +Y up unless ``units``/``up`` say otherwise; with
    ``scan_id`` the markers (given here, else the scan's uploaded marker file) are in the scan
    file's units and axes, and the scan's surface is not used."""

    mode: Literal["markers_only"]
    scan_id: str | None = Field(None, description="optional: the scan whose frame (and "
                                "uploaded markers, unless given here) to use")  # fmt: skip
    markers: Markers | None = Field(
        None,
        description=_MARKERS_DOC + " (without scan_id: metres, +Y up unless units/up are given)",
        json_schema_extra=_MARKER_KEYS,
    )
    units: MarkerUnits | None = Field(
        None,
        description="without scan_id only: units of the markers (default 'm'; 'auto' detects "
        "them from the markers' height)",
    )
    up: MarkerUp | None = Field(
        None,
        description="without scan_id only: the markers' up axis (default '+y'; 'auto' detects "
        "it from head and foot landmarks)",
    )
    options: ScanFitOptions = Field(default_factory=ScanFitOptions)

    @field_validator("units", "up")
    @classmethod
    def _frame_without_scan(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is not None and info.data.get("scan_id") is not None:
            raise ValueError(
                f"{info.field_name} describes markers given without a scan; with scan_id the "
                "markers are in the scan's units and axes, set at upload"
            )
        return v


class MeasurementsFit(_FitBase):
    """``measurements``: the most likely body from tape measurements (no scan, no markers)."""

    mode: Literal["measurements"]
    sex: Sex = Field(description="the body's sex")
    measurements: dict[str, StrictFloat] = Field(
        min_length=1,
        description="ANSUR II measurement name (as listed by core.measure, e.g. 'stature', "
        "'weightkg', 'waistcircumference') -> value in metres (weightkg in kg)",
        json_schema_extra=_keys_from(_measurements),
        examples=[{"stature": 1.65, "weightkg": 62.0}],
    )
    scan_id: None = Field(None, description="does not apply (null only)")
    markers: None = Field(None, description="does not apply (null only)")
    options: MeasurementsOptions = Field(default_factory=MeasurementsOptions)


def _fit_mode(v: Any) -> Any:
    """The tag of a fit request: its ``mode`` (default ``full``)."""
    return v.get("mode", "full") if isinstance(v, dict) else getattr(v, "mode", None)


#: Tags of the discriminated unions (stripped from validation errors' locations).
UNION_TAGS = frozenset(
    ("full", "markerless", "markers_only", "measurements", "from_model", "from_fit", "from_morph")
)

#: A fit request, one schema per ``mode`` (``full`` when absent).
FitCreate = Annotated[
    Annotated[FullFit, Tag("full")]
    | Annotated[MarkerlessFit, Tag("markerless")]
    | Annotated[MarkersOnlyFit, Tag("markers_only")]
    | Annotated[MeasurementsFit, Tag("measurements")],
    Discriminator(_fit_mode),
]


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


class PartQualityOut(BaseModel):
    """Figures of one body part (metres; coverage a fraction); ``null`` where not measurable."""

    quality: Literal["good", "suspect", "failed"]
    scan_points: int
    scan_to_fit_mean_m: float | None = None
    scan_to_fit_p95_m: float | None = None
    fit_to_scan_mean_m: float | None = None
    fit_to_scan_p95_m: float | None = None
    coverage: float | None = None
    area_change: float | None = None
    displacement_m: float | None = None
    data_beyond_m: float | None = Field(
        None, description="hands: unexplained scan data beyond the fitted hand (m)"
    )
    hand_bend_deg: float | None = Field(
        None, description="hands: angle between forearm axis and wrist->hand centroid (°)"
    )
    hand_proportion: float | None = Field(
        None, description="hands: hand reach per forearm length over the template's, max(r, 1/r)"
    )
    hand_tip_gap_m: float | None = Field(
        None, description="hands: median distance of the fitted fingertips to the scan (m)"
    )
    hand_body_gap_m: float | None = Field(
        None,
        description="hands: 5th percentile distance of the hand to the fitted torso and thighs "
        "(m); a hand resting on the body cannot be told from it in a closed mesh",
    )
    head_turn_deg: float | None = Field(
        None, description="head: rotation of the head against the torso from the template's (deg)"
    )
    head_distortion_m: float | None = Field(
        None, description="head: RMS distance of its shape from the template head's (m)"
    )
    leg_proportion: float | None = Field(
        None, description="legs: inseam per trunk length over the template's, max(r, 1/r)"
    )
    arm_symmetry: float | None = Field(
        None, description="arms: the left arm's length over the right's, max(r, 1/r)"
    )
    foot_turn_deg: float | None = Field(
        None, description="feet: heel->toe direction against the torso's forward (deg)"
    )
    feet_apart_m: float | None = Field(
        None,
        description="feet: left foot's centre left of the right's, torso frame (m; < 0 crossed)",
    )
    sternum_proportion: float | None = Field(
        None,
        description="torso: the Substernale's share of navel -> suprasternal notch over the "
        "template's, max(r, 1/r)",
    )
    scan_spread_m: float | None = Field(
        None,
        description="the scan's own spread about its surface there (m; scanner noise reads "
        "about 0.001, more where the scan holds the skin in layers: a subject who moved "
        "between views, views misaligned); hands and feet take their arm's and leg's",
    )


class FitQualityOut(BaseModel):
    """The fit's quality verdict (``core.registration.quality``): ``good``; ``suspect`` (worth a
    look); ``failed`` (a body part is lost, collapsed or misplaced: do not use the body as it
    is). The job still ends ``succeeded`` so the result can be inspected."""

    quality: Literal["good", "suspect", "failed"]
    reasons: list[str] = Field(default_factory=list, description="each names the body part")
    parts: dict[str, PartQualityOut] = Field(
        default_factory=dict,
        description="head, torso, arm_L/R, hand_L/R, leg_L/R, foot_L/R (_L = subject's left)",
    )
    thresholds: dict[str, dict[str, float | None]] = Field(
        default_factory=dict, description="figure -> suspect / failed limits (null: never)"
    )
    unresolved: list[str] = Field(
        default_factory=list,
        description="parts suspect only because the scan cannot place them (a hand resting on "
        "the body): refitting would not help; their place is a guess",
    )


class FitOut(BaseModel):
    id: str
    mode: FitMode = "full"
    scan_id: str | None = Field(None, description="None for a markers-only fit without a scan")
    state: FitState
    options: dict[str, Any]
    progress: Progress | None = None
    timings: Timings
    error: ErrorInfo | None = None
    attempts: int
    result_formats: list[str] = Field(default_factory=list)
    quality: FitQualityOut | None = Field(
        None, description="a succeeded fit's quality verdict (none for fits without a scan)"
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="a succeeded fit's warnings (the result JSON's report.warnings): what may "
        "make the body wrong, e.g. points removed as not the body, parts without data",
    )
    removed: dict[str, int] = Field(
        default_factory=dict,
        description="scan points removed as not the body before fitting (floor_points, "
        "stray_points; hair_points: hair on the head a markerless fit left out; "
        "cut_cap_points: the surface closing a scan cut above the soles; head_cap_points: "
        "the flat surface closing a scan cut through the head); scan->fit "
        "figures and the quality check are over the kept points",
    )


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


# ----------------------------------------------------------------------------- shape models


class FeatureRange(BaseModel):
    range: list[float] = Field(
        description="[low, high] accepted by the model (beyond: 422 out_of_range)"
    )
    training_range: list[float] = Field(
        description="[low, high] covered by its training bodies (beyond, up to `range`: the "
        "body is extrapolated and the answer carries a warning)"
    )
    unit: str


class ModelSpace(BaseModel):
    features: dict[str, FeatureRange] = Field(
        description="feature name -> supported range and unit (measurements: ANSUR II names, m)"
    )
    components: int = Field(description="number of PCA components (length of a full `pca`)")
    explained_variance: float
    training_bodies: int
    density_kg_m3: float


class ModelOut(BaseModel):
    """A shape model: what it accepts (sexes, features, ranges, components) and its provenance."""

    name: str
    sexes: list[Sex]
    spaces: dict[str, ModelSpace] = Field(description="per sex (and 'joint', when present)")
    metadata: dict[str, Any] = Field(default_factory=dict)
    provenance: str = ""


class ModelList(BaseModel):
    items: list[ModelOut]


class SynthesizeRequest(BaseModel):
    """A body from features (``height_m``, ``weight_kg``, ``age`` and any measurement the model
    lists, metres), from PCA weights (``pca``) or at random (``seed``; with features it draws the
    individual variation around the most likely body). Missing features take their most likely
    values given the others."""

    model_config = ConfigDict(
        extra="allow",
        json_schema_extra={
            "additionalProperties": {"type": "number"},
            "examples": [
                {"sex": "female", "height_m": 1.65, "weight_kg": 60},
                {"sex": "male", "pca": [5.0, -2.0]},
                {"sex": "male", "seed": 7},
            ],
        },
    )

    sex: Sex
    height_m: float | None = Field(None, gt=0, allow_inf_nan=False, description="stature, m")
    weight_kg: float | None = Field(None, gt=0, allow_inf_nan=False, description="kg")
    age: float | None = Field(None, ge=0, allow_inf_nan=False, description="years")
    pca: list[float] | None = Field(
        None, min_length=1, description="PCA weights (metres), at most the model's components"
    )
    seed: int | None = Field(
        None, ge=0, le=2**53 - 1, description="random body, reproducible (a JSON-safe integer)"
    )


class SynthesizedBody(BaseModel):
    """JSON variant of a synthesised body (``Accept: application/json``)."""

    vertices: list[list[float]] = Field(description="(13380, 3), template order, metres, +Y up")
    faces: list[list[int]] = Field(description="(m, 3) template triangles")
    measurements: dict[str, float | None] = Field(
        description="ANSUR II measurements of the body (metres; weightkg in kg)"
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="where the model extrapolated beyond its training range (empty inside it)",
    )


# ----------------------------------------------------------------------------- bodies

BodySource = Literal["model", "fit", "edit", "morph", "pose"]
FiniteNumber = Annotated[float, Field(strict=True, allow_inf_nan=False)]


class BodyMorph(BaseModel):
    """An in-between body ``(1 - t) from + t to`` of two stored bodies (paper §4.1)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    from_: str = Field(alias="from", description="body id (t = 0)")
    to: str = Field(description="body id (t = 1)")
    t: float = Field(ge=0, le=1, allow_inf_nan=False, description="0 = `from`, 1 = `to`")


class ModelBody(SynthesizeRequest):
    """A body synthesised from a shape model: the fields of ``POST /v1/models/{model}/synthesize``
    (``{sex, height_m?, weight_kg?, age?, <measurement>?}``, ``{sex, pca}`` or ``{sex, seed}``)."""

    model_config = ConfigDict(
        json_schema_extra={
            "additionalProperties": {"type": "number"},
            "examples": [
                {"sex": "female", "height_m": 1.65, "weight_kg": 60},
                {"model": "default", "sex": "male", "seed": 7},
            ],
        },
    )

    model: str = Field("default", description="the shape model (`GET /v1/models`)")


class FitBody(BaseModel):
    """The fitted body of a succeeded fit (a scan has no sex, so it must be given)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"sex": "male", "fit_id": "fit_0123456789abcdef0123"}]},
    )

    fit_id: str = Field(description="take the body of this succeeded fit")
    sex: Sex
    model: str = Field("default", description="the shape model (`GET /v1/models`)")


class MorphBody(BaseModel):
    """An in-between body of two stored bodies: model and sex those of the nearer body unless
    ``sex`` is given."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"morph": {"from": "bdy_0123456789abcdef0123", "to": "bdy_...", "t": 0.3}}]
        },
    )

    morph: BodyMorph = Field(description="store the in-between body of two of your bodies")
    sex: Sex | None = Field(None, description="default: the nearer body's")
    model: str = Field(
        "default", description="must name a model (`GET /v1/models`); the nearer body's is used"
    )


def _body_source(v: Any) -> Any:
    """The tag of a body request: ``morph`` or ``fit_id`` present, else a model body."""
    if isinstance(v, dict):
        return "from_morph" if "morph" in v else "from_fit" if "fit_id" in v else "from_model"
    return {ModelBody: "from_model", FitBody: "from_fit", MorphBody: "from_morph"}.get(type(v))


#: A body to store, one schema per source (OpenAPI ``oneOf``): from a shape model, from a fit
#: (``fit_id``) or an in-between body (``morph``); the sources exclude each other.
BodyCreate = Annotated[
    Annotated[ModelBody, Tag("from_model")]
    | Annotated[FitBody, Tag("from_fit")]
    | Annotated[MorphBody, Tag("from_morph")],
    Discriminator(_body_source),
]


Posture = Literal["standing", "seated", "driving", "reach"]


class BodyPose(BaseModel):
    """Pose a body with the template's standard rig (MakeHuman, 163 bones) carried to it: a named
    posture and/or bone rotations (rotation vectors: axis x angle in radians, in the template's
    axes, about the bone's joint, composed along the bone chain; they override the posture's
    rotation of the same bone)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"posture": "seated"},
                {"posture": "seated", "seat_contact": False},
                {"rotations": {"upperleg01.L": [-1.2, 0, 0], "lowerleg01.L": [1.0, 0, 0]}},
            ],
            "anyOf": [  # a posture and/or at least one rotation
                {"required": ["posture"], "properties": {"posture": {"type": "string"}}},
                {"required": ["rotations"], "properties": {"rotations": {"minProperties": 1}}},
            ],
        },
    )

    posture: Posture | None = Field(None, description="a named posture")
    rotations: dict[str, list[StrictFloat]] = Field(
        default_factory=dict,
        description="bone name (the rig's 163: `propertyNames`) -> rotation vector [x, y, z] "
        "(radians)",
        json_schema_extra=_keys_from(_bones, minItems=3, maxItems=3),
    )
    seat_contact: StrictBool | None = Field(
        None,
        description="rest the body on a flat seat: the soft tissue under the buttocks "
        "compressed as measured in seated people (MRI; 33 mm under the ischial tuberosities), "
        "its underside flattened on the seat plane; default: on for `seated` and `driving`, "
        "off otherwise (then plain linear blend skinning)",
    )


class MorphRequest(BaseModel):
    """Bodies to put in one GLB: the first as the mesh, one morph target per other body."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"bodies": ["bdy_0123456789abcdef0123", "bdy_..."]}]},
    )

    bodies: list[str] = Field(
        min_length=2,
        max_length=16,
        json_schema_extra={"uniqueItems": True},
        description="2-16 of your body ids, each once",
    )


#: The template's parts (``core.template.load_template().part_names``; a test checks they agree).
TemplatePart = Literal[
    "head", "neck", "torso", "pelvis", "upper_arm_L", "upper_arm_R", "forearm_L", "forearm_R",
    "hand_L", "hand_R", "thigh_L", "thigh_R", "shin_L", "shin_R", "foot_L", "foot_R",
]  # fmt: skip


class BodyEdit(BaseModel):
    """Change a body's features (paper §5): its PCA weights move by Δfeatures × the feature
    map, its individual residual is kept, and the ``keep`` parts do not move."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"delta": {"weight_kg": 10}},
                {"delta": {"height_m": 0.05}, "target": {"weight_kg": 80}, "keep": []},
            ],
            "anyOf": [  # at least one change
                {"required": ["delta"], "properties": {"delta": {"minProperties": 1}}},
                {"required": ["target"], "properties": {"target": {"minProperties": 1}}},
            ],
        },
    )

    delta: dict[str, FiniteNumber] = Field(
        default_factory=dict,
        max_length=64,
        json_schema_extra=_keys_from(_edit_features),
        description="feature -> change (height_m m, weight_kg kg, age years, measurements m)",
    )
    target: dict[str, FiniteNumber] = Field(
        default_factory=dict,
        max_length=64,
        json_schema_extra=_keys_from(_edit_features),
        description="feature -> absolute new value (turned into a change from the body's "
        "current features); a feature may not be in both `delta` and `target`",
    )
    keep: list[TemplatePart] | None = Field(
        None,
        max_length=16,
        description="template parts held in place, at most 16 (repeats count once; default "
        "head, hand_L, hand_R: face and hands do not move; a height_m change shifts them "
        "rigidly with the body); [] for the plain edit of the paper",
    )


class BodyOut(BaseModel):
    """A stored body (its mesh: `GET /v1/bodies/{id}`)."""

    id: str
    model: str
    sex: Sex
    source: BodySource = Field(
        description="'model': synthesised; 'fit': a fit's body; 'edit': edited from another"
    )
    fit_id: str | None = Field(
        None, description="the fit it was made from (also for bodies edited from one)"
    )
    derived_from: str | None = Field(None, description="the body it was edited from")
    params: dict[str, Any] = Field(description="the request that made it")
    features: dict[str, float] = Field(
        description="the model's features of the body: measured height_m (m) and weight_kg "
        "(kg, volume x the model's density), the others (age years, measurements m) the most "
        "likely given its shape"
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="where the body lies beyond the model's training range (a model body: its "
        "request's features; a fit's or an edited body: its measured height_m and weight_kg), "
        "so that the model extrapolates it and edits of it; empty inside the range",
    )
    created_at: datetime


class BodyMesh(BodyOut):
    """JSON variant of a body's mesh (``Accept: application/json``)."""

    vertices: list[list[float]] = Field(description="(13380, 3), template order, metres, +Y up")
    faces: list[list[int]] = Field(description="(m, 3) template triangles")
    colors: list[list[int]] | None = Field(
        None,
        description="(13380, 3) RGB 0-255 per vertex, for bodies of a fit of a coloured scan "
        "(and their edits and poses); absent otherwise",
    )


class BodyPage(BaseModel):
    items: list[BodyOut]
    next_cursor: str | None = None


class MeasurementValue(BaseModel):
    value: float | None = Field(description="None when the body has no such section")
    unit: str


class BodyMeasurements(BaseModel):
    body_id: str
    sex: Sex
    density_kg_m3: float = Field(description="the model's calibrated density (for weightkg)")
    measurements: dict[str, MeasurementValue] = Field(
        description="ANSUR II name -> value (metres; weightkg in kg)"
    )
