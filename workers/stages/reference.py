"""Stage ``reference``: the path-traced reference the evaluate stage scores every GI mode against, cached per scene.

Reads ``ingest`` only (the resolved lights and sky; the scene with the bake's material options) and the
reference fields of ``config.evaluate`` (``enabled``, ``cameras``, ``width``, ``height``, ``fov_y``, ``spp``,
``preview_spp``, ``bounces``, ``surface_points``, ``sampling``, ``points``) and ``seed`` — nothing of the probe
grid, its trace or its light. So its cache key (proto/stages.py) is the same for every bake of a scene with the
same lighting and reference settings, whatever their probe configs: the first bake pays for it, every later one
reuses it, and every bake of the scene is scored at the same points, from the same cameras.

What it computes
----------------
1. **Review cameras** (:func:`review_cameras`): ``evaluate.cameras`` when it is a list (the server puts the
   scene's stored review cameras there, ``PUT /v1/scenes/{id}/cameras``); else the glTF's own cameras (read at
   ingest, :mod:`workers.gltf.cameras`); else ``evaluate.cameras`` cameras auto-placed in free space inside the
   scene bounds looking at geometry (:func:`workers.render.cameras.auto_cameras`, a regular grid of candidates:
   independent of the probe grid); the default outside camera when none qualifies (an open scene).
2. **Surface points** (:mod:`workers.kernels.surface_points`): ``surface_points`` stratified points on the
   surfaces the review cameras see (``sampling = "cameras"``, the default) or uniform by area on front faces in
   free space (``"area"``; also the fallback without cameras).
3. **Check points**: ``evaluate.points`` (each point with its normal, or the 6 axis normals).
4. At every surface point and check-point normal: direct irradiance (punctual lights, Embree shadow rays) and
   path-traced indirect irradiance (:func:`workers.kernels.pathtrace.indirect_irradiance`: ``spp`` paths per
   surface point, ``check_spp`` (:func:`check_spp`, default at least :data:`proto.models.CHECK_SPP_DEFAULT`) per check-point normal,
   ``bounces`` vertices (default 64: the converged light the light stage iterates to) with Russian roulette from
   vertex 3, next-event estimation of emitters) with each value's standard error from its paths. Traced in
   batches of at most :data:`BATCH_POINTS` points (fewer at high path counts: memory); progress is reported per
   batch.
5. **Previews** (needs EGL): for the first ``previews`` review cameras the G-buffer (:class:`workers.render.gbuffer.GBufferRenderer`)
   and a ``preview_spp`` reference image (:func:`workers.kernels.reference.reference_at_gbuffer`) — pictures
   only, no metric is computed from them. Without EGL the previews are skipped with a warning
   (``previews_unavailable``); the metrics do not need them.

Artifacts (all internal: they feed ``evaluate``, which writes the bundle's ``check_points`` and ``eval_*``):
``reference_points`` npy (N, 27) float32, columns :data:`POINT_COLUMNS`; ``reference_check_points`` json
(points, normals, regions, reference_direct, reference_indirect, reference_stderr: [point][normal] RGB);
``reference_cameras`` json (cameras, source); per preview camera ``reference_<cam>_gbuffer`` npy (H, W, 16)
float32 (:data:`GBUFFER_CHANNELS`), ``reference_<cam>_image`` npy (H, W, 9) float32 (e_direct, e_indirect,
radiance) and ``reference_<cam>_shadow`` npy (H, W, L) uint8 (per-light visibility, for the shading pass).
"""
from __future__ import annotations

import math
import time

import numpy as np

from workers.kernels.pathtrace import DEFAULT_MAX_PATHS, indirect_irradiance, scene_eps
from workers.kernels.reference import reference_at_gbuffer
from workers.kernels.shading import direct_irradiance
from workers.kernels.surface_points import area_points, camera_points, check_point_set
from workers.render.cameras import Camera, auto_cameras, default_camera, fit_clip_planes
from workers.stages.base import Artifact, StageContext, StageOutput, jsonable

__all__ = ["run_reference", "review_cameras", "POINT_COLUMNS", "GBUFFER_CHANNELS", "BATCH_POINTS",
           "DEFAULT_BOUNCES", "RR_DEPTH", "point_column"]

DEFAULT_BOUNCES = 64
RR_DEPTH = 3
BATCH_POINTS = 256
"""Points per path-tracing batch (one progress report each)."""
POINT_COLUMNS = ("position", "normal", "geo_normal", "view", "albedo", "emission", "e_direct", "e_indirect",
                 "stderr")
"""Column groups (3 each) of the ``reference_points`` table."""
GBUFFER_CHANNELS = ("position", "normal", "geo_normal", "albedo", "emission", "shaded")
"""Channel groups of ``reference_<cam>_gbuffer`` (3 each, ``shaded`` 1)."""
INTERNAL = {"internal": True}


def point_column(table: np.ndarray, name: str) -> np.ndarray:
    """Column group ``name`` of a ``reference_points`` table: (N, 3) float64."""
    i = POINT_COLUMNS.index(name)
    return np.asarray(table, np.float64)[:, 3 * i:3 * i + 3]


def check_spp(ev) -> int:
    """Paths per check-point normal (:meth:`proto.models.EvaluateSection.effective_check_spp`)."""
    return ev.effective_check_spp()


def _settings(config) -> dict:
    ev = config.evaluate
    return {"cameras": ev.cameras, "width": int(ev.width), "height": int(ev.height), "fov_y": float(ev.fov_y),
            "spp": int(ev.spp), "check_spp": check_spp(ev), "preview_spp": int(ev.preview_spp),
            "bounces": int(ev.bounces) if ev.bounces else DEFAULT_BOUNCES, "surface_points": int(ev.surface_points),
            "sampling": ev.sampling, "previews": int(ev.previews)}


def review_cameras(config, scene, caster) -> tuple[list[Camera], str]:
    """The review cameras of a bake and where they come from: ``"config"``, ``"gltf"``, ``"auto"`` or
    ``"default"`` (see the module doc). Names are unique and safe for artifact names."""
    ev = config.evaluate
    kw = dict(width=int(ev.width), height=int(ev.height))
    box = np.asarray(scene.bounds, np.float64)
    specs, source = None, None
    if isinstance(ev.cameras, (list, tuple)):
        specs = [c.model_dump() if hasattr(c, "model_dump") else dict(c) for c in ev.cameras]
        source = "config"
    elif getattr(scene, "cameras", None) and int(ev.cameras) > 0:
        specs, source = [dict(c) for c in scene.cameras][:16], "gltf"
    if specs is not None:
        out, taken = [], set()
        for i, d in enumerate(specs):
            name = d.get("name") or f"cam-{i}"
            while name in taken:
                name = f"{name[:28]}-{i}"
            taken.add(name)
            cam = Camera(d["position"], d["target"], fov_y=d.get("fov_y") or float(ev.fov_y), name=name, **kw)
            out.append(fit_clip_planes(cam, caster, box))
        return out, source
    n = int(ev.cameras)
    if n <= 0:
        return [], "none"
    cams = auto_cameras(caster, box, n, fov_y=float(ev.fov_y), **kw)
    if cams:
        return cams, "auto"
    return [default_camera(box, fov_y=float(ev.fov_y), **kw)], "default"


def camera_record(cam: Camera) -> dict:
    """What the manifest records of a review camera (``evaluate.cameras``)."""
    return {"name": cam.name, "position": [float(x) for x in cam.position], "target": [float(x) for x in cam.target],
            "fov": float(cam.fov_y), "width": cam.width, "height": cam.height}


class _Work:
    """Progress by path count across the parts of the stage."""

    def __init__(self, report, total: float):
        self.report, self.total, self.done = report, max(float(total), 1.0), 0.0

    def part(self, amount: float):
        start = self.done
        self.done += amount

        def rep(f: float) -> None:
            self.report(min(1.0, (start + amount * min(max(f, 0.0), 1.0)) / self.total))
        return rep


def _trace_points(scene, pts, nrm, geo, lights, sky, s, seed, caster, eps, report) -> tuple[np.ndarray, ...]:
    """Direct, indirect and stderr (N, 3) float64 at points, path traced in batches of BATCH_POINTS."""
    n = len(pts)
    e_dir = np.zeros((n, 3))
    e_ind = np.zeros((n, 3))
    err = np.zeros((n, 3))
    if n == 0:
        report(1.0)
        return e_dir, e_ind, err, {}
    if lights:
        e_dir[:] = direct_irradiance(pts, nrm, lights, caster, eps)
    stats = {"rays": 0, "seconds": 0.0, "batches": 0}
    rr = RR_DEPTH if s["bounces"] > RR_DEPTH else None
    res = indirect_irradiance(scene, pts, nrm, lights, sky=sky, spp=s["spp"], bounces=s["bounces"], seed=seed,
                              rr_depth=rr, caster=caster, eps=eps, geo_normals=geo,
                              max_paths=min(BATCH_POINTS * s["spp"], DEFAULT_MAX_PATHS), report=report)
    e_ind[:] = res.irradiance
    err[:] = res.stderr
    stats.update(rays=int(res.stats["rays"]), seconds=float(res.stats["seconds"]),
                 batches=int(math.ceil(n / BATCH_POINTS)), rr_kills=int(res.stats["rr_kills"]),
                 vertices=int(res.stats["vertices"]), below_surface=int(res.stats["below_surface"]))
    return e_dir, e_ind, err, stats


def _pack_gbuffer(gb) -> np.ndarray:
    return np.concatenate([gb.position, gb.normal, gb.geo_normal, gb.albedo, gb.emission,
                           gb.shaded[..., None].astype(np.float32)], axis=-1).astype(np.float32)


def run_reference(ctx: StageContext) -> StageOutput:
    t_start = time.perf_counter()
    ev = ctx.config.evaluate
    if not ev.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    from workers.raycast import caster_for_scene

    s = _settings(ctx.config)
    scene = ctx.scene
    lit = ctx.inputs["ingest"]["lights"]
    lights, sky = list(lit["lights"]), lit["sky"]
    caster = caster_for_scene(scene)
    eps = scene_eps(scene)
    seed = int(ctx.config.seed)
    warnings: list[dict] = []
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    cams, source = review_cameras(ctx.config, scene, caster)
    timings["cameras_s"] = time.perf_counter() - t0
    ctx.report(0.01)

    t0 = time.perf_counter()
    sampling = s["sampling"]
    sp = None
    if sampling == "cameras" and cams:
        sp = camera_points(scene, cams, s["surface_points"], seed=seed, caster=caster)
        if len(sp["position"]) < 0.1 * s["surface_points"]:
            sp = None                 # the cameras see (almost) nothing: uniform by area instead
    if sp is None:
        sampling = "area"
        sp = area_points(scene, s["surface_points"], seed=seed, caster=caster, eps=eps)
    timings["sampling_s"] = time.perf_counter() - t0
    if s["surface_points"] and len(sp["position"]) < 0.5 * s["surface_points"]:
        warnings.append({"code": "few_surface_points",
                         "message": f"only {len(sp['position'])} of {s['surface_points']} surface points could be "
                                    f"placed ({sampling} sampling): the metrics are noisier"})

    cp = ev.points
    cpts, cnrm = (check_point_set(cp.points, cp.normals) if cp is not None else (np.zeros((0, 3)),
                                                                                 np.zeros((0, 6, 3))))
    P, D = cnrm.shape[:2]
    preview_cams = cams[:s["previews"]]
    previews = bool(preview_cams)
    preview_px = sum(c.width * c.height for c in preview_cams)
    paths = len(sp["position"]) * s["spp"] + P * D * s["check_spp"] + preview_px * s["preview_spp"]
    work = _Work(ctx.report, 1.02 * paths)
    work.part(0.02 * paths)(1.0)                 # cameras and sampling

    t0 = time.perf_counter()
    e_dir, e_ind, err, pt_stats = _trace_points(scene, sp["position"], sp["normal"], sp["geo_normal"], lights, sky,
                                                s, seed, caster, eps, work.part(len(sp["position"]) * s["spp"]))
    timings["surface_points_s"] = time.perf_counter() - t0
    table = np.concatenate([sp[k] for k in POINT_COLUMNS[:6]] + [e_dir, e_ind, err], axis=1).astype(np.float32) \
        if len(sp["position"]) else np.zeros((0, 3 * len(POINT_COLUMNS)), np.float32)
    arts = [Artifact("reference_points", np.ascontiguousarray(table), format="npy",
                     description="reference at the surface points: " + ", ".join(POINT_COLUMNS) + " (3 columns each)",
                     meta={**INTERNAL, "columns": list(POINT_COLUMNS), "sampling": sampling})]

    t0 = time.perf_counter()
    c_dir, c_ind, c_err, c_stats = _trace_points(scene, np.repeat(cpts, D, axis=0), cnrm.reshape(-1, 3),
                                                 cnrm.reshape(-1, 3), lights, sky, {**s, "spp": s["check_spp"]},
                                                 seed + 0x10000, caster, eps, work.part(P * D * s["check_spp"]))
    timings["check_points_s"] = time.perf_counter() - t0
    check = None
    if cp is not None:
        check = {"points": cpts.tolist(), "normals": cnrm.tolist(), "regions": cp.regions,
                 "reference_direct": c_dir.reshape(P, D, 3).tolist(),
                 "reference_indirect": c_ind.reshape(P, D, 3).tolist(),
                 "reference_stderr": c_err.reshape(P, D, 3).tolist()}
        arts.append(Artifact("reference_check_points", check, format="json",
                             description="reference at the check points", meta=dict(INTERNAL)))

    t0 = time.perf_counter()
    preview_names = []
    if previews:
        from workers.render.context import RenderUnavailable, create_context
        from workers.render.gbuffer import GBufferRenderer
        from workers.render.shading import shadow_masks

        try:
            gl = create_context()
        except RenderUnavailable as e:
            gl = None
            warnings.append({"code": "previews_unavailable",
                             "message": f"no preview images: {e} (the metrics do not need them)"})
        if gl is not None:
            try:
                gbr = GBufferRenderer(scene, gl, caster=caster)
                try:
                    for ci, cam in enumerate(preview_cams):
                        gb = gbr.render(cam)
                        ref = reference_at_gbuffer(scene, gb, lights, sky=sky, caster=caster, eps=eps,
                                                   spp=s["preview_spp"], bounces=s["bounces"],
                                                   seed=seed + 1000 + ci,
                                                   rr_depth=RR_DEPTH if s["bounces"] > RR_DEPTH else None,
                                                   report=work.part(cam.width * cam.height * s["preview_spp"]))
                        sel = gb.shaded
                        sm = np.ones(gb.shape + (len(lights),), np.uint8)
                        if lights and sel.any():
                            sm[sel] = shadow_masks(gb.position[sel].astype(np.float64),
                                                   gb.normal[sel].astype(np.float64), lights, caster, eps)
                        name = cam.name
                        arts.append(Artifact(f"reference_{name}_gbuffer", _pack_gbuffer(gb), format="npy",
                                             description="preview G-buffer: " + ", ".join(GBUFFER_CHANNELS),
                                             meta={**INTERNAL, "camera": name}))
                        img = np.concatenate([ref["e_direct"], ref["e_indirect"], ref["radiance"]], axis=-1)
                        arts.append(Artifact(f"reference_{name}_image", img.astype(np.float32), format="npy",
                                             description="preview reference: e_direct, e_indirect, radiance",
                                             meta={**INTERNAL, "camera": name, "spp": s["preview_spp"]}))
                        arts.append(Artifact(f"reference_{name}_shadow", np.ascontiguousarray(sm), format="npy",
                                             description="preview per-light visibility", meta={**INTERNAL,
                                                                                               "camera": name}))
                        preview_names.append(name)
                finally:
                    gbr.release()
            finally:
                gl.release()
    timings["previews_s"] = time.perf_counter() - t0

    cam_doc = {"cameras": [c.to_dict() for c in cams], "source": source, "previews": preview_names}
    arts.append(Artifact("reference_cameras", cam_doc, format="json", description="the review cameras",
                         meta=dict(INTERNAL)))
    ctx.report(1.0)
    stats = {"enabled": True, "cameras": [camera_record(c) for c in cams], "camera_source": source,
             "sampling": sampling, "surface_points": int(len(sp["position"])), "check_points": int(P),
             "normals_per_check_point": int(D), "spp": s["spp"], "check_spp": s["check_spp"],
             "preview_spp": s["preview_spp"],
             "bounces": s["bounces"], "rr_depth": RR_DEPTH if s["bounces"] > RR_DEPTH else None,
             "previews": preview_names, "surface": {k: v for k, v in sp["stats"].items()}, "trace": pt_stats,
             "check_trace": c_stats, "timings": timings, "seconds": time.perf_counter() - t_start}
    if warnings:
        stats["warnings"] = warnings
    return StageOutput(artifacts=arts, stats=jsonable(stats))

