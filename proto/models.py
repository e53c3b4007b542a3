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
import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, StrictBool, field_validator, model_validator

from proto.gi_modes import SELF_SHADOW_BIAS

FORMAT_VERSION = 1
"""Bundle format version written into every manifest (see proto/bundle.md)."""

MAX_PROBES = 1 << 20
"""Upper bound on the probe count of one grid (16x32x16 = 8192 is typical)."""

MAX_COORD = 1e7
"""Largest world-space coordinate (metres, 10,000 km) a config may name: light positions, boxes, cameras.
The same bound the upload applies to scene geometry (workers.gltf.limits.MAX_COORD)."""

MAX_COLOR = 1e6
"""Largest linear-RGB light colour component (sky radiance has the same bound)."""


Int = Annotated[int, Strict()]
"""An int that refuses strings, booleans and fractions (``"4"``, ``true``, ``4.5``); ``4.0`` is accepted as 4
(:meth:`_Strict._integral_floats`: JSON has one number type)."""
Float = Annotated[float, Strict()]
"""A float that refuses strings and booleans (ints are accepted); NaN/inf are refused by the models' config."""
Bool = StrictBool
"""``true``/``false`` only: ``1``, ``"true"`` and ``"yes"`` are refused."""

Vec3 = tuple[Float, Float, Float]
Count = Annotated[Int, Field(ge=1, le=256)]


class _Strict(BaseModel):
    # allow_inf_nan=False: NaN and +-inf (JSON's NaN/Infinity literals, TOML's nan/inf) are refused in every
    # float field with "Input should be a finite number" at the field's path.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _integral_floats(cls, data: Any) -> Any:
        """``4.0`` where an int is expected is 4: integral floats (here and in lists) become ints before the
        strict fields see them; float fields take the int back as a float, so nothing else changes. Numpy
        scalars (Python callers) become the Python number or bool they hold."""
        if isinstance(data, dict):
            return {k: _integral(v) for k, v in data.items()}
        return data


def _integral(v: Any) -> Any:
    if hasattr(v, "dtype") and hasattr(v, "tolist"):  # a numpy scalar or array
        v = v.tolist()
    if isinstance(v, float) and v.is_integer() and abs(v) < 2.0**63:
        return int(v)
    if isinstance(v, (list, tuple)):
        return [_integral(x) if not isinstance(x, (dict, list, tuple)) else x for x in v]
    return v


def _finite(v: Vec3 | None, name: str, bound: float = MAX_COORD) -> Vec3 | None:
    if v is not None and not all(math.isfinite(c) for c in v):
        raise ValueError(f"{name} must be finite")
    if v is not None and not all(abs(c) <= bound for c in v):
        raise ValueError(f"{name} components must be within +-{bound:g}")
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
    intensity: Float = Field(1.0, ge=0.0, le=1e9, description="candela (point, spot) or lux (directional)")
    range: Float | None = Field(None, gt=0.0, description="metres; None = infinite")
    inner_cone_angle: Float = Field(0.0, ge=0.0, le=math.pi / 2, description="radians (spot)")
    outer_cone_angle: Float = Field(math.pi / 4, gt=0.0, le=math.pi / 2, description="radians (spot)")

    @field_validator("color")
    @classmethod
    def _color_ok(cls, v: Vec3) -> Vec3:
        if not all(math.isfinite(c) and 0 <= c <= MAX_COLOR for c in v):
            raise ValueError(f"color components must be finite and in [0, {MAX_COLOR:g}]")
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
    use_scene_lights: Bool = Field(True, description="keep the lights the glTF defines")
    sky: Vec3 = Field((0.0, 0.0, 0.0), description="uniform sky radiance seen by rays that miss, linear RGB")
    max_albedo: Float | None = Field(
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
    spacing: Float | None = Field(None, gt=0.0, le=1e4, description="metres between probes")
    box: Box | None = Field(None, description="grid box; default: the scene bounds (the automatic grid: the "
                                              "bounds of its enclosed spaces)")
    budget: Int = Field(24_000, ge=8, le=MAX_PROBES, description="most probes of the automatic grid")
    padding: Float = Field(0.0, ge=0.0, le=0.5,
                           description="fraction of each extent added on both sides of the box")
    yaw: Float | None = Field(
        None, ge=-180.0, le=180.0,
        description="degrees the probe grid is turned about +Y (the bake frame, manifest grid.frame); default: "
                    "turned to the scene's dominant wall directions (0 with a `box`, or when the scene has no "
                    "dominant walls). With `yaw` set, a `box` is in the turned frame")

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

    rays_per_probe: Int = Field(256, ge=16, le=4096, description="rays per probe, spherical Fibonacci pattern")
    ray_rotations: Int = Field(64, ge=1, le=64,
                               description="random rotations of the ray pattern across the probes (1: every probe "
                                           "the same, as the DDGI runtime per frame; 8 or more: the 8 corners of "
                                           "every grid cell differ, so the errors of a small bright opening seen "
                                           "by few rays average out instead of adding up)")
    relocate_iterations: Int = Field(5, ge=0, le=20, description="iterations of the DDGI-P Fig 7 optimizer")
    max_offset: Float = Field(0.45, ge=0.0, le=0.5, description="relocation limit, fraction of the spacing per axis")
    rescue_offset: Float = Field(0.95, ge=0.0, lt=1.0,
                                 description="a probe still inside geometry after the iterations moves to the "
                                             "nearest free space within this fraction of the spacing per axis "
                                             "(0: off, as DDGI-P)")
    backface_fraction: Float = Field(0.25, gt=0.0, lt=1.0,
                                     description="a probe seeing more backfaces than this is inside geometry")
    depth_texels: Int = Field(16, ge=4, le=64, description="octahedral depth-moment map size per probe (+1 border)")
    depth_sharpness: Float = Field(50.0, ge=1.0, le=200.0,
                                   description="exponent of the max(0, cos) weight of depth moments (RTXGI default 50)")


class LightSection(_Strict):
    """Multi-bounce probe irradiance (DDGI-I §3.4-3.5; stage light)."""

    bounces: Int | None = Field(None, ge=1, le=256, description="a fixed number of bounces; default: until converged")
    max_bounces: Int = Field(128, ge=1, le=1024, description="cap when iterating to convergence")
    tolerance: Float = Field(0.005, gt=0.0, le=0.5,
                             description="stop when the light unaccounted for (the uncertainty of each probe's "
                                         "geometric tail, which is then added; the tail itself while it exceeds "
                                         "a quarter of the light) is below this fraction of the probe's light, "
                                         "at every probe")
    irradiance_texels: Int = Field(8, ge=4, le=32, description="octahedral irradiance map size per probe (+1 border)")
    sh_order: Literal[1, 2] = Field(2, description="spherical-harmonics order of the per-probe SH output")
    self_shadow_bias: Float = Field(SELF_SHADOW_BIAS, ge=0.0, le=2.0,
                                    description="B of DDGI-P eq 2")  # default: proto/gi_modes.json
    near_radius: Float = Field(1.5, ge=0.0, le=4.0,
                               description="near-field occlusion at the probe-ray hits: geometry within this many "
                                           "probe spacings (the smallest axis) of a hit covers part of its "
                                           "hemisphere that the probes, up to a cell away, see as far field "
                                           "(workers/kernels/probe_hits.py near_occlusion; 0 = off)")
    near_rays: Int = Field(8, ge=0, le=256, description="near-field occlusion rays per probe-ray hit (0 = off)")
    near_strength: Float = Field(0.25, ge=0.0, le=1.0,
                                 description="the weight s of the near-field term: E_indirect = (1 - s·a)·G + "
                                             "s·a·(the nearby surface's light), a the occluded part of the hit's "
                                             "hemisphere; a fit against the path tracer on three held-out interiors "
                                             "(docs/architecture.md, near-field occlusion)")
    gather: Literal["sh", "octahedral"] = Field(
        "sh", description="what each probe reports at a probe-ray hit in the bounces: 'sh' its L2 SH irradiance at "
                          "the hit's normal (projected from the bounce's own rays), 'octahedral' its irradiance map "
                          "(bilinear, as DDGI's runtime reads it; at an angle to a wall an 8-texel map reads the "
                          "dim side of a door high and a room lit through it 10-20% bright: docs/architecture.md)")
    extra_rays: Float = Field(0.5, ge=0.0, le=8.0,
                              description="adaptive probe rays: extra sets of trace.rays_per_probe rays, this "
                                          "fraction of the live probes' count in all, to the probes whose few rays "
                                          "see a small bright thing (a lit room through a door), in proportion to "
                                          "the noise of their first-bounce light (workers/kernels/adaptive_rays.py; "
                                          "0 = off)")
    extra_sets: Int = Field(7, ge=0, le=15, description=(
        "the most extra ray sets one probe gets (7: with 3 every probe that saw a bright thing got 3, the allocation "
        "capped flat instead of following the noise; docs/architecture.md, adaptive rays)"))

    @field_validator("sh_order", mode="before")
    @classmethod
    def _sh_order_not_bool(cls, v: Any) -> Any:
        if isinstance(v, bool):  # a Literal[1, 2] would take true as 1
            raise ValueError("sh_order must be the number 1 or 2, not a boolean")
        return v


class VisibilitySection(_Strict):
    """The visibility field θ of MD §3.4 step 1 (stage visibility)."""

    samples_per_cell: Int | None = Field(
        None, ge=1, le=32, description="refined-grid samples per cell axis (S); default: the automatic grid's "
                                       "choice (both sides of the thinnest walls), else 8")
    rays: Int = Field(1, ge=1, le=64, description="occlusion rays per sample and probe: 1 = binary, more = soft")
    jitter: Float = Field(0.05, ge=0.0, le=0.5,
                          description="radius of the jittered ray targets around a probe, fraction of the spacing")
    slabs: Int = Field(4, ge=1, le=256,
                       description="RQ jobs the field is split into (z slabs of whole cell layers; "
                                   "slabs beyond the layer count are empty); the result does not depend on it")


class MasksSection(_Strict):
    """Mask Decomposition (MD §3.2-3.4; stages anneal, masks, compress)."""

    clusters: Int = Field(4, ge=1, le=8, description="K, the number of probe clusters (mask channels)")
    coloring: Literal["anneal", "parity"] = Field(
        "anneal", description="'anneal' (MD §3.3, eq 7 + eq 8) or 'parity' (eq 4, needs clusters = 8)")
    sweeps: Int = Field(1000, ge=0, le=100000, description="simulated-annealing sweeps over all probes")
    regularization: Float = Field(0.001, ge=0.0, le=10.0, description="λ of eq 8")
    sigma: Float = Field(0.5, ge=0.0, le=8.0, description="Gaussian filter of the masks, in refined-grid samples")
    light_aware: Bool = Field(False, description="fit the masks to the light field (eq 9) after eq 5")
    light_aware_penalty: Float = Field(0.001, ge=0.0, le=10.0,
                                       description="λ of eq 9's penalty on channels that were 0 before the fit")
    compress_tolerance: Float = Field(
        0.095, ge=0.0, le=0.5,
        description="merge mask blocks whose values differ by at most this, and store blocks within it of all 0 / "
                    "all 1 as constants (0 = lossless; the default, 24/255, added 0.09% RMSE to mask GI on zdm2: "
                    "tests/bench/bench_md.py)")

    @model_validator(mode="after")
    def _parity_needs_8(self) -> "MasksSection":
        if self.coloring == "parity" and self.clusters != 8:
            raise ValueError("coloring 'parity' (MD eq 4) needs clusters = 8")
        return self


class LightRange(_Strict):
    """A random-light distribution for PRT datasets (PRT §4.1)."""

    types: list[Literal["point", "spot", "directional"]] = Field(["point"], min_length=1)
    count: Int = Field(1, ge=1, le=8, description="lights per configuration")
    box: Box | None = Field(None, description="where point/spot lights are placed (world axes; in a turned bake "
                                                  "frame, place.yaw, its bounding box there); default: the scene bounds")
    near_surface: Float = Field(0.5, ge=0.0, le=1.0, description="share of point/spot lights placed close to a "
                                "surface (near_distance along its normal) instead of uniformly in the box")
    near_distance: tuple[Float, Float] = Field((0.02, 0.25), description="metres from the surface, min and max")
    color_min: Vec3 = Field((1.0, 1.0, 1.0), description="linear RGB, per channel lower bound")
    color_max: Vec3 = Field((1.0, 1.0, 1.0), description="linear RGB, per channel upper bound")
    intensity_min: Float = Field(1.0, ge=0.0, le=1e9)
    intensity_max: Float = Field(10.0, ge=0.0, le=1e9)

    @field_validator("color_min", "color_max")
    @classmethod
    def _color_ok(cls, v: Vec3) -> Vec3:
        if not all(0 <= c <= MAX_COLOR for c in v):
            raise ValueError(f"color components must be in [0, {MAX_COLOR:g}]")
        return v

    @field_validator("near_distance")
    @classmethod
    def _near_ok(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= v[0] <= v[1]:
            raise ValueError("near_distance must be (min, max) metres with 0 <= min <= max")
        return v


class PrtSection(_Strict):
    """Data-driven PRT (PRT §3-5; stage prt). Off unless enabled."""

    enabled: Bool = Field(False, description="bake a relightable transfer")
    scenario: LightRange = Field(default_factory=LightRange)
    configurations: Int = Field(128, ge=4, le=4096, description="N, random lighting configurations")
    measurement_points: Int = Field(256, ge=4, le=65536, description="M, blue-noise points on the surfaces")
    supersampling: Int = Field(1, ge=1, le=64, description="direct samples averaged per measurement point (§5.1)")
    basis: Int = Field(16, ge=1, le=512, description="n, basis vectors kept")
    ridge: Float = Field(1e-2, ge=0.0, le=1e3, description="λ of eq 14 (0 = pseudo-inverse, eq 13) if ridge_folds = 0")
    ridge_folds: Int = Field(4, ge=0, le=32, description="choose λ of eq 14 by this many-fold cross-validation over "
                             "the configurations (0: use ridge)")
    norm: Literal["l1", "l2"] = Field("l1", description="‖x‖ that normalizes the dataset (§4.2): l1 (sum, the "
                                      "reflected power) or l2")
    gamma: Float | None = Field(None, gt=0.0, le=4.0, description="work in gamma space with this exponent (§5.3)")
    channels: Literal["mono", "multi"] = Field("mono", description="mono: one basis for each colour channel (§5.2)")
    lightmap: Int = Field(256, ge=0, le=4096, description="lightmap resolution (0 = no lightmap target)")


class CameraSpec(_Strict):
    """A camera given by hand: world-space position and target, metres; vertical field of view, degrees."""

    position: Vec3
    target: Vec3
    fov_y: Float | None = Field(None, gt=1.0, lt=179.0)
    name: str | None = Field(None, max_length=32, pattern=r"^[a-z0-9_-]+$")

    @model_validator(mode="after")
    def _check(self) -> "CameraSpec":
        _finite(self.position, "position")
        _finite(self.target, "target")
        return self


class CheckPoints(_Strict):
    """Check points: where a level designer or a build tool reads the light (glTF coordinates, metres).

    Each point gets its normals (one per point), else the 6 axis normals +X, -X, +Y, -Y, +Z, -Z in that order;
    ``regions`` names groups of point indices (the fidelity points files' layout) for per-region mean ratios.
    """

    points: list[Vec3] = Field(..., min_length=1, max_length=4096)
    normals: list[Vec3] | None = Field(None, description="one normal per point (need not be unit); default: the "
                                                         "6 axis normals +X, -X, +Y, -Y, +Z, -Z per point")
    regions: dict[str, list[Int]] | None = Field(None, description="region name -> indices into points: "
                                                                   "per-region metrics (mean ratio)")

    @model_validator(mode="after")
    def _check(self) -> "CheckPoints":
        for i, p in enumerate(self.points):
            _finite(p, f"points[{i}]")
        if self.normals is not None:
            if len(self.normals) != len(self.points):
                raise ValueError(f"normals: give one per point ({len(self.points)}), got {len(self.normals)}")
            for i, n in enumerate(self.normals):
                _finite(n, f"normals[{i}]")
                if sum(c * c for c in n) < 1e-12:
                    raise ValueError(f"normals[{i}] must not be zero")
        for name, idx in (self.regions or {}).items():
            if not re.fullmatch(r"[A-Za-z0-9_-]{1,32}", name):
                raise ValueError(f"region name {name!r}: 1-32 letters, digits, '_' or '-'")
            if not idx or any(not 0 <= i < len(self.points) for i in idx):
                raise ValueError(f"region {name!r} needs indices into points (0..{len(self.points) - 1})")
        return self


class EvaluateSection(_Strict):
    """Metrics of every GI mode against a path-traced reference at surface points, and previews (DESIGN stage 7;
    stages reference + evaluate).

    The reference (stage ``reference``) depends only on the scene, its lighting and the fields marked
    "reference" below, so every bake of a scene with the same lighting reuses it, whatever its probe config."""

    enabled: Bool = Field(True, description="metrics at surface points and previews against a path-traced "
                                           "reference (the reference is cached per scene and lighting: measured "
                                           "12-19% of a first default bake, under 4% of a re-bake)")
    cameras: Int | list[CameraSpec] = Field(3, description="reference: review cameras: an auto-placed count "
                                                           "(0..16; the glTF's own cameras when it has any, or the "
                                                           "scene's stored review cameras), or a list of cameras")
    width: Int = Field(160, ge=16, le=4096, description="reference: preview width, pixels")
    height: Int = Field(120, ge=16, le=4096, description="reference: preview height, pixels")
    fov_y: Float = Field(60.0, gt=1.0, lt=179.0, description="reference: degrees, for auto-placed cameras")
    spp: Int = Field(192, ge=1, le=65536, description=(
        "reference: paths per surface point (192: the metrics' noise, workers/kernels/point_metrics.py)"))
    check_spp: Int | None = Field(None, ge=1, le=262144, description=(
        "reference: paths per check-point normal; default max(spp, 8192): check points are few and a level "
        "designer reads each one, so each gets a low-noise value (measured on two rooms: a region of a room lit "
        "only through a doorway scatters ±2% between seeds at 8192-16384 paths, up to 11% at 2048)"))
    dark_spp: Int = Field(1024, ge=0, le=262144, description=(
        "reference: the most paths per surface point that is not dark, the fewest per dark one. Dark points "
        "(luminance at most twice the leak metric's threshold, 10% of the mean, or within two standard errors of "
        "it: the leak metrics are computed there) share as many paths as the first pass had (N x spp), each at "
        "least this many and at most 131072 (zdm2: 4 dark points of 2048, about 98k paths each); the others spp·2^k "
        "up to it, more where their noise in the rmse metrics' units "
        "(pooled over 16 neighbouring points) is larger, at most as many extra paths as the first pass; both judged on an independent "
        "pilot pass of spp/4 paths, so the choice does not bias the values; 0 or <= spp: none (and no pilot)"))
    preview_spp: Int = Field(4, ge=1, le=4096, description="reference: paths per preview pixel (pictures only, "
                                                           "never metrics)")
    bounces: Int | None = Field(None, ge=1, le=256, description="reference: path bounces; default 64 with "
                                                                "Russian roulette (the converged light)")
    surface_points: Int = Field(2048, ge=0, le=65536, description="reference: stratified surface points the "
                                                                  "metrics are computed at")
    sampling: Literal["cameras", "area"] = Field(
        "cameras", description="reference: surface points on the surfaces the review cameras see, or uniform by "
                               "area on front faces in free space (also without cameras)")
    points: CheckPoints | None = Field(None, description="reference: check points (artifact check_points)")
    previews: Int = Field(1, ge=0, le=16, description="reference: how many review cameras (the first ones) get "
                                                      "preview images and shading-pass timings (0 = none; needs "
                                                      "EGL/Mesa, skipped with a warning without it)")
    modes: list[Literal["direct", "leaking", "ddgi", "mask", "mask_normalized", "prt"]] | None = Field(
        None, description="modes to evaluate; default: every mode the bake has data for")
    repeats: Int = Field(0, ge=0, le=100, description="timed repeats of each shading pass (median reported, after "
                         "a warm-up draw); 0: the time of the preview's own second draw, one sample and no extra draw "
                         "(tests/bench/bench_evaluate.py times with 7 for MD Table 1)")
    flip: Bool = Field(False, description="compute FLIP on the previews (about 0.1 s per mode and camera at "
                                          "160x120; against a low-spp preview reference)")

    @field_validator("cameras")
    @classmethod
    def _camera_count(cls, v):
        if isinstance(v, int) and not 0 <= v <= 16:
            raise ValueError("cameras must be 0..16 or a list")
        if isinstance(v, list) and len(v) > 16:
            raise ValueError("at most 16 cameras")
        return v

    def effective_check_spp(self) -> int:
        """Paths per check-point normal: ``check_spp``, default max(``spp``, :data:`CHECK_SPP_DEFAULT`)."""
        return int(self.check_spp) if self.check_spp else max(int(self.spp), CHECK_SPP_DEFAULT)


CHECK_SPP_DEFAULT = 8192
"""Paths per check-point normal unless ``evaluate.check_spp`` says: a region of two-rooms lit only through its
doorway scatters about ±2% between seeds at 8192-16384 paths (heavy tails: the rare paths through the door that
reach the lit room), 11% high at 2048 (tests/bench/bench_evaluate.py --cost --cycles-spp N)."""


class BakeConfig(_Strict):
    """A bake's settings, one section per stage.

    A stage's cache key is the hash of its section (and the keys of its inputs), so a
    change to one section re-runs that stage and those after it only.
    """

    seed: Int = Field(0, ge=0, le=2**31 - 1, description="seed for every random choice of the bake")
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
    format: Literal["ktx2", "npy", "json", "png", "glb"]
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
