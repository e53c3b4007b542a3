"""Contracts shared by every side of Kiln: the bake config and the bundle manifest.

The bake config is what a user writes (JSON through the API, TOML through the CLI).
Every section is validated strictly: unknown keys and out-of-range values are refused
with the field's path, so a typo never silently bakes with a default.

Units and frames: positions and lengths are world-space metres in glTF's frame
(+Y up, right-handed); colours are linear RGB; light intensities follow
KHR_lights_punctual (point/spot: candela, directional: lux); sky radiance is
linear RGB radiance (W/sr/m^2 up to a common scale).

The JSON Schema of :class:`BakeConfig` is exported to ``proto/schema/bake-config.schema.json``
(``python -m proto.export_schema``); a test keeps it in sync.
"""
from __future__ import annotations

import hashlib
import json
import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

FORMAT_VERSION = 1
"""Bundle format version written into every manifest (see proto/bundle.md)."""

MAX_PROBES = 1 << 20
"""Upper bound on the probe count of one grid (16x32x16 = 8192 is typical)."""

Vec3 = tuple[float, float, float]
Count = Annotated[int, Field(ge=1, le=256)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _finite(v: Vec3 | None, name: str) -> Vec3 | None:
    if v is not None and not all(math.isfinite(c) for c in v):
        raise ValueError(f"{name} must be finite")
    return v


class LightConfig(_Strict):
    """One punctual light added to the scene (KHR_lights_punctual semantics).

    ``position`` is required for point and spot lights, ``direction`` (the direction
    the light travels, world space, need not be unit) for spot and directional lights.
    """

    type: Literal["point", "spot", "directional"]
    position: Vec3 | None = Field(None, description="world-space position, metres (point, spot)")
    direction: Vec3 | None = Field(None, description="direction the light travels, world space (spot, directional)")
    color: Vec3 = Field((1.0, 1.0, 1.0), description="linear RGB")
    intensity: float = Field(1.0, ge=0.0, le=1e9, description="candela (point, spot) or lux (directional)")
    range: float | None = Field(None, gt=0.0, description="metres; None = infinite")
    inner_cone_angle: float = Field(0.0, ge=0.0, le=math.pi / 2, description="radians (spot)")
    outer_cone_angle: float = Field(math.pi / 4, gt=0.0, le=math.pi / 2, description="radians (spot)")

    @field_validator("color")
    @classmethod
    def _color_ok(cls, v: Vec3) -> Vec3:
        if not all(math.isfinite(c) and c >= 0 for c in v):
            raise ValueError("color components must be finite and >= 0")
        return v

    @model_validator(mode="after")
    def _check(self) -> "LightConfig":
        _finite(self.position, "position")
        _finite(self.direction, "direction")
        if self.type in ("point", "spot") and self.position is None:
            raise ValueError(f"a {self.type} light needs a position")
        if self.type in ("spot", "directional"):
            if self.direction is None:
                raise ValueError(f"a {self.type} light needs a direction")
            if sum(c * c for c in self.direction) < 1e-12:
                raise ValueError("direction must not be zero")
        if self.type == "spot" and self.inner_cone_angle >= self.outer_cone_angle:
            raise ValueError("inner_cone_angle must be below outer_cone_angle")
        return self


class SceneSection(_Strict):
    """Lighting added to (or replacing) what the glTF carries."""

    lights: list[LightConfig] = Field(default_factory=list, max_length=64,
                                      description="lights added to the scene's own KHR_lights_punctual lights")
    use_scene_lights: bool = Field(True, description="keep the lights the glTF defines")
    sky: Vec3 = Field((0.0, 0.0, 0.0), description="uniform sky radiance seen by rays that miss, linear RGB")
    max_albedo: float | None = Field(
        None, gt=0.0, le=1.0,
        description="clamp every surface's diffuse GI albedo to this (per channel); default: the albedo the file "
                    "says (an albedo of 0.95 or more is kept but warned about: a closed room of albedo 1 never "
                    "converges)")
    specular_gi: Literal["metals", "all", "none"] = Field(
        "metals",
        description="the diffuse equivalent of specular reflection in the GI albedo (Unity's meta pass: "
                    "specular x roughness^2 / 2): 'metals' for the metallic lobe only (dielectrics keep glTF's "
                    "diffuse term), 'all' for Unity's formula with F0 = 0.04 on dielectrics, 'none' for glTF's "
                    "diffuse term alone")

    @field_validator("sky")
    @classmethod
    def _sky_ok(cls, v: Vec3) -> Vec3:
        if not all(math.isfinite(c) and 0 <= c <= 1e6 for c in v):
            raise ValueError("sky components must be finite and in [0, 1e6]")
        return v


class Box(_Strict):
    """An axis-aligned box, world space, metres."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _check(self) -> "Box":
        _finite(self.min, "min")
        _finite(self.max, "max")
        if not all(a < b for a, b in zip(self.min, self.max)):
            raise ValueError("box min must be below max on every axis")
        return self


class PlaceSection(_Strict):
    """The probe grid (DESIGN stage 1): counts *or* spacing, over the scene bounds or a box.

    With ``counts`` the grid has exactly that many probes per axis, the outermost
    probes on the faces of the (padded) box. With ``spacing`` the counts are
    ``ceil(extent / spacing) + 1`` per axis and the grid is centred on the box.
    """

    counts: tuple[Count, Count, Count] | None = Field(
        None, description="probes along x, y, z; default (neither counts nor spacing): chosen from the scene "
                          "(its enclosed spaces, room sizes and wall thicknesses, under `budget`; manifest grid.auto)")
    spacing: float | None = Field(None, gt=0.0, le=1e4, description="metres between probes")
    box: Box | None = Field(None, description="grid box; default: the scene bounds (the automatic grid: the "
                                              "bounds of its enclosed spaces)")
    budget: int = Field(24_000, ge=8, le=MAX_PROBES, description="most probes of the automatic grid")
    padding: float = Field(0.0, ge=0.0, le=0.5,
                           description="fraction of each extent added on both sides of the box")

    @model_validator(mode="before")
    @classmethod
    def _spacing_replaces_counts(cls, data: Any) -> Any:
        # Giving spacing alone means "no counts": the default counts must not clash with it.
        if isinstance(data, dict) and data.get("spacing") is not None and "counts" not in data:
            data = {**data, "counts": None}
        return data

    @model_validator(mode="after")
    def _one_of(self) -> "PlaceSection":
        if self.counts is not None and self.spacing is not None:
            raise ValueError("give at most one of counts or spacing (neither: chosen from the scene)")
        if self.counts is not None and math.prod(self.counts) > MAX_PROBES:
            raise ValueError(f"at most {MAX_PROBES} probes")
        return self


class TraceSection(_Strict):
    """Probe rays, relocation and classification (DDGI-P §2.3, §5 Fig 7, §6 Fig 10; stages relocate + trace)."""

    rays_per_probe: int = Field(256, ge=16, le=4096, description="rays per probe, spherical Fibonacci pattern")
    relocate_iterations: int = Field(5, ge=0, le=20, description="iterations of the DDGI-P Fig 7 optimizer")
    max_offset: float = Field(0.45, ge=0.0, le=0.5, description="relocation limit, fraction of the spacing per axis")
    backface_fraction: float = Field(0.25, gt=0.0, lt=1.0,
                                     description="a probe seeing more backfaces than this is inside geometry")
    depth_texels: int = Field(16, ge=4, le=64, description="octahedral depth-moment map size per probe (+1 border)")
    depth_sharpness: float = Field(50.0, ge=1.0, le=200.0,
                                   description="exponent of the max(0, cos) weight of depth moments (RTXGI default 50)")


class LightSection(_Strict):
    """Multi-bounce probe irradiance (DDGI-I §3.4-3.5; stage light)."""

    bounces: int | None = Field(None, ge=1, le=256, description="a fixed number of bounces; default: until converged")
    max_bounces: int = Field(128, ge=1, le=1024, description="cap when iterating to convergence")
    tolerance: float = Field(0.005, gt=0.0, le=0.5,
                             description="stop when the light still to come (the geometric tail of each probe's "
                                         "per-bounce change) is below this fraction of the probe's light, at "
                                         "every probe")
    irradiance_texels: int = Field(8, ge=4, le=32, description="octahedral irradiance map size per probe (+1 border)")
    sh_order: Literal[1, 2] = Field(2, description="spherical-harmonics order of the per-probe SH output")
    self_shadow_bias: float = Field(0.3, ge=0.0, le=2.0, description="B of DDGI-P eq 2")


class VisibilitySection(_Strict):
    """The visibility field θ of MD §3.4 step 1 (stage visibility)."""

    samples_per_cell: int | None = Field(
        None, ge=1, le=32, description="refined-grid samples per cell axis (S); default: the automatic grid's "
                                       "choice (both sides of the thinnest walls), else 8")
    rays: int = Field(1, ge=1, le=64, description="occlusion rays per sample and probe: 1 = binary, more = soft")
    jitter: float = Field(0.05, ge=0.0, le=0.5,
                          description="radius of the jittered ray targets around a probe, fraction of the spacing")
    slabs: int = Field(4, ge=1, le=256,
                       description="RQ jobs the field is split into (z slabs of whole cell layers; "
                                   "slabs beyond the layer count are empty); the result does not depend on it")


class MasksSection(_Strict):
    """Mask Decomposition (MD §3.2-3.4; stages anneal, masks, compress)."""

    clusters: int = Field(4, ge=1, le=8, description="K, the number of probe clusters (mask channels)")
    coloring: Literal["anneal", "parity"] = Field(
        "anneal", description="'anneal' (MD §3.3, eq 7 + eq 8) or 'parity' (eq 4, needs clusters = 8)")
    sweeps: int = Field(1000, ge=0, le=100000, description="simulated-annealing sweeps over all probes")
    regularization: float = Field(0.001, ge=0.0, le=10.0, description="λ of eq 8")
    sigma: float = Field(0.5, ge=0.0, le=8.0, description="Gaussian filter of the masks, in refined-grid samples")
    light_aware: bool = Field(False, description="fit the masks to the light field (eq 9) after eq 5")
    light_aware_penalty: float = Field(0.001, ge=0.0, le=10.0,
                                       description="λ of eq 9's penalty on channels that were 0 before the fit")
    compress_tolerance: float = Field(0.0, ge=0.0, le=0.5,
                                      description="merge mask blocks whose values differ by at most this (0 = lossless)")

    @model_validator(mode="after")
    def _parity_needs_8(self) -> "MasksSection":
        if self.coloring == "parity" and self.clusters != 8:
            raise ValueError("coloring 'parity' (MD eq 4) needs clusters = 8")
        return self


class LightRange(_Strict):
    """A random-light distribution for PRT datasets (PRT §4.1)."""

    types: list[Literal["point", "spot", "directional"]] = Field(["point"], min_length=1)
    count: int = Field(1, ge=1, le=8, description="lights per configuration")
    box: Box | None = Field(None, description="where point/spot lights are placed; default: the scene bounds")
    color_min: Vec3 = Field((1.0, 1.0, 1.0), description="linear RGB, per channel lower bound")
    color_max: Vec3 = Field((1.0, 1.0, 1.0), description="linear RGB, per channel upper bound")
    intensity_min: float = Field(1.0, ge=0.0, le=1e9)
    intensity_max: float = Field(10.0, ge=0.0, le=1e9)


class PrtSection(_Strict):
    """Data-driven PRT (PRT §3-5; stage prt). Off unless enabled."""

    enabled: bool = Field(False, description="bake a relightable transfer")
    scenario: LightRange = Field(default_factory=LightRange)
    configurations: int = Field(128, ge=4, le=4096, description="N, random lighting configurations")
    measurement_points: int = Field(256, ge=4, le=65536, description="M, blue-noise points on the surfaces")
    supersampling: int = Field(1, ge=1, le=64, description="direct samples averaged per measurement point (§5.1)")
    basis: int = Field(16, ge=1, le=512, description="n, basis vectors kept")
    ridge: float = Field(1e-3, ge=0.0, le=1e3, description="λ of eq 14 (0 = pseudo-inverse, eq 13)")
    gamma: float | None = Field(None, gt=0.0, le=4.0, description="work in gamma space with this exponent (§5.3)")
    channels: Literal["mono", "multi"] = Field("mono", description="mono: one basis for each colour channel (§5.2)")
    lightmap: int = Field(256, ge=0, le=4096, description="lightmap resolution (0 = no lightmap target)")


class CameraSpec(_Strict):
    """A camera given by hand: world-space position and target, metres; vertical field of view, degrees."""

    position: Vec3
    target: Vec3
    fov_y: float | None = Field(None, gt=1.0, lt=179.0)
    name: str | None = Field(None, max_length=32, pattern=r"^[a-z0-9_-]+$")


class EvaluateSection(_Strict):
    """Previews and metrics of every GI mode against a path-traced reference (DESIGN stage 7; stage evaluate)."""

    enabled: bool = Field(False, description="render previews and metrics against a path-traced reference "
                                            "(slow: minutes per camera at 64 spp on this CPU; needs EGL/Mesa)")
    cameras: int | list[CameraSpec] = Field(3, description="auto-placed camera count (0..16), or a list of cameras")
    width: int = Field(512, ge=16, le=4096)
    height: int = Field(384, ge=16, le=4096)
    fov_y: float = Field(60.0, gt=1.0, lt=179.0, description="degrees, for auto-placed cameras")
    spp: int = Field(64, ge=1, le=4096, description="path-traced reference samples per pixel")
    bounces: int | None = Field(None, ge=1, le=256, description="reference bounces; default: the light stage's")
    modes: list[Literal["direct", "leaking", "ddgi", "mask", "mask_normalized", "prt"]] | None = Field(
        None, description="modes to evaluate; default: every mode the bake has data for")
    repeats: int = Field(5, ge=1, le=100, description="timed repeats of each shading pass (median reported)")
    flip: bool = Field(True, description="compute FLIP (slow on large images)")

    @field_validator("cameras")
    @classmethod
    def _camera_count(cls, v):
        if isinstance(v, int) and not 0 <= v <= 16:
            raise ValueError("cameras must be 0..16 or a list")
        return v


class BakeConfig(_Strict):
    """A bake's settings, one section per stage.

    A stage's cache key is the hash of its section (and the keys of its inputs), so a
    change to one section re-runs that stage and those after it only.
    """

    seed: int = Field(0, ge=0, le=2**31 - 1, description="seed for every random choice of the bake")
    scene: SceneSection = Field(default_factory=SceneSection)
    place: PlaceSection = Field(default_factory=PlaceSection)
    trace: TraceSection = Field(default_factory=TraceSection)
    light: LightSection = Field(default_factory=LightSection)
    visibility: VisibilitySection = Field(default_factory=VisibilitySection)
    masks: MasksSection = Field(default_factory=MasksSection)
    prt: PrtSection = Field(default_factory=PrtSection)
    evaluate: EvaluateSection = Field(default_factory=EvaluateSection)

    def section_hash(self, *names: str) -> str:
        """sha256 (hex) of the canonical JSON of the named sections (``"seed"`` allowed); a dotted name
        (``"masks.sigma"``) takes one field of a section, so a stage's key follows only what it reads."""
        data = self.model_dump(mode="json")
        picked = {}
        for n in names:
            section, _, field = n.partition(".")
            picked[n] = data[section][field] if field else data[section]
        payload = json.dumps(picked, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(payload.encode()).hexdigest()


# --------------------------------------------------------------------------- manifest


class ArtifactInfo(BaseModel):
    """One file of a bundle. ``shape``/``dtype`` describe the decoded numpy array."""

    name: str
    file: str
    format: Literal["ktx2", "npy", "json", "png"]
    shape: list[int]
    dtype: str
    bytes: int
    sha256: str
    stage: str
    description: str = ""
    meta: dict[str, Any] = Field(default_factory=dict)


class StageInfo(BaseModel):
    """What one stage did: wall seconds, whether it came from cache, and its stats."""

    name: str
    seconds: float
    cached: bool = False
    cache_key: str
    stats: dict[str, Any] = Field(default_factory=dict)


class SceneSummary(BaseModel):
    id: str
    triangles: int
    bounds: list[list[float]]
    lights: int
    materials: int
    warnings: list[str] = Field(default_factory=list)


class BakeWarning(BaseModel):
    """Something that makes a bake probably wrong without failing it (an unlit scene, light that did not
    converge, ...), shown to the user by the API, the CLI and the web app.

    ``code`` is a stable machine-readable word (``not_converged``, ``unlit_scene``, ``scene`` for the scene's
    own ingest warnings, ...), ``message`` a sentence for people, ``stage`` the stage that emitted it
    (None for the scene's ingest warnings, found when the file was uploaded).
    """

    code: str
    message: str
    stage: str | None = None


class Manifest(BaseModel):
    """``manifest.json`` of a bundle (proto/bundle.md)."""

    format_version: int = FORMAT_VERSION
    kiln_version: str
    bake_id: str | None = None
    scene: SceneSummary
    config: dict[str, Any]
    grid: dict[str, Any] = Field(default_factory=dict)
    stages: list[StageInfo] = Field(default_factory=list)
    artifacts: list[ArtifactInfo] = Field(default_factory=list)
    warnings: list[BakeWarning] = Field(default_factory=list)

    def artifact(self, name: str) -> ArtifactInfo:
        for a in self.artifacts:
            if a.name == name:
                return a
        raise KeyError(name)
