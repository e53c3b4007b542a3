"""Stage ``reference``: the path-traced reference the evaluate stage scores every GI mode against, cached per scene.

Reads ``ingest`` only (the resolved lights and sky; the scene with the bake's material options) and the
reference fields of ``config.evaluate`` and ``seed`` — nothing of the probe grid, its trace or its light. So its
cache key (proto/stages.py) is the same for every bake of a scene with the same lighting and reference settings,
whatever their probe configs: the first bake pays for it, every later one reuses it, and every bake of the scene
is scored at the same points, from the same cameras.

1. **Review cameras**: :func:`workers.render.cameras.review_cameras` (the bake's, the glTF's, auto-placed, or a
   default).
2. **Surface points** (:mod:`workers.kernels.surface_points`): ``surface_points`` stratified points on the
   surfaces the review cameras see (``sampling = "cameras"``) or uniform by area on front faces in free space
   (``"area"``; also the fallback when the cameras see less than 10% of them).
3. **Check points**: ``evaluate.points`` (each point with its normal, or the 6 axis normals).
4. At every surface point and check-point normal: direct and path-traced indirect irradiance with its standard
   error (:func:`workers.kernels.reference.irradiance_at_points`): ``spp`` paths per surface point, ``check_spp``
   per check-point normal (then surface points that are dark get ``dark_spp`` in all, and the others more paths in proportion to
   the square root of their noise in the rmse metrics' units, pooled over their neighbours, up to ``dark_spp``: :func:`workers.kernels.reference.refine_points`, chosen on an independent pilot pass of
   :func:`~workers.kernels.reference.pilot_spp` paths a point, traced first, so the choice does not bias
   the values or their standard errors; the pilot's values are also the Russian-roulette control variate of the
   surface points' passes, :func:`~workers.kernels.reference.tail_guess`), ``bounces`` vertices
   (default :data:`DEFAULT_BOUNCES`: the converged light the light stage iterates to), Russian roulette from vertex :data:`RR_DEPTH`, in batches of :data:`BATCH_POINTS` points.
5. **Previews** (needs EGL; pictures only): :func:`workers.render.previews.reference_previews` for the first
   ``previews`` review cameras; without EGL skipped with the warning ``previews_unavailable``.

Artifacts (all internal, for ``evaluate``; layouts in :mod:`workers.kernels.reference_layout`):
``reference_points`` npy (N, 27) float32; ``reference_check_points`` json (points, normals, regions,
reference_direct, reference_indirect, reference_stderr: [point][normal] RGB); ``reference_cameras`` json
(cameras, source, previews); per preview camera ``reference_<cam>_gbuffer`` npy (H, W, 16) float32,
``reference_<cam>_image`` npy (H, W, 9) float32 (e_direct, e_indirect, radiance) and ``reference_<cam>_shadow``
npy (H, W, L) uint8 (per-light visibility, for the shading pass).
"""
from __future__ import annotations

import time

import numpy as np

from workers.kernels.pathtrace import scene_eps
from workers.kernels.reference import irradiance_at_points, pilot_spp, refine_points, tail_guess
from workers.kernels.reference_layout import GBUFFER_CHANNELS, POINT_COLUMNS, point_table
from workers.kernels.surface_points import check_point_set, surface_point_set
from workers.raycast import caster_for_scene
from workers.render.cameras import camera_record, review_cameras
from workers.render.previews import reference_previews
from workers.stages.base import Artifact, StageContext, StageOutput, jsonable

__all__ = ["run_reference", "BATCH_POINTS", "DEFAULT_BOUNCES", "RR_DEPTH"]

DEFAULT_BOUNCES = 64
RR_DEPTH = 3
BATCH_POINTS = 256
"""Points per path-tracing batch (one progress report each)."""
INTERNAL = {"internal": True}


def _settings(config) -> dict:
    ev = config.evaluate
    return {"cameras": ev.cameras, "width": int(ev.width), "height": int(ev.height), "fov_y": float(ev.fov_y),
            "spp": int(ev.spp), "check_spp": ev.effective_check_spp(), "dark_spp": int(ev.dark_spp),
            "preview_spp": int(ev.preview_spp),
            "bounces": int(ev.bounces) if ev.bounces else DEFAULT_BOUNCES, "surface_points": int(ev.surface_points),
            "sampling": ev.sampling, "previews": int(ev.previews)}


class _Work:
    """Progress by path count across the parts of the stage."""

    def __init__(self, report, total: float):
        self.report, self.total, self.done = report, max(float(total), 1.0), 0.0

    def part(self, amount: float):
        start = self.done
        self.done += amount
        return lambda f: self.report(min(1.0, (start + amount * min(max(f, 0.0), 1.0)) / self.total))


def run_reference(ctx: StageContext) -> StageOutput:
    t_start = time.perf_counter()
    if not ctx.config.evaluate.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    s, scene, seed, lit = _settings(ctx.config), ctx.scene, int(ctx.config.seed), ctx.inputs["ingest"]["lights"]
    lights, sky, rr = list(lit["lights"]), lit["sky"], RR_DEPTH if s["bounces"] > RR_DEPTH else None
    caster, eps = caster_for_scene(scene), scene_eps(scene)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    cams, source = review_cameras(ctx.config, scene, caster)
    timings["cameras_s"], t0 = time.perf_counter() - t0, time.perf_counter()
    ctx.report(0.01)
    sp, sampling, warnings = surface_point_set(scene, cams, s["surface_points"], s["sampling"], seed=seed,
                                               caster=caster, eps=eps)
    timings["sampling_s"] = time.perf_counter() - t0
    cp = ctx.config.evaluate.points
    cpts, cnrm = check_point_set(cp.points, cp.normals) if cp is not None else (np.zeros((0, 3)), np.zeros((0, 6, 3)))
    P, D = cnrm.shape[:2]
    preview_cams = cams[:s["previews"]]
    n_sp = len(sp["position"])
    paths = n_sp * s["spp"] + P * D * s["check_spp"] + sum(c.width * c.height for c in preview_cams) * s["preview_spp"]
    work = _Work(ctx.report, 1.02 * paths)
    work.part(0.02 * paths)(1.0)                 # cameras and sampling

    def trace(points, normals, geo, spp, seed_, part, tail=None):
        t = time.perf_counter()
        out = irradiance_at_points(scene, points, normals, geo, lights, sky=sky, spp=spp, bounces=s["bounces"],
                                   seed=seed_, rr_depth=rr, caster=caster, eps=eps, batch_points=BATCH_POINTS,
                                   tail=tail, report=work.part(part))
        return out, time.perf_counter() - t

    # an independent pilot pass first: its values are the Russian-roulette control variate of the passes below, and
    # which points get more paths is chosen on it (refine_points)
    t0 = time.perf_counter()
    n_pilot = pilot_spp(s["spp"])
    (_, p_ind, p_err, _), _ = trace(sp["position"], sp["normal"], sp["geo_normal"], n_pilot, seed + 0x30000, 0)
    pilot, tail = (p_ind, p_err, n_pilot), tail_guess(p_ind)
    timings["pilot_s"] = time.perf_counter() - t0
    (e_dir, e_ind, err, pt_stats), timings["surface_points_s"] = trace(
        sp["position"], sp["normal"], sp["geo_normal"], s["spp"], seed, n_sp * s["spp"], tail)
    t0 = time.perf_counter()
    e_ind, err, paths_per_point = refine_points(
        lambda i, n: trace(sp["position"][i], sp["normal"][i], sp["geo_normal"][i], n, seed + 0x20000 + n, 0,
                           tail[i])[0][1:3],
        e_dir, e_ind, err, s["spp"], s["dark_spp"], pilot=pilot, surface=sp)
    refined = int((paths_per_point > s["spp"]).sum())
    timings["refine_s"] = time.perf_counter() - t0
    arts = [Artifact("reference_points", np.ascontiguousarray(point_table(sp, e_dir, e_ind, err)), format="npy",
                     description="reference at the surface points: " + ", ".join(POINT_COLUMNS) + " (3 columns each)",
                     meta={**INTERNAL, "columns": list(POINT_COLUMNS), "sampling": sampling})]
    (c_dir, c_ind, c_err, c_stats), timings["check_points_s"] = trace(
        np.repeat(cpts, D, axis=0), cnrm.reshape(-1, 3), cnrm.reshape(-1, 3), s["check_spp"], seed + 0x10000,
        P * D * s["check_spp"])
    if cp is not None:
        check = {"points": cpts.tolist(), "normals": cnrm.tolist(), "regions": cp.regions,
                 **{f"reference_{k}": v.reshape(P, D, 3).tolist() for k, v in
                    (("direct", c_dir), ("indirect", c_ind), ("stderr", c_err))}}
        arts.append(Artifact("reference_check_points", check, format="json",
                             description="reference at the check points", meta=dict(INTERNAL)))
    t0 = time.perf_counter()
    pics, more = reference_previews(scene, preview_cams, lights, sky, caster, eps, spp=s["preview_spp"],
                                    bounces=s["bounces"], seed=seed, rr_depth=rr,
                                    progress=lambda c: work.part(c.width * c.height * s["preview_spp"])) \
        if preview_cams else ([], [])
    warnings += more
    for p in pics:
        name, meta = p["name"], {**INTERNAL, "camera": p["name"]}
        arts.append(Artifact(f"reference_{name}_gbuffer", p["gbuffer"], format="npy", meta=meta,
                             description="preview G-buffer: " + ", ".join(GBUFFER_CHANNELS)))
        arts.append(Artifact(f"reference_{name}_image", p["image"], format="npy", description="preview reference: "
                             "e_direct, e_indirect, radiance", meta={**meta, "spp": s["preview_spp"]}))
        arts.append(Artifact(f"reference_{name}_shadow", p["shadow"], format="npy",
                             description="preview per-light visibility", meta=dict(meta)))
    timings["previews_s"] = time.perf_counter() - t0
    names = [p["name"] for p in pics]
    arts.append(Artifact("reference_cameras", {"cameras": [c.to_dict() for c in cams], "source": source,
                                               "previews": names}, format="json",
                         description="the review cameras", meta=dict(INTERNAL)))
    ctx.report(1.0)
    stats = {"enabled": True, "cameras": [camera_record(c) for c in cams], "camera_source": source,
             "sampling": sampling, "surface_points": int(n_sp), "check_points": int(P), "normals_per_check_point":
             int(D), "spp": s["spp"], "check_spp": s["check_spp"], "dark_spp": s["dark_spp"], "refined_points": refined,
             "pilot_spp": pilot[2] if n_sp else 0,
             "paths": int(paths_per_point.sum()),
             "preview_spp": s["preview_spp"],
             "bounces": s["bounces"], "rr_depth": rr, "previews": names, "surface": dict(sp["stats"]),
             "trace": pt_stats, "check_trace": c_stats, "timings": timings, "seconds": time.perf_counter() - t_start}
    if warnings:
        stats["warnings"] = warnings
    return StageOutput(artifacts=arts, stats=jsonable(stats))
