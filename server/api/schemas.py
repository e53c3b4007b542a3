"""What the API answers, as pydantic models: one family per resource (the FastAPI template's ``BakeCreate`` /
``BakePublic`` / ``BakesPublic``), and the error shape every 4xx has.

They are the routes' ``response_model``: the OpenAPI document (``/openapi.json``, ``/docs``, ``/redoc``) shows
them. The hot routes still write their own JSON (``bakes.json_response``: ``json.dumps`` rather than FastAPI's
encoder, see docs/architecture.md), and FastAPI does not re-validate a returned ``Response``, so these models
document the responses rather than reshape them; ``tests/server/test_schemathesis.py`` checks the real
responses of a real server against them (a field the code adds and a model lacks fails it: the models forbid
extra fields, so their schemas say ``additionalProperties: false``).

The request bodies are here too, in their resource's family: ``CamerasBody``, ``ThresholdsBody`` (scenes),
``BakeCreate`` (bakes), ``RelightRequest`` (relight). FastAPI validates every request against them: an unknown
or bad field is a 422 naming it. They have comments, not
docstrings: a docstring would enter the OpenAPI document as the schema's description.
"""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool

from proto.models import BakeConfig, BakeWarning, CameraSpec, LightConfig, Manifest
from server.gates import GRAMMAR


class _Out(BaseModel):
    model_config = ConfigDict(extra="forbid")


# --------------------------------------------------------------------------------------------- errors


class ErrorDetail(BaseModel):
    """``code``: a stable machine-readable word (``scene_not_found``, ``invalid_config``, ``over_budget``, ...);
    ``message``: a sentence for people naming the field or parameter. Some codes add fields (``over_budget``:
    ``estimate``, ``limits``, ``over_budget``)."""

    model_config = ConfigDict(extra="allow")
    code: str = Field(..., examples=["scene_not_found"])
    message: str = Field(..., examples=["no scene 3f2a..."])


class ErrorResponse(_Out):
    """Every error the app answers: ``{"error": {"code", "message"}}`` (server/api/errors.py)."""

    error: ErrorDetail


ERROR_MEANING = {
    400: "a malformed request (the message says what)",
    401: "no valid API key (only when the server has keys, KILN_API_KEYS): 'Authorization: Bearer <key>'",
    404: "no such resource for this team (another team's reads the same)",
    408: "the upload did not arrive in time (KILN_INGEST_TIMEOUT_S)",
    409: "the resource is not in a state that allows it",
    413: "the body is over its limit (KILN_MAX_JSON_KB; uploads: KILN_MAX_UPLOAD_MB)",
    415: "not a glTF file",
    416: "the Range starts past the end of the file",
    422: "a parameter or body field refused (the message names it)",
    429: "a team quota or limit reached (Retry-After says when to retry)",
}


def error_responses(*codes: int | dict[int, str], model: type[BaseModel] = ErrorResponse) -> dict:
    """``responses=`` entries for the 4xx a route answers, each with the error shape: ``error_responses(401, 422,
    {404: "no such scene"})`` (a dict gives the route's own sentence for a code)."""
    out = {}
    for c in codes:
        for code, why in (c.items() if isinstance(c, dict) else [(c, ERROR_MEANING[c])]):
            out[code] = {"model": model, "description": why}
    return out


# --------------------------------------------------------------------------------------------- ops


class Health(_Out):
    status: Literal["ok", "degraded"]
    redis: bool
    catalog: bool
    auth: Literal["open", "api-keys"] = Field(..., description="open: no API keys configured")


# --------------------------------------------------------------------------------------------- scenes


class ReviewCamera(_Out):
    """A review camera: world space, metres; ``fov_y`` vertical field of view in degrees."""

    name: str | None = None
    position: list[float] | None
    target: list[float] | None
    fov_y: float | None = None


class ScenePublic(_Out):
    """An uploaded scene as the catalog keeps it: the parse's summary, when and under which name it came."""

    id: str = Field(..., description="sha256 of the normalized scene (the same file uploaded twice: the same id)")
    triangles: int
    bounds: list[list[float | None]] = Field(..., description="[[min x, y, z], [max x, y, z]], metres")
    lights: int = Field(..., description="KHR_lights_punctual lights in the file")
    materials: int
    emissive_materials: int = Field(0, description="materials that emit light, used by some triangle")
    warnings: list[str] = Field(default_factory=list, description="what the parse noticed (ingest warnings)")
    bytes: int | None = Field(None, description="size of the normalized scene (counts against the storage quota)")
    created: float = Field(..., description="upload time, seconds since the epoch")
    filename: str | None = Field(None, description="the client's file name (multipart, X-Filename or ?filename)")
    review_cameras: list[ReviewCamera] | None = Field(None, description="stored by PUT /v1/scenes/{id}/cameras")
    thresholds: list[str] | None = Field(None, description="quality gates stored by PUT /v1/scenes/{id}/thresholds")


class ScenesPublic(_Out):
    items: list[ScenePublic]
    total: int
    limit: int
    offset: int


MAX_REVIEW_CAMERAS = 16
"""Review cameras a scene keeps (web/src/view/reviewCameras.js has the same number)."""


class CamerasBody(BaseModel):   # PUT /v1/scenes/{id}/cameras
    model_config = ConfigDict(extra="forbid")
    cameras: list[CameraSpec] = Field(..., max_length=MAX_REVIEW_CAMERAS,
                                      description="review cameras (an empty list removes the stored ones)")


class SceneCameras(_Out):
    """``source``: ``stored`` (PUT), ``gltf`` (the file's own cameras) or ``auto`` (placed by the scene's latest
    evaluated bake, ``from_bake``; none before the first)."""

    scene_id: str
    source: Literal["stored", "gltf", "auto"]
    cameras: list[ReviewCamera]
    from_bake: str | None


MAX_THRESHOLDS = 32
"""Quality gates a scene keeps."""


class ThresholdsBody(BaseModel):   # PUT /v1/scenes/{id}/thresholds
    model_config = ConfigDict(extra="forbid")
    thresholds: list[str] = Field(..., max_length=MAX_THRESHOLDS,
                                  description=f"gates, {GRAMMAR} (an empty list removes the stored ones)",
                                  examples=[["mask_normalized.leak > 0.05", "*.rmse >= 0.2"]])


class ThresholdGate(_Out):
    """One stored threshold read with the gates grammar (server/gates.py): it *fails* a bake when
    ``<metric> <op> <value>`` holds for a metric it names (``*`` matches any text), or when it names none."""

    text: str = Field(..., examples=["mask_normalized.leak > 0.05"])
    metric: str = Field(..., description="a metric name or an fnmatch pattern ('*.leak')")
    op: Literal[">", ">=", "<", "<=", "==", "!="]
    value: float


class ThresholdResult(_Out):
    """A gate checked against one bake's metrics (``gates.check``)."""

    text: str
    passed: bool
    matched: dict[str, float] = Field(..., description="metric -> value, every metric the gate names")
    failing: dict[str, float] = Field(..., description="metric -> value where the comparison holds")
    message: str = Field(..., description="gates.Gate.describe()")


class BakeThresholds(_Out):
    """The scene's thresholds checked against one of its succeeded bakes (``gates.manifest_metrics``)."""

    bake_id: str
    created: float
    passed: bool = Field(..., description="every threshold passed (true when there are none)")
    results: list[ThresholdResult]


class SceneThresholds(_Out):
    """``GET/PUT /v1/scenes/{id}/thresholds``: the stored gates, read, and their pass/fail for the scene's
    succeeded bakes (the newest ``limit``, newest first)."""

    scene_id: str
    thresholds: list[str]
    gates: list[ThresholdGate]
    bakes: list[BakeThresholds]


# --------------------------------------------------------------------------------------------- bakes

BakeStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
StageStatus = Literal["pending", "running", "retrying", "succeeded", "failed", "cancelled"]


class BakeCreate(BaseModel):   # POST /v1/bakes: a scene of the team and a config (every section optional, defaults filled)
    model_config = ConfigDict(extra="forbid")
    scene_id: str = Field(..., min_length=1, max_length=128)
    config: BakeConfig = Field(default_factory=BakeConfig)


class BakeLinks(_Out):
    self: str
    events: str
    bundle: str
    artifacts: str
    cancel: str


class BakeCreated(_Out):
    """A bake accepted (202; ``succeeded`` at once when every stage came from the cache)."""

    id: str
    status: BakeStatus
    links: BakeLinks


class StageCost(_Out):
    name: str
    seconds: float
    memory_bytes: int
    artifact_bytes: int
    queue: Literal["long", "short"]


class BakeEstimate(_Out):
    """``proto.cost``'s estimate of a bake (the automatic grid at its upper bound: ``probes_exact`` false)."""

    probes: int
    probes_exact: bool
    seconds: float
    peak_memory_bytes: int
    artifact_bytes: int
    bundle_bytes: int
    samples_per_cell: int
    field_samples: int
    stages: list[StageCost]


class BakeLimits(_Out):
    """The server's budget for one bake (``KILN_MAX_BAKE_MEMORY_MB``, ``KILN_MAX_BAKE_SECONDS``,
    ``KILN_MAX_BAKE_DISK_MB``); null: no limit."""

    peak_memory_bytes: int | None
    seconds: float | None
    artifact_bytes: int | None


class OverBudget(_Out):
    resource: Literal["peak_memory_bytes", "seconds", "artifact_bytes"]
    estimate: float
    limit: float


class BakeDryRun(_Out):
    """``POST /v1/bakes?dry_run=true``: the estimate; nothing is recorded or started."""

    estimate: BakeEstimate
    limits: BakeLimits
    over_budget: list[OverBudget] = Field(..., description="empty: within the budget")


class BakeRefusedDetail(ErrorDetail):
    """``over_budget`` adds the estimate, the limits and what is over them; other codes have none of them."""

    estimate: BakeEstimate | None = None
    limits: BakeLimits | None = None
    over_budget: list[OverBudget] | None = None


class BakeRefused(_Out):
    """A 422 of ``POST /v1/bakes``: a config refused (``invalid_config``, ``invalid_request``) or over the
    budget (``over_budget``, with the estimate)."""

    error: BakeRefusedDetail


class BakeError(_Out):
    """Why a bake failed: ``stage`` (null: before any stage ran), a ``code`` and a sentence."""

    stage: str | None
    code: str
    message: str


class StagePublic(_Out):
    name: str
    status: StageStatus
    progress: float | None
    seconds: float | None
    cached: bool
    stats: dict[str, Any] = Field(..., description="what the stage measured (per stage; free-form)")


class ArtifactPublic(_Out):
    """One file of the bake's bundle (proto/bundle.md): ``GET /v1/bakes/{id}/artifacts/{name}``."""

    name: str | None
    file: str | None
    format: str | None
    shape: list[int] | None
    dtype: str | None
    bytes: int | None
    sha256: str | None
    stage: str | None
    meta: dict[str, Any] | None


class BakeItem(_Out):
    """A bake as ``GET /v1/bakes`` lists it."""

    id: str
    scene_id: str
    status: BakeStatus
    config: BakeConfig = Field(..., description="the config the bake runs with (the scene's review cameras in)")
    created: float
    started: float | None
    finished: float | None
    error: BakeError | None
    stages: list[StagePublic]
    warnings: list[BakeWarning] = Field(..., description="the manifest's, or those of the stages done so far")
    warning_count: int
    metrics: dict[str, float | None]
    links: BakeLinks


class BakePublic(BakeItem):
    """One bake (``GET /v1/bakes/{id}``, cancel): the list's fields, the artifacts so far and the check points."""

    artifacts: list[ArtifactPublic]
    check_points: dict[str, Any] | None = Field(..., description="the check_points artifact (evaluate.points; "
                                                                 "proto/bundle.md 5.4), or null")


class BakesPublic(_Out):
    items: list[BakeItem]
    total: int
    limit: int
    offset: int


class StageSnapshot(_Out):
    name: str
    status: StageStatus
    progress: float | None
    seconds: float | None
    cached: bool


class BakeSnapshot(_Out):
    """The data of each Server-Sent Event of ``GET /v1/bakes/{id}/events`` (``progress`` and ``status``
    events; ``deleted`` carries only ``{"id"}``)."""

    id: str
    scene_id: str
    status: BakeStatus
    error: BakeError | None
    stages: list[StageSnapshot]
    warnings: list[BakeWarning]


# --------------------------------------------------------------------------------------------- relight


class RelightRequest(BaseModel):   # POST /v1/bakes/{id}/relight
    model_config = ConfigDict(extra="forbid")
    lights: list[LightConfig] = Field(..., max_length=64, description="the lights to relight with")
    lightmap: StrictBool = Field(True, description="also reconstruct the lightmap (when the bake has one)")


class RelightJSON(_Out):
    """``?format=json``: the relit bundle's manifest and every file, base64."""

    format: Literal["kiln-relight/1"]
    manifest: Manifest
    files: dict[str, str] = Field(..., description="file name -> base64 of its bytes (manifest.json among them)")


# --------------------------------------------------------------------------------------------- compare


class BakeRef(_Out):
    id: str
    scene_id: str
    status: BakeStatus
    created: float


class MetricDelta(_Out):
    a: float
    b: float
    delta: float | None = Field(..., description="b - a (null: past a double)")
    ratio: float | None = Field(..., description="b / a; null when a is 0")
    delta_stderr: float | None = Field(None, description="standard error of the delta, paired: both bakes scored "
                                       "against one reference (its noise shared); null: not paired, use "
                                       "sqrt(stderr_a² + stderr_b²)")


class Pairing(_Out):
    paired: bool = Field(..., description="both bakes were scored against the same cached reference")
    reason: str
    points: int = Field(..., description="surface points the paired standard errors are computed on")
    check_points: int


class Comparison(_Out):
    """``GET /v1/compare``: the metrics both bakes have, and those only one has."""

    a: BakeRef
    b: BakeRef
    metrics: dict[str, MetricDelta]
    paired: Pairing
    only_a: list[str]
    only_b: list[str]
