"""Stage ``evaluate``: previews and metrics of every GI mode against a path-traced reference (DESIGN stage 7).

Reads ``ingest`` (lights, sky, bounds), ``place`` (grid), ``relocate`` (relocated probes), ``trace`` (states,
depth moments), ``light`` (irradiance atlas, ``sh_l1_*``, its bounce count), ``masks`` (dense masks, cluster
volumes), ``compress`` (mask atlas + indirection) and, when present, ``prt``. Config: ``config.evaluate``
(see :class:`Settings`; defaults apply while the section does not exist).

Per camera (given, or auto-placed in free space looking at geometry, :func:`workers.render.cameras.auto_cameras`
with the relocated non-OFF probes as candidates; the default outside camera when none qualifies):

1. G-buffer (:class:`workers.render.gbuffer.GBufferRenderer`);
2. reference: direct light with Embree shadow rays + path-traced indirect irradiance at the same pixels
   (:func:`workers.kernels.pathtrace.reference_at_gbuffer`, ``spp``, bounces = the light stage's);
3. per mode, the deferred pass of :mod:`workers.render.shading` (the proto/glsl mode shaders): radiance,
   indirect irradiance, and the pass's wall time (render + ``ctx.finish()``, median of ``repeats``);
4. metrics (:mod:`workers.kernels.metrics`): RMSE (MD §4.2, tone-mapped LDR, shaded pixels), FLIP mean (LDR
   after the same tone map; exposure from the reference), leak score (indirect irradiance), relative RMSE of
   the indirect irradiance, texture memory each mode samples (bytes as uploaded), GI texture fetches per
   pixel (per mode the formula in its GLSL header, with the per-pixel counts — non-OFF DDGI corners,
   clusters with m_k > 0 — measured from the baked data at the G-buffer points), pass time.

Artifacts (PNG when proto.bundle accepts ``format="png"``, else npy (H, W, 3) uint8 images until it does):
``eval_<cam>_<mode>`` previews (tone-mapped; ``<mode>`` also ``reference``), ``eval_<cam>_<mode>_error``
heatmaps (MD Fig 3 bottom row: per-pixel error E(x) of §4.2, jet ramp 0 … ``HEATMAP_VMAX``), ``eval_contact``
(one row per camera: reference and modes, then their heatmaps), ``eval_metrics`` (json), ``eval_cameras``
(json). Stats: ``metrics`` (flat ``<mode>.<metric>`` means over cameras, for the catalog / compare) and
``per_camera``.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from workers.kernels import metrics as MT
from workers.kernels import samplers as SM
from workers.kernels.ddgi import cage_probes
from workers.kernels.grid import OFF
from workers.kernels.pathtrace import reference_at_gbuffer, scene_eps
from workers.raycast import caster_for_scene
from workers.render.cameras import Camera, auto_cameras, default_camera, fit_clip_planes
from workers.render.context import RenderUnavailable, create_context, renderer_info
from workers.render.gbuffer import GBufferRenderer
from workers.render.shading import GBufferInputs, ShadingRenderer, prepare_mode, shadow_masks
from workers.stages.base import Artifact, StageContext, StageError, StageOutput, samples_per_cell

HEATMAP_VMAX = 0.25  # LDR error at the red end of the heatmaps
GBUFFER_FETCHES = 4  # position, normal, albedo, emission (+1 per 4 lights: shadow mask)


@dataclass
class Settings:
    """``config.evaluate`` (the lead adds ``EvaluateSection`` with these fields and defaults)."""

    cameras: int | list = 3               # auto-placed count, or a list of {position, target, fov_y?, name?}
    width: int = 512
    height: int = 384
    fov_y: float = 60.0
    spp: int = 64
    bounces: int | None = None            # None: the light stage's bounce count
    modes: list | None = None             # None: every mode the bake has data for
    repeats: int = 5
    flip: bool = True

    @classmethod
    def of(cls, config) -> "Settings":
        sec = getattr(config, "evaluate", None)
        if sec is None:
            return cls()
        d = sec.model_dump() if hasattr(sec, "model_dump") else dict(sec)
        if isinstance(d.get("cameras"), list):  # drop unset optional fields (fov_y, name): the defaults apply
            d["cameras"] = [{k: v for k, v in c.items() if v is not None} for c in d["cameras"]]
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__ and k != "enabled"})


_PNG_OK: bool | None = None


def png_supported() -> bool:
    """Whether proto.bundle.write_artifact writes format="png" (it refuses it until the lead adds it)."""
    global _PNG_OK
    if _PNG_OK is None:
        from proto import bundle

        with tempfile.TemporaryDirectory() as d:
            try:
                bundle.write_artifact(d, "probe", MT.png_bytes(np.zeros((1, 1, 3), np.uint8)), "evaluate",
                                      format="png")
                _PNG_OK = True
            except Exception:
                _PNG_OK = False
    return _PNG_OK


def _image_artifact(name: str, img: np.ndarray, description: str, meta=None) -> Artifact:
    img = MT.to_uint8(img)
    if png_supported():
        return Artifact(name, MT.png_bytes(img), format="png", description=description,
                        meta={**(meta or {}), "shape": list(img.shape)})
    return Artifact(name, np.ascontiguousarray(img), format="npy", description=description + " (PNG pending: "
                    "uint8 image)", meta=dict(meta or {}))


def _gather(ctx: StageContext) -> dict:
    arrays = {}
    for st in ("light", "relocate", "trace", "masks", "compress", "prt"):
        if st in ctx.inputs:
            lz = ctx.inputs[st]
            for n in lz.names():
                arrays[n] = (lambda lz=lz, n=n: lz[n])
    return arrays


class _Lazy(dict):
    def __getitem__(self, k):
        v = dict.__getitem__(self, k)
        if callable(v):
            v = v()
            dict.__setitem__(self, k, v)
        return v


def available_modes(arrays) -> list[str]:
    modes = ["direct"]
    if all(f"sh_l1_{c}" in arrays for c in "rgb"):
        modes.append("leaking")
    if all(n in arrays for n in ("irradiance", "depth_moments", "probe_positions_relocated", "probe_states")):
        modes.append("ddgi")
    if "mask_indirection" in arrays and "mask_atlas_0123" in arrays and "cluster_sh_0_r" in arrays:
        modes.append("mask")
        if "cluster_weights_0123" in arrays:
            modes.append("mask_normalized")
    if "prt" in arrays:
        modes.append("prt")
    return modes


def _cameras(settings: Settings, caster, box, candidates) -> list[Camera]:
    kw = dict(width=settings.width, height=settings.height, fov_y=settings.fov_y)
    if isinstance(settings.cameras, (list, tuple)):
        out = []
        for i, c in enumerate(settings.cameras):
            d = dict(c)
            cam = Camera(d["position"], d["target"], fov_y=d.get("fov_y", settings.fov_y), width=settings.width,
                         height=settings.height, name=d.get("name") or f"cam-{i}")
            out.append(fit_clip_planes(cam, caster, box))
        return out
    cams = auto_cameras(caster, box, int(settings.cameras), candidates=candidates, **kw) if settings.cameras else []
    if not cams and len(candidates):
        cams = auto_cameras(caster, box, int(settings.cameras), **kw)
    return cams or [default_camera(box, **kw)]


def gi_fetches(mode: str, res, arrays, grid, points, normals, views) -> np.ndarray:
    """(N,) GI texture fetches per pixel of ``mode`` at the points (the formulas of the mode GLSL headers)."""
    N = points.shape[0]
    if mode == "direct" or N == 0:
        return np.zeros(N)
    if mode == "leaking":
        return np.full(N, 7.0 if res.info.get("sh_order") == 2 else 3.0)     # sh_l2 sub-volumes, or sh_l1_{r,g,b}
    if mode == "ddgi":
        _, cage = cage_probes(points, normals, views, grid["counts"], grid["origin"], grid["spacing"], 0.3)
        live = (np.asarray(arrays["probe_states"]).reshape(-1)[cage] != OFF).sum(axis=1)
        return 8.0 + 2.0 * live
    if mode in ("mask", "mask_normalized"):
        K = res.info["clusters"]
        A = 1 + (K > 4)
        vols = [arrays["masks_0123"]] + ([arrays["masks_4567"]] if K > 4 else [])
        m = SM.mask_values(vols, points, normals, grid, float(res.uniforms.get("uMaskOffset", 0.0)), views)[:, :K]
        z = (m > 0).sum(axis=1)
        per = 7.0 if res.info.get("sh_order") == 2 else 3.0                   # L2: 7 sub-volumes per cluster
        return 1.0 + A + per * z + (A if mode == "mask_normalized" else 0)
    if mode == "prt":
        return np.full(N, float(res.info.get("coefficients", 4)) * res.info["groups"])
    raise ValueError(mode)


def _prt_resources(arrays, grid, lights, caster, sh_order=None):
    from workers.prt_relight import PrtModel, direct_vector
    from workers.kernels import prt as kprt

    model = PrtModel.from_arrays(arrays)
    x = direct_vector(model, list(lights), caster)
    xg = kprt.gamma_encode(x, model.gamma)
    xa = np.concatenate([xg, np.linalg.norm(xg, axis=0)[None]], axis=0).astype(np.float32)
    u = np.einsum("cnm,mc->nc", model.sh.transfer, xa)
    return prepare_mode("prt", arrays, grid, prt_model=model, prt_coefficients=u, sh_order=sh_order)


def run_evaluate(ctx: StageContext) -> StageOutput:
    t_start = time.perf_counter()
    sec = getattr(ctx.config, "evaluate", None)
    if sec is not None and not sec.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    settings = Settings.of(ctx.config)
    scene = ctx.scene
    place = ctx.inputs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    lit = ctx.inputs["ingest"]["lights"]
    lights, sky = list(lit["lights"]), lit["sky"]
    arrays = _Lazy(_gather(ctx))
    have = available_modes(arrays)
    if "prt" in have and not (ctx.inputs.get("prt") and ctx.inputs["prt"].stats.get("enabled", True)):
        have.remove("prt")
    modes = [m for m in (settings.modes or have) if m in have]
    light_stats = ctx.inputs["light"].stats if "light" in ctx.inputs else {}
    bounces = settings.bounces or int(light_stats.get("bounces") or 1)
    B = float(ctx.config.light.self_shadow_bias)
    caster = caster_for_scene(scene)
    eps = scene_eps(scene)
    box = np.array([np.asarray(grid["origin"], np.float64),
                    np.asarray(grid["origin"]) + np.asarray(grid["spacing"]) * (np.asarray(grid["counts"]) - 1)])
    if np.any(box[1] - box[0] <= 0):
        box = np.asarray(scene.bounds, np.float64)
    pos = np.asarray(arrays["probe_positions_relocated"]).reshape(-1, 3) if "probe_positions_relocated" in arrays \
        else np.zeros((0, 3))
    if len(pos) and "probe_states" in arrays:
        pos = pos[np.asarray(arrays["probe_states"]).reshape(-1) != OFF]
    cams = _cameras(settings, caster, box, pos)
    try:
        gl = create_context()
    except RenderUnavailable as e:
        raise StageError("render_unavailable", str(e)) from e
    mask_meta = None
    if "mask" in modes or "mask_normalized" in modes:
        S = samples_per_cell(ctx.config, ctx.inputs["place"].stats)
        T = int(ctx.inputs["compress"].stats["block_size"])
        mask_meta = {"samples_per_cell": S, "block_size": T, "border_lo": int(ctx.inputs["compress"].stats.get("border_lo", T - S - 1))}
    arts: list[Artifact] = []
    per_camera = []
    sheet_rows = []
    try:
        gbr = GBufferRenderer(scene, gl, caster=caster)
        shader = ShadingRenderer(gl, lights)
        resources = {}
        for m in modes:
            res = (_prt_resources(arrays, grid, lights, caster) if m == "prt" else
                   prepare_mode(m, arrays, grid, self_shadow_bias=B, mask_meta=mask_meta))
            shader.set_mode(res)
            resources[m] = res
        ctx.report(0.05)
        for ci, cam in enumerate(cams):
            cname = cam.name or f"cam-{ci}"
            gb = gbr.render(cam)
            sel = gb.shaded
            t0 = time.perf_counter()
            ref = reference_at_gbuffer(scene, gb, lights, sky=sky, caster=caster, eps=eps, spp=settings.spp,
                                       bounces=bounces, seed=ctx.config.seed + ci)
            t_ref = time.perf_counter() - t0
            pts = gb.position[sel].astype(np.float64)
            nrm = gb.normal[sel].astype(np.float64)
            views = -gb.view_dirs()[sel].astype(np.float64)
            sm = np.ones(gb.shape + (len(lights),), np.uint8)
            if lights and len(pts):
                sm[sel] = shadow_masks(pts, nrm, lights, caster, eps)
            shader.set_gbuffer(GBufferInputs.from_gbuffer(gb, sm))
            k = MT.exposure_for(ref["radiance"], sel)
            ref_ldr = MT.tonemap(ref["radiance"], k)
            tiles = [("reference", ref_ldr)]
            heat = [("error scale 0-%.2f" % HEATMAP_VMAX, MT.heatmap(np.linspace(0, HEATMAP_VMAX, gb.shape[1])[None]
                                                                     .repeat(gb.shape[0], 0), HEATMAP_VMAX))]
            arts.append(_image_artifact(f"eval_{cname}_reference", ref_ldr, f"path-traced reference, {cname}",
                                        {"camera": cname, "exposure": k}))
            cam_metrics = {"camera": cam.to_dict(), "pixels": int(sel.sum()), "exposure": k,
                           "reference_seconds": t_ref, "reference_stats": ref["stats"], "modes": {}}
            timings = shader.time_passes(modes, cam.position, settings.repeats)   # interleaved: fair ratios
            for m in modes:
                eye = cam.position
                rad = shader.render(m, 0, eye)
                ind = shader.render(m, 1, eye)
                timing = timings[m]
                ldr = MT.tonemap(rad, k)
                err = MT.pixel_error(ldr, ref_ldr)
                fl = None
                if settings.flip and sel.any():
                    fl = MT.flip_mean(ldr, ref_ldr, sel)
                leak = MT.leak_score(ind, ref["e_indirect"], sel)
                fetch = gi_fetches(m, resources[m], arrays, grid, pts, nrm, views)
                cam_metrics["modes"][m] = {
                    "rmse": MT.rmse(ldr, ref_ldr, sel), "flip": fl, "leak": leak["leak"],
                    "indirect_relative_rmse": MT.relative_rmse(ind, ref["e_indirect"], sel),
                    # absolute excess indirect (lux, mean over shaded pixels): the leak where the whole view is
                    # dark in the reference (a sealed room), where the relative leak score is 0 by definition
                    "indirect_excess": float(np.maximum(MT.luminance(ind) - MT.luminance(ref["e_indirect"]), 0)[sel]
                                             .mean()) if sel.any() else 0.0,
                    "texture_bytes": resources[m].texture_bytes,
                    "gi_fetches_per_pixel": float(fetch.mean()) if fetch.size else 0.0,
                    "gi_fetches_max": float(fetch.max()) if fetch.size else 0.0,
                    "pass_fetches_per_pixel": (float(fetch.mean()) if fetch.size else 0.0) + GBUFFER_FETCHES
                    + math.ceil(len(lights) / 4),
                    "pass_ms": timing["median_s"] * 1e3, "pass_ms_min": timing["min_s"] * 1e3,
                }
                tiles.append((m, ldr))
                heat.append((f"{m} error", MT.heatmap(err, HEATMAP_VMAX, sel)))
                arts.append(_image_artifact(f"eval_{cname}_{m}", ldr, f"{m} GI, {cname}", {"camera": cname, "mode": m}))
                arts.append(_image_artifact(f"eval_{cname}_{m}_error", MT.heatmap(err, HEATMAP_VMAX, sel),
                                            f"{m} per-pixel error E(x) (MD §4.2), 0..{HEATMAP_VMAX}",
                                            {"camera": cname, "mode": m, "vmax": HEATMAP_VMAX}))
            sheet_rows.append(tiles + heat)
            per_camera.append(cam_metrics)
            ctx.report(0.05 + 0.9 * (ci + 1) / len(cams))
        info = renderer_info(gl)
        shader.release()
        gbr.release()
    finally:
        gl.release()
    cols = len(modes) + 1
    tiles = [t for row in sheet_rows for t in row]
    arts.append(_image_artifact("eval_contact", MT.contact_sheet(tiles, columns=cols),
                                "contact sheet: per camera the reference and each mode, then error heatmaps"))
    summary = {}
    for m in modes:
        vals = [c["modes"][m] for c in per_camera]
        for key in ("rmse", "flip", "leak", "indirect_relative_rmse", "indirect_excess", "gi_fetches_per_pixel", "pass_ms",
                    "pass_fetches_per_pixel"):
            xs = [v[key] for v in vals if v[key] is not None]
            if xs:
                summary[f"{m}.{key}"] = float(np.mean(xs))
        summary[f"{m}.texture_bytes"] = float(vals[0]["texture_bytes"]) if vals else 0.0
    for a, b in (("mask", "leaking"), ("ddgi", "mask"), ("mask_normalized", "leaking")):
        if f"{a}.pass_ms" in summary and summary.get(f"{b}.pass_ms"):
            summary[f"ratio.{a}_over_{b}.pass_ms"] = summary[f"{a}.pass_ms"] / summary[f"{b}.pass_ms"]
    metrics_json = {"modes": modes, "summary": summary, "cameras": per_camera, "renderer": info,
                    "settings": settings.__dict__ | {"bounces": bounces}, "heatmap_vmax": HEATMAP_VMAX,
                    "tone_map": "exposure 0.18/median reference luminance, ACES (Narkowicz), sRGB"}
    arts.append(Artifact("eval_metrics", _jsonable(metrics_json), format="json",
                         description="evaluate metrics per camera and mode, and their means"))
    arts.append(Artifact("eval_cameras", {"cameras": [c.to_dict() for c in cams]}, format="json",
                         description="the evaluation cameras"))
    stats = {"metrics": summary, "modes": modes, "cameras": len(cams), "bounces": bounces, "spp": settings.spp,
             "renderer": info.get("renderer"), "seconds": time.perf_counter() - t_start,
             "png": png_supported()}
    return StageOutput(artifacts=arts, stats=_jsonable(stats))


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    return x
