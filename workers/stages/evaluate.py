"""Stage ``evaluate``: every GI mode scored against the cached path-traced reference, and previews (DESIGN stage 7).

Reads ``reference`` (surface points, check points, review cameras, preview G-buffers and reference images —
cached per scene and lighting, independent of the probe config; layout :mod:`workers.kernels.reference_layout`)
and the bake's data: ``ingest`` (lights), ``place`` (grid), ``relocate``, ``trace``, ``light``, ``masks``,
``compress`` and, when enabled, ``prt``. Config: ``config.evaluate``.

- **Metrics**, from the points only: each mode's indirect irradiance on the CPU
  (:func:`workers.kernels.point_modes.mode_irradiance`, the Python twins of the GLSL modes) scored against the
  reference (:func:`workers.kernels.point_metrics.point_summary`: ``<mode>.rmse`` (MD §4.2), ``.leak``,
  ``.indirect_relative_rmse``, ``.indirect_excess``, ``.mean_ratio``, each with ``_stderr``; at check points with
  regions :func:`~workers.kernels.point_metrics.check_point_report`), plus ``<mode>.texture_bytes`` and
  ``<mode>.gi_fetches_per_pixel`` / ``_max`` (:func:`workers.kernels.point_modes.gi_fetches`).
- **Previews** (pictures; timing and image metrics only): :func:`workers.render.previews.mode_previews`.

Artifacts: ``check_points`` (json; with ``evaluate.points``: points, normals, reference_direct,
reference_indirect, reference_stderr ([point][normal] RGB), modes {mode: [point][normal] RGB}, regions),
``eval_metrics`` (json), ``eval_cameras`` (json), ``eval_points`` (npy (N, 3 x modes) float32, internal: each
mode's indirect irradiance at the reference's surface points, modes in ``meta.modes`` order; what
``GET /v1/compare`` pairs with another bake of the same reference:
:func:`workers.kernels.point_metrics.paired_delta_stderr`), and with previews ``eval_<cam>_<mode>`` (PNG, ``<mode>`` also
``reference``), ``eval_<cam>_<mode>_error`` heatmaps, ``eval_contact``. Stats: ``metrics`` (flat, for the catalog,
compare and ``kiln bake --fail-on``), ``cameras``, ``points``, ``check_points``, ``modes``.
"""
from __future__ import annotations

import time

import numpy as np

from proto.models import EvaluateSection
from workers.kernels import point_metrics as PM
from workers.kernels.frame import frame_of, rotate_lights, to_frame
from workers.kernels.point_modes import MaskArrays, available_modes, gi_fetches, mode_irradiance
from workers.kernels.reference_layout import point_columns
from workers.render.previews import HEATMAP_VMAX, mode_previews, mode_resources, png_supported
from workers.stages.base import Artifact, LazyArtifacts, StageContext, StageOutput, jsonable, samples_per_cell

INPUTS = ("light", "relocate", "trace", "masks", "clusters", "compress", "prt")
"""The stages whose artifacts the modes read, by name (a later stage's name wins)."""
SETTINGS = ("cameras", "width", "height", "fov_y", "spp", "preview_spp", "bounces", "surface_points", "sampling",
            "previews", "modes", "repeats", "flip")


def settings_of(config) -> dict:
    """``config.evaluate`` as the stage reads it and records in ``eval_metrics`` (the :data:`SETTINGS` fields;
    review cameras without their unset optional fields: the defaults apply)."""
    d = (getattr(config, "evaluate", None) or EvaluateSection()).model_dump()
    if isinstance(d.get("cameras"), list):
        d["cameras"] = [{k: v for k, v in c.items() if v is not None} for c in d["cameras"]]
    return {k: d[k] for k in SETTINGS}


class _Lazy(dict):
    """The bake's artifacts by name (of the :data:`INPUTS` stages), each loaded on first access."""

    def __init__(self, ctx: StageContext):
        super().__init__({n: ctx.inputs[st] for st in INPUTS if st in ctx.inputs for n in ctx.inputs[st].names()})

    def __getitem__(self, k):
        v = dict.__getitem__(self, k)
        if isinstance(v, LazyArtifacts):           # not loaded yet
            v = v[k]
            dict.__setitem__(self, k, v)
        return v


def _timing(key: str) -> bool:
    """Whether a metric is a wall time (``pass_ms``, ``pass_ms_min``, their ratios): not reproducible."""
    return key.split(".")[-1] in ("pass_ms", "pass_ms_min")


def run_evaluate(ctx: StageContext) -> StageOutput:
    t_start = time.perf_counter()
    sec = getattr(ctx.config, "evaluate", None)
    if sec is not None and not sec.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    settings, seed, B = settings_of(ctx.config), int(ctx.config.seed), float(ctx.config.light.self_shadow_bias)
    ref, place, lights = ctx.inputs["reference"], ctx.inputs["place"].stats, ctx.inputs["ingest"]["lights"]["lights"]
    rstats, grid, lights = ref.stats, {k: place[k] for k in ("counts", "origin", "spacing", "layers") if k in place}, list(lights)
    # the reference's points, cameras and the lights are in the world; the bake's GI in its frame (grid.frame): every
    # GI lookup maps its world points, normals and views with M (workers/kernels/frame.py), the PRT mode's lights too
    M = frame_of(place)
    frame_lights = rotate_lights(lights, M)
    arrays = _Lazy(ctx)
    have = available_modes(arrays)
    if "prt" in have and not (ctx.inputs.get("prt") and ctx.inputs["prt"].stats.get("enabled", True)):
        have.remove("prt")
    modes = [m for m in (settings["modes"] or have) if m in have]
    mask_meta = caster = prt_model = None
    if "mask" in modes or "mask_normalized" in modes:
        S, cst = samples_per_cell(ctx.config, place), ctx.inputs["compress"].stats
        T = int(cst["block_size"])
        mask_meta = {"samples_per_cell": S, "block_size": T, "border_lo": int(cst.get("border_lo", T - S - 1))}
    marr = MaskArrays(arrays, mask_meta)
    if "prt" in modes:
        from workers.prt_relight import PrtModel
        from workers.raycast import caster_for_scene

        caster, prt_model = caster_for_scene(ctx.scene), PrtModel.from_arrays(arrays)
    ctx.report(0.02)

    def values(m, points, normals, views):
        return mode_irradiance(m, marr, grid, to_frame(points, M), to_frame(normals, M), to_frame(views, M),
                               self_shadow_bias=B, lights=frame_lights, caster=caster, prt_model=prt_model)

    t0 = time.perf_counter()                                   # ---- the modes at the reference's points
    pts, recon = point_columns(ref["reference_points"]), {}
    for i, m in enumerate(modes):
        recon[m] = values(m, pts["position"], pts["normal"], pts["view"])
        ctx.report(0.02 + 0.4 * (i + 1) / max(len(modes), 1))
    summary, per_mode = PM.point_summary(modes, recon, pts, seed)
    t_points, t0 = time.perf_counter() - t0, time.perf_counter()
    check = (PM.check_point_report(ref["reference_check_points"], modes, lambda m, p, n: values(m, p, n, n), seed,
                                   summary) if "reference_check_points" in ref else None)
    t_check = time.perf_counter() - t0
    ctx.report(0.5)
    resources = mode_resources(modes, arrays, grid, frame_lights, caster, B, mask_meta)   # ---- textures, GI fetches
    for m in modes:
        summary[f"{m}.texture_bytes"] = float(resources[m].texture_bytes)
        if len(pts["position"]):
            f = gi_fetches(m, resources[m], marr, grid, to_frame(pts["position"], M), to_frame(pts["normal"], M),
                           to_frame(pts["view"], M))
            summary[f"{m}.gi_fetches_per_pixel"] = float(f.mean()) if f.size else 0.0
            summary[f"{m}.gi_fetches_max"] = float(f.max()) if f.size else 0.0
    ctx.report(0.6)
    t0 = time.perf_counter()                                   # ---- previews
    rdoc = ref["reference_cameras"] if "reference_cameras" in ref else {"cameras": [], "previews": []}
    pictures, info, warnings = mode_previews(
        ref, rdoc, modes, resources, lights, summary, previews=settings["previews"], repeats=settings["repeats"],
        flip=settings["flip"], report=lambda f: ctx.report(0.6 + 0.35 * f), frame=M)
    arts = [Artifact(n, data, format=fmt, description=d, meta=meta) for n, data, fmt, d, meta in pictures]
    t_previews, cameras = time.perf_counter() - t0, rstats.get("cameras") or []
    if len(pts["position"]):                                   # ---- artifacts and stats
        arts.append(Artifact("eval_points", np.ascontiguousarray(
            np.concatenate([recon[m] for m in modes], axis=1).astype(np.float32)), format="npy",
            meta={"internal": True, "modes": modes}, description="each mode's indirect irradiance at the reference's "
            "surface points ((N, 3 x modes) float32, RGB lux, modes in meta order): GET /v1/compare's paired standard "
            "errors"))
    if check is not None:
        arts.append(Artifact("check_points", jsonable(check), format="json", meta={"modes": modes, "points": len(
            check["points"])}, description="reference and every mode's indirect irradiance at the check points "
                                           "([point][normal] RGB)"))
    # the artifact holds no wall times (they live in the stats): the same bake gives the same bytes on any worker
    previews = [{**c, "modes": {m: {k: v for k, v in d.items() if not _timing(k)} for m, d in c["modes"].items()}}
                for c in info.get("per_camera", [])]
    metrics_json = {"modes": modes, "summary": {k: v for k, v in summary.items() if not _timing(k)},
                    "points": {m: per_mode.get(m) for m in modes}, "surface_points": int(len(pts["position"])),
                    "sampling": rstats.get("sampling"), "cameras": cameras,
                    "renderer": {k: v for k, v in info.items() if k != "per_camera"}, "previews": previews,
                    "settings": settings, "reference": {k: rstats.get(k) for k in (
                        "spp", "bounces", "rr_depth", "preview_spp", "camera_source")}, "heatmap_vmax": HEATMAP_VMAX,
                    "tone_map": "exposure 0.18/median reference luminance, ACES (Narkowicz), sRGB"}
    arts.append(Artifact("eval_metrics", jsonable(metrics_json), format="json", description="evaluate metrics per "
                         "mode (at the surface points, with standard errors) and per preview camera"))
    arts.append(Artifact("eval_cameras", jsonable({"cameras": rdoc.get("cameras", []), "source": rdoc.get("source")}),
                         format="json", description="the review cameras"))
    ctx.report(1.0)
    stats = {"metrics": summary, "modes": modes, "cameras": cameras, "camera_source": rstats.get("camera_source"),
             "points": int(len(pts["position"])), "sampling": rstats.get("sampling"),
             "check_points": len(check["points"]) if check else 0, "spp": rstats.get("spp"),
             "bounces": rstats.get("bounces"), "renderer": info.get("renderer"), "png": png_supported(),
             "timings": {"points_s": t_points, "check_points_s": t_check, "previews_s": t_previews},
             "seconds": time.perf_counter() - t_start}
    if warnings:
        stats["warnings"] = warnings
    return StageOutput(artifacts=arts, stats=jsonable(stats))
