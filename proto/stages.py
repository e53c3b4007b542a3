"""The stage table: names, order, what each reads, and how its cache key is made.

Shared by the API (which plans a bake and enqueues jobs by name) and the workers (which
map each name to its function in :mod:`workers.pipeline`). A stage's cache key is the
sha256 of its name and version, the config sections it reads, and the keys of the stages it
reads (the first stage reads the scene id) — so keys are known before anything runs.

Pure: nothing here writes. :func:`build_manifest` and :func:`finalize_bake` read finished stages' records
through any :class:`StageRecords` (``persist.store.Store`` is one) and return what the caller writes.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, replace
from typing import Protocol

from proto.models import ArtifactInfo, BakeConfig, BakeWarning, Manifest, SceneSummary, StageInfo

KILN_VERSION = "0.1.0"


@dataclass(frozen=True)
class StageDef:
    name: str
    version: int                        # bump when the stage's output for the same inputs changes
    sections: tuple[str, ...]           # BakeConfig sections (and "seed") that the stage reads
    inputs: tuple[str, ...]             # upstream stages whose artifacts/stats it reads
    timeout: int = 3600                 # seconds, for the RQ job
    shards_from: str | None = None      # "section.field" giving a shard count: the stage fans out
    inputs_when: tuple[tuple[str, str], ...] = ()   # (stage, "section.field"): read only when that field is true
    # set on the expanded entries of a sharded stage (see expand):
    shard: int | None = None            # this entry is shard `shard` of `shard_count` of `parent`
    shard_count: int | None = None
    parent: str | None = None


REFERENCE_FIELDS = ("enabled", "cameras", "width", "height", "fov_y", "spp", "check_spp", "dark_spp", "preview_spp",
                    "bounces", "surface_points", "sampling", "points", "previews")
"""The ``evaluate`` fields the ``reference`` stage reads (its cache key): not the modes, repeats or FLIP."""

STAGES: tuple[StageDef, ...] = (
    # 2: stats["warnings"] (unlit_scene, light_outside_scene); 3: the `scene` artifact (GLB)
    StageDef("ingest", 3, ("scene",), (), timeout=600),
    # 7: stats["warnings"] grid_coarse (the default budget binds the automatic grid far above what the rooms ask);
    # 8: the automatic spacing room scale / 8 (was / 6; workers/kernels/autogrid.py ROOM_DIVISIONS)
    # 9: the bake frame: the grid turned about +Y to the walls (workers/kernels/frame.py; stats["frame"], grid.frame)
    # 10: no floor of 0.05 m on the automatic spacing (a scene of a few cm got a 4 x 3 x 3 grid; autogrid.choose_grid)
    # 11: a thin open scene's box grown to the room scale along its thin axes (a lone floor's one layer of probes lay
    # in its plane) (autogrid.choose_grid); grid_coarse from
    # 2x the wanted spacing in an enclosed scene (stats["warnings"])
    StageDef("place", 11, ("place", "seed"), ("ingest",), timeout=600),
    # relocate 3: the iterations after the first trace only the probes that can still move (kernels/relocation.py settled)
    StageDef("relocate", 3, ("trace", "seed"), ("ingest", "place"), timeout=3600),
    # trace 2: depth_moments stored as RG16F (workers/kernels/precision.py), float32 kept as internal depth_moments_full
    # 3: depth_moments' far texels clamped to the probe's reach (workers/kernels/depth_moments.py clamp_far), which
    # reads the runtime's self-shadow bias; OFF probes' moments 0; stored without the tile borders (proto/atlas.py);
    # 4: trace.ray_rotations patterns across the probes (ray_directions (K, R, 3), ray_pattern; kernels/sampling.py)
    StageDef("trace", 4, ("trace", "light.self_shadow_bias", "seed"), ("ingest", "place", "relocate"), timeout=3600),
    # light 3: point lights' hot spots sampled from the light (workers/kernels/light_spots.py); 4: L2 deringing
    # against the probe's own map (workers/kernels/sh.py sh_l2_floor); 5: irradiance and SH volumes RGBA16F,
    # probe_sh a KTX2 table (issue 17); 6: irradiance E5B9G9R9_UFLOAT_PACK32 without the tile borders,
    # probe_sh a half-float table; 7: bent shading normals shaded as Cycles 3.4 does (workers/kernels/shading.py);
    # 8: near-field occlusion at the probe-ray hits (workers/kernels/probe_hits.py near_occlusion); 9: adaptive rays
    # (workers/kernels/adaptive_rays.py: extra rays traced here, their rotations seeded, so the key holds the seed);
    # 10: L2 SH windowed where it rings below 0 between the texel directions (workers/kernels/sh.py sh_l2_nonnegative);
    # 11: the bounces' gather reads each probe's L2 SH, not its 8-texel map (light.gather, workers/kernels/gather.py)
    # 12: the series' geometric tail added at the stop (workers/kernels/convergence.py);
    # 13: a probe's extra ray sets take rotations from a hash of the probe, not the row's number, and light.extra_sets
    # defaults to 7 (workers/kernels/adaptive_rays.py extra_patterns)
    StageDef("light", 13, ("light", "seed"), ("ingest", "place", "relocate", "trace"), timeout=3600),
    # visibility 2: rays stop max(1e-4 x the scene's diagonal, 16 float32 spacings) before their target, not 1e-4 x
    # max(diagonal, largest coordinate) (workers/kernels/visibility.py TFAR_EPS: scenes away from the origin)
    StageDef("visibility", 2, ("visibility.samples_per_cell", "visibility.rays", "visibility.jitter", "seed"),
             ("place", "relocate", "trace"), timeout=3600, shards_from="visibility.slabs"),
    # anneal 2: anneal_loss a float32 KTX2 table (was npy float64)
    StageDef("anneal", 2, ("masks.clusters", "masks.coloring", "masks.sweeps", "masks.regularization", "seed"),
             ("place", "trace", "visibility"), timeout=3600),
    # masks 3: the cluster probe volumes moved to stage clusters; light read only by the light-aware fit (eq 9), so
    # by default the masks and their compression run beside the light stage
    StageDef("masks", 3, ("masks.sigma", "masks.light_aware", "masks.light_aware_penalty"),
             ("place", "relocate", "trace", "visibility", "anneal"), timeout=3600,
             inputs_when=(("light", "masks.light_aware"),)),
    # each cluster's probes' SH and weights (MD §3.4): what the mask modes shade with, from the light and the colouring
    StageDef("clusters", 1, (), ("trace", "light", "anneal"), timeout=3600),
    # compress 3: the mask lookup's blend takes from the offset read only the clusters the point sees
    # (compress.lookup_blend; its lookup_error stat)
    StageDef("compress", 3, ("masks.compress_tolerance", "seed"), ("place", "masks"), timeout=3600),
    # prt 2: the npy tables as KTX2 tables, the SH basis volumes RGBA16F (proto/bundle.md 5.3); 3: lights near
    # surfaces in the scenario, the L1 norm, cross-validated ridge (issue 14, artifact 5); 4: hits shaded as the light
    # stage shades them (bent normals, horizon factor, near-field occlusion: workers/kernels/prt_dataset.py)
    # 5: the light stage's SH gather (light.gather) in the dataset's bounces
    StageDef("prt", 6, ("prt", "light", "seed"), ("ingest", "place", "relocate", "trace", "light"), timeout=3600),
    # the path-traced reference, cached per scene and lighting: reads no probe stage (workers/stages/reference.py);
    # 2: noisy surface points refined too (kernels/reference.refine_points), not only dark ones; 3: which points are
    # refined is chosen on an independent pilot pass (the choice on the first pass biased values and errors low);
    # 4: stratified first directions with replicate standard errors, the pilot's Russian-roulette control variate
    # (workers/kernels/pathtrace.py); 5: path vertices with bent shading normals shaded as Cycles 3.4 does
    # 6: extra paths by the square root of each point's noise in the rmse metrics' units, pooled over neighbours
    # 7: camera points cast a denser pixel grid when sky fills the image (kernels/surface_points.camera_points)
    # 8: dark points share the first pass's paths again (kernels/reference.DARK_BUDGET), and a pilot within two
    # standard errors of the dark threshold counts as dark (zdm2's 4 dark points: 1,024 -> 98,304 paths each)
    StageDef("reference", 8, tuple(f"evaluate.{f}" for f in REFERENCE_FIELDS) + ("seed",), ("ingest",),
             timeout=7200),
    # 2: metrics at the reference's points (with standard errors), previews on its G-buffers; 3: the noise bias
    # removed from rmse and indirect_relative_rmse (workers/kernels/point_metrics.py); 4: their standard errors by
    # the delta method (the bootstrap understated them); 5: the mask modes' lookup blend takes from the offset read
    # only the clusters the point sees (compress.lookup_blend, gi_mask.glsl); 6: the eval_points artifact (each mode
    # at the points: GET /v1/compare's paired standard errors); 7: the preview reference picture and the error
    # heatmaps denoised (workers/render/previews.py denoised_radiance; the image metrics still the noisy image)
    StageDef("evaluate", 7, ("evaluate", "light.self_shadow_bias", "visibility.samples_per_cell", "seed"),
             ("ingest", "place", "relocate", "trace", "light", "visibility", "anneal", "masks", "clusters", "compress",
              "prt", "reference"), timeout=7200),
)
STAGE_BY_NAME = {s.name: s for s in STAGES}


def _field(config: BakeConfig, dotted: str):
    """The config value at ``"section.field"``."""
    section, field = dotted.split(".")
    return getattr(getattr(config, section), field)


def shard_count(config: BakeConfig, st: StageDef) -> int:
    return int(_field(config, st.shards_from))


def expand(config: BakeConfig) -> list[StageDef]:
    """The stages of a bake in run order, a sharded stage as its shards followed by its join.

    Shard ``i`` of stage ``s`` is named ``s.i``; the join keeps the name ``s`` and reads every shard. A stage's
    ``inputs_when`` entries join its inputs when their config field is true (``masks`` reads ``light`` only for the
    light-aware fit).
    """
    out: list[StageDef] = []
    for st in STAGES:
        extra = tuple(dep for dep, field in st.inputs_when if _field(config, field))
        if extra:
            st = replace(st, inputs=st.inputs + extra)
        if st.shards_from is None:
            out.append(st)
            continue
        n = shard_count(config, st)
        names = tuple(f"{st.name}.{i}" for i in range(n))
        out += [replace(st, name=nm, shard=i, shard_count=n, parent=st.name) for i, nm in enumerate(names)]
        out.append(replace(st, inputs=st.inputs + names))
    return out


def dependencies(stages: list[StageDef]) -> dict[str, list[str]]:
    """Which stages' jobs each stage's job waits for: the stages among ``stages`` that it reads
    (``StageDef.inputs``; a join reads its shards), in run order. A DAG, not the run order's chain: the
    reference waits only for ingest; visibility's shards, anneal, masks (without the light-aware fit) and compress
    for no light, so two workers run them beside the light stage, and after it only ``clusters`` and evaluate are
    left (DESIGN "Data flow"; :func:`workers.pipeline.bake_local` runs the CLI's bakes the same way)."""
    names = {st.name for st in stages}
    return {st.name: [d for d in st.inputs if d in names] for st in stages}


def plan(scene_id: str, config: BakeConfig, namespace: str | None = None) -> list[tuple[StageDef, str]]:
    """Stages in run order (shards expanded) with their cache keys (hex sha256).

    ``namespace`` (the server passes the bake's team) goes into the first stage's key and so into every
    key: one team's bakes never find another team's stage outputs in the shared store, so the cache tells a
    team nothing of what others baked. ``None`` (the CLI's in-process bakes) gives the keys without one.
    """
    keys: dict[str, str] = {}
    out = []
    for st in expand(config):
        h = hashlib.sha256()
        h.update(f"{st.name}:{st.version}:{config.section_hash(*st.sections)}".encode())
        if st.shard is not None:
            h.update(f":shard={st.shard}/{st.shard_count}".encode())
        if not st.inputs:
            h.update(f":scene={scene_id}".encode())
            if namespace is not None:
                h.update(f":namespace={namespace}".encode())
        for dep in st.inputs:
            h.update(f":{dep}={keys[dep]}".encode())
        keys[st.name] = h.hexdigest()
        out.append((st, keys[st.name]))
    return out


def _stage_warnings(stage: str, stats: dict | None) -> list[BakeWarning]:
    """A stage's ``stats["warnings"]`` (``[{"code", "message"}, ...]``) as BakeWarnings tagged with the stage.

    Lenient on purpose: a malformed entry (a plain string, a missing code) still becomes a warning rather
    than failing the bake or vanishing.
    """
    raw = (stats or {}).get("warnings") if isinstance(stats, dict) else None
    if not raw:
        return []
    if isinstance(raw, (str, dict)):
        raw = [raw]
    out = []
    for w in raw:
        if isinstance(w, dict):
            code = str(w.get("code") or "warning")
            message = str(w.get("message") if w.get("message") is not None else code)
        else:
            code, message = "warning", str(w)
        out.append(BakeWarning(code=code, message=message, stage=stage))
    return out


def collect_warnings(stages: list[tuple[str, dict | None]], scene_warnings: list[str] | None = None
                     ) -> list[BakeWarning]:
    """Every warning of a bake: the scene's ingest warnings (code ``scene``, stage None) first, then each
    stage's ``stats["warnings"]`` in stage order, tagged with the stage's name.

    ``stages`` is ``[(stage name, stats), ...]`` in run order. The shards of a sharded stage (``visibility.0``,
    ...) are tagged with their stage's name (``visibility``), and identical warnings are kept once (the same
    warning from every shard, or from a shard and its join).
    """
    out: list[BakeWarning] = [BakeWarning(code="scene", message=str(m), stage=None) for m in scene_warnings or []]
    for name, stats in stages:
        out += _stage_warnings(name.split(".", 1)[0], stats)
    seen, unique = set(), []
    for w in out:
        key = (w.code, w.message, w.stage)
        if key not in seen:
            seen.add(key)
            unique.append(w)
    return unique


class StageRecords(Protocol):
    """Where finished stages' records are read by cache key; ``persist.store.Store`` is one."""

    def get_stage(self, cache_key: str) -> dict | None:
        """The record ``{"seconds", "stats", "artifacts": [ArtifactInfo dicts]}`` of a finished stage, or None."""


def build_manifest(records: StageRecords, scene_summary: dict, config: BakeConfig, bake_id: str | None = None,
                   cached: dict[str, bool] | None = None, namespace: str | None = None) -> Manifest:
    """The bundle manifest of a bake whose stages are all in the store, with every stage's and the scene's
    warnings collected into ``warnings`` (:func:`collect_warnings`). ``namespace``: as for :func:`plan`."""
    stages, artifacts, grid = [], [], {}
    for st, key in plan(scene_summary["id"], config, namespace):
        rec = records.get_stage(key)
        if rec is None:
            raise RuntimeError(f"stage {st.name} is not in the store")
        stages.append(StageInfo(name=st.name, seconds=rec["seconds"], cache_key=key,
                                cached=(cached or {}).get(st.name, False), stats=rec["stats"]))
        # internal artifacts (e.g. cached ray hits) feed later stages but are not part of the bundle
        artifacts += [ArtifactInfo(**a) for a in rec["artifacts"] if not a.get("meta", {}).get("internal")]
        if st.name == "place":
            grid = {k: rec["stats"][k] for k in ("counts", "origin", "spacing", "layers") if k in rec["stats"]}
            if "frame" in rec["stats"]:
                grid["frame"] = rec["stats"]["frame"]   # the bake frame: world -> grid axes (proto/bundle.md 5)
            if rec["stats"].get("auto") is not None:
                grid["auto"] = rec["stats"]["auto"]     # what the automatic grid chose, and why
    warnings = collect_warnings([(s.name, s.stats) for s in stages], scene_summary.get("warnings"))
    return Manifest(kiln_version=KILN_VERSION, bake_id=bake_id, scene=SceneSummary(**scene_summary),
                    config=config.model_dump(mode="json"), grid=grid, stages=stages, artifacts=artifacts,
                    warnings=warnings)


def manifest_metrics(manifest: Manifest | dict) -> dict[str, float]:
    """The flat metrics the catalog keeps for a finished bake (dashboards, gates, quotas).

    ``stage_seconds.<stage>`` per stage (seconds), ``artifact_bytes`` (the bundle's artifacts, bytes), and the
    evaluate stage's finite numeric quality metrics ``<mode>.<metric>`` as its stats hold them (booleans, NaN and
    infinities are left out). ``manifest``: the model or its JSON form (a stored or downloaded manifest).
    """
    m = manifest.model_dump(mode="json") if isinstance(manifest, Manifest) else manifest
    metrics = {f"stage_seconds.{s['name']}": float(s.get("seconds") or 0.0) for s in m.get("stages", [])}
    metrics["artifact_bytes"] = float(sum(a.get("bytes", 0) for a in m.get("artifacts", [])))
    for s in m.get("stages", []):  # the evaluate stage's quality metrics: "<mode>.<metric>"
        if s["name"] == "evaluate":
            metrics.update({k: float(v) for k, v in ((s.get("stats") or {}).get("metrics") or {}).items()
                            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)})
    return metrics


@dataclass(frozen=True)
class Finalized:
    """What finishing a bake writes to the catalog: its ``manifest`` (JSON-ready dict) and ``metrics``."""
    manifest: dict
    metrics: dict[str, float]


def finalize_bake(bake: dict, scene: dict | None, records: StageRecords) -> Finalized:
    """The manifest and metrics of a bake whose stages are all stored; writes nothing.

    ``bake``: the catalog's bake (``id``, ``team``, ``scene_id``, ``config``, ``stages``); ``scene``: the
    catalog's scene of that team (``None`` when it is gone: a RuntimeError). The caller records the result
    (``persist.catalog.Catalog.mark_succeeded``).
    """
    config = BakeConfig.model_validate(bake["config"])
    if scene is None:
        raise RuntimeError(f"scene {bake['scene_id']} of bake {bake['id']} is not in the catalog")
    summary = {k: scene[k] for k in ("id", "triangles", "bounds", "lights", "materials", "warnings")}
    cached = {s["name"]: s["cached"] for s in bake.get("stages", [])}
    manifest = build_manifest(records, summary, config, bake_id=bake["id"], cached=cached, namespace=bake["team"])
    return Finalized(manifest=manifest.model_dump(mode="json"), metrics=manifest_metrics(manifest))
