"""Stage ``evaluate``: every GI mode scored against the cached path-traced reference, and previews (DESIGN stage 7).

Reads ``reference`` (:mod:`workers.stages.reference`: surface points, check points, review cameras, preview
G-buffers and reference images — cached per scene and lighting, independent of the probe config) and the bake's
data: ``ingest`` (lights), ``place`` (grid), ``relocate``, ``trace``, ``light``, ``masks``, ``compress`` and, when
enabled, ``prt``. Config: ``config.evaluate``.

Metrics (from the points only, :mod:`workers.kernels.point_metrics`)
--------------------------------------------------------------------
Each mode's indirect irradiance is reconstructed at the reference's surface points on the CPU
(:func:`workers.kernels.point_modes.mode_irradiance`, the Python twins of the GLSL modes) and compared with the
reference there: ``<mode>.rmse`` (MD §4.2 on the tone-mapped shading result), ``<mode>.indirect_relative_rmse``,
``<mode>.leak``, ``<mode>.indirect_excess``, ``<mode>.mean_ratio``, each with ``<mode>.<metric>_stderr``
propagated from the reference's noise; with check-point regions ``<mode>.region.<name>.mean_ratio`` (and
``_stderr``). Also ``<mode>.texture_bytes`` and ``<mode>.gi_fetches_per_pixel`` / ``_max`` (the per-point GI
texture fetches of each mode's GLSL header formula, at the surface points).

Previews (pictures; only timing and image metrics, never the metrics above)
---------------------------------------------------------------------------
Per review camera with a stored preview, the deferred pass of :mod:`workers.render.shading` (the proto/glsl
mode shaders) on the reference's G-buffer: per mode the tone-mapped image, its error heatmap (MD Fig 3 bottom
row, ``HEATMAP_VMAX``), and the pass's wall time (``<mode>.pass_ms``, median of ``repeats``,
``<mode>.pass_fetches_per_pixel``), plus image-space ``<mode>.image_rmse`` and ``<mode>.flip`` against the
low-spp preview reference. Without EGL the previews are skipped with a warning (``previews_unavailable``).

Artifacts: ``check_points`` (json; with ``evaluate.points``: points, normals, reference_direct,
reference_indirect, reference_stderr ([point][normal] RGB), modes {mode: [point][normal] RGB}, regions),
``eval_metrics`` (json), ``eval_cameras`` (json), and with previews ``eval_<cam>_<mode>`` (PNG, ``<mode>`` also
``reference``), ``eval_<cam>_<mode>_error`` heatmaps, ``eval_contact``. Stats: ``metrics`` (flat, for the catalog,
compare and ``kiln bake --fail-on``), ``cameras`` (the review cameras: name, position, target, fov),
``points``, ``check_points``, ``modes``.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from workers.kernels import metrics as MT
from workers.kernels import point_metrics as PM
from workers.kernels import samplers as SM
from workers.kernels.ddgi import cage_probes
from workers.kernels.grid import OFF
from workers.kernels.point_modes import MaskArrays, mode_irradiance
from workers.render.shading import prepare_mode
from workers.stages.base import Artifact, StageContext, StageOutput, samples_per_cell, jsonable
from workers.stages.reference import GBUFFER_CHANNELS, point_column

HEATMAP_VMAX = 0.25  # LDR error at the red end of the heatmaps
GBUFFER_FETCHES = 4  # position, normal, albedo, emission (+1 per 4 lights: shadow mask)
POINT_METRICS = PM.METRICS


@dataclass
class Settings:
    """``config.evaluate`` (:class:`proto.models.EvaluateSection`), as the stage reads it."""

    cameras: int | list = 3
    width: int = 160
    height: int = 120
    fov_y: float = 60.0
    spp: int = 64
    preview_spp: int = 4
    bounces: int | None = None
    surface_points: int = 2048
    sampling: str = "cameras"
    previews: int = 1
    modes: list | None = None             # None: every mode the bake has data for
    repeats: int = 3
    flip: bool = False

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


def _reference_points(ref) -> dict:
    table = np.asarray(ref["reference_points"], np.float64)
    from workers.stages.reference import POINT_COLUMNS

    return {k: point_column(table, k) for k in POINT_COLUMNS}


def _unpack_gbuffer(packed: np.ndarray) -> dict:
    out, c = {}, 0
    for k in GBUFFER_CHANNELS:
        w = 1 if k == "shaded" else 3
        out[k] = np.ascontiguousarray(packed[..., c:c + w]) if w == 3 else packed[..., c] > 0.5
        c += w
    return out


def _point_summary(modes, recon, pts, seed) -> tuple[dict, dict]:
    """Flat ``<mode>.<metric>`` (and ``_stderr``) summary and the per-mode dicts, from the surface points."""
    summary, per_mode = {}, {}
    if len(pts["position"]) == 0:
        return summary, per_mode
    exposure = MT.exposure_for(PM.radiance(pts["e_direct"], pts["e_indirect"], pts["albedo"],
                                           pts["emission"]).reshape(-1, 1, 3))
    for m in modes:
        r = PM.metrics_with_stderr(recon[m], pts["e_indirect"], pts["stderr"], pts["e_direct"], pts["albedo"],
                                   pts["emission"], seed=seed, exposure=exposure)
        per_mode[m] = r
        for k, v in r.items():
            if v is not None and math.isfinite(v):
                summary[f"{m}.{k}"] = float(v)
    lum = MT.luminance(pts["e_indirect"])
    summary["reference.mean_indirect"] = float(lum.mean())
    summary["reference.mean_indirect_stderr"] = float(np.sqrt(np.sum((pts["stderr"] @ MT.REC709) ** 2)) / len(lum))
    return summary, per_mode


def _previews(ctx, settings, ref, rdoc, modes, resources, lights, summary, arts, warnings) -> dict:
    """The per-camera previews (module doc); adds their artifacts and timing/image metrics; returns the
    renderer's info ({} when no preview was rendered)."""
    from workers.render.cameras import Camera
    from workers.render.context import RenderUnavailable, create_context, renderer_info
    from workers.render.shading import GBufferInputs, ShadingRenderer

    names = list(rdoc.get("previews") or [])
    cams = {c["name"]: Camera.from_dict(c) for c in rdoc.get("cameras", [])}
    names = [n for n in names if n in cams and f"reference_{n}_gbuffer" in ref]
    if not settings.previews or not names:
        return {}
    try:
        gl = create_context()
    except RenderUnavailable as e:
        warnings.append({"code": "previews_unavailable", "message": f"no preview images or pass timings: {e}"})
        return {}
    per_camera, sheet_rows = [], []
    try:
        shader = ShadingRenderer(gl, lights)
        try:
            for m in modes:
                shader.set_mode(resources[m])
            for ci, name in enumerate(names):
                cam = cams[name]
                gb = _unpack_gbuffer(np.asarray(ref[f"reference_{name}_gbuffer"], np.float32))
                img = np.asarray(ref[f"reference_{name}_image"], np.float32)
                sm = np.asarray(ref[f"reference_{name}_shadow"], np.uint8)
                sel = gb["shaded"]
                shader.set_gbuffer(GBufferInputs(gb["position"], gb["normal"], gb["albedo"], gb["emission"], sel,
                                                 sm))
                ref_rad, ref_ind = img[..., 6:9], img[..., 3:6]
                k = MT.exposure_for(ref_rad, sel)
                ref_ldr = MT.tonemap(ref_rad, k)
                tiles = [("reference", ref_ldr)]
                heat = [("error scale 0-%.2f" % HEATMAP_VMAX,
                         MT.heatmap(np.linspace(0, HEATMAP_VMAX, sel.shape[1])[None].repeat(sel.shape[0], 0),
                                    HEATMAP_VMAX))]
                arts.append(_image_artifact(f"eval_{name}_reference", ref_ldr,
                                            f"path-traced preview reference ({ref.stats.get('preview_spp')} spp), "
                                            f"{name}", {"camera": name, "exposure": k}))
                timings = shader.time_passes(modes, cam.position, settings.repeats, warmup=ci == 0)
                cm = {"camera": name, "pixels": int(sel.sum()), "exposure": k, "modes": {}}
                for m in modes:
                    rad = shader.render(m, 0, cam.position)
                    ind = shader.render(m, 1, cam.position)
                    ldr = MT.tonemap(rad, k)
                    err = MT.pixel_error(ldr, ref_ldr)
                    fl = MT.flip_mean(ldr, ref_ldr, sel) if settings.flip and sel.any() else None
                    cm["modes"][m] = {"image_rmse": MT.rmse(ldr, ref_ldr, sel), "flip": fl,
                                      "image_leak": MT.leak_score(ind, ref_ind, sel)["leak"],
                                      "pass_ms": timings[m]["median_s"] * 1e3, "pass_ms_min": timings[m]["min_s"] * 1e3}
                    tiles.append((m, ldr))
                    hm = MT.heatmap(err, HEATMAP_VMAX, sel)
                    heat.append((f"{m} error", hm))
                    arts.append(_image_artifact(f"eval_{name}_{m}", ldr, f"{m} GI, {name}", {"camera": name, "mode": m}))
                    arts.append(_image_artifact(f"eval_{name}_{m}_error", hm,
                                                f"{m} per-pixel error E(x) (MD §4.2) against the preview reference, "
                                                f"0..{HEATMAP_VMAX}", {"camera": name, "mode": m,
                                                                       "vmax": HEATMAP_VMAX}))
                sheet_rows.append(tiles + heat)
                per_camera.append(cm)
                ctx.report(0.6 + 0.35 * (ci + 1) / len(names))
            info = renderer_info(gl)
        finally:
            shader.release()
    finally:
        gl.release()
    tiles = [t for row in sheet_rows for t in row]
    arts.append(_image_artifact("eval_contact", MT.contact_sheet(tiles, columns=len(modes) + 1),
                                "contact sheet: per camera the preview reference and each mode, then error heatmaps"))
    for m in modes:
        for key in ("image_rmse", "flip", "image_leak", "pass_ms", "pass_ms_min"):
            xs = [c["modes"][m][key] for c in per_camera if c["modes"][m][key] is not None]
            if xs:
                summary[f"{m}.{key}"] = float(np.mean(xs))
        if f"{m}.pass_ms" in summary and f"{m}.gi_fetches_per_pixel" in summary:
            summary[f"{m}.pass_fetches_per_pixel"] = (summary[f"{m}.gi_fetches_per_pixel"] + GBUFFER_FETCHES
                                                      + math.ceil(len(lights) / 4))
    for a, b in (("mask", "leaking"), ("ddgi", "mask"), ("mask_normalized", "leaking")):
        if f"{a}.pass_ms" in summary and summary.get(f"{b}.pass_ms"):
            summary[f"ratio.{a}_over_{b}.pass_ms"] = summary[f"{a}.pass_ms"] / summary[f"{b}.pass_ms"]
    info["per_camera"] = per_camera
    return info


def _timing(key: str) -> bool:
    """Whether a metric is a wall time (``pass_ms``, ``pass_ms_min``, their ratios): not reproducible."""
    return key.split(".")[-1] in ("pass_ms", "pass_ms_min")


def run_evaluate(ctx: StageContext) -> StageOutput:
    t_start = time.perf_counter()
    sec = getattr(ctx.config, "evaluate", None)
    if sec is not None and not sec.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    settings = Settings.of(ctx.config)
    ref = ctx.inputs["reference"]
    rstats = ref.stats
    place = ctx.inputs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    lit = ctx.inputs["ingest"]["lights"]
    lights = list(lit["lights"])
    arrays = _Lazy(_gather(ctx))
    have = available_modes(arrays)
    if "prt" in have and not (ctx.inputs.get("prt") and ctx.inputs["prt"].stats.get("enabled", True)):
        have.remove("prt")
    modes = [m for m in (settings.modes or have) if m in have]
    B = float(ctx.config.light.self_shadow_bias)
    mask_meta = None
    if "mask" in modes or "mask_normalized" in modes:
        S = samples_per_cell(ctx.config, ctx.inputs["place"].stats)
        T = int(ctx.inputs["compress"].stats["block_size"])
        mask_meta = {"samples_per_cell": S, "block_size": T,
                     "border_lo": int(ctx.inputs["compress"].stats.get("border_lo", T - S - 1))}
    marr = MaskArrays(arrays, mask_meta)
    caster = None
    prt_model = None
    if "prt" in modes:
        from workers.prt_relight import PrtModel
        from workers.raycast import caster_for_scene

        caster = caster_for_scene(ctx.scene)
        prt_model = PrtModel.from_arrays(arrays)
    warnings: list[dict] = []
    ctx.report(0.02)

    # ---- the modes at the reference's points
    t0 = time.perf_counter()
    pts = _reference_points(ref)
    recon = {}
    for i, m in enumerate(modes):
        recon[m] = mode_irradiance(m, marr, grid, pts["position"], pts["normal"], pts["view"], self_shadow_bias=B,
                                   lights=lights, caster=caster, prt_model=prt_model)
        ctx.report(0.02 + 0.4 * (i + 1) / max(len(modes), 1))
    summary, per_mode = _point_summary(modes, recon, pts, int(ctx.config.seed))
    t_points = time.perf_counter() - t0

    t0 = time.perf_counter()
    check = None
    if "reference_check_points" in ref:
        doc = ref["reference_check_points"]
        cp = np.asarray(doc["points"], np.float64)
        cn = np.asarray(doc["normals"], np.float64)                       # (P, D, 3)
        P, D = cn.shape[:2]
        cpts, cnrm = np.repeat(cp, D, axis=0), cn.reshape(-1, 3)
        check = {k: doc[k] for k in ("points", "normals", "reference_direct", "reference_indirect",
                                     "reference_stderr")}
        check["modes"] = {}
        cref = np.asarray(doc["reference_indirect"], np.float64)
        cerr = np.asarray(doc["reference_stderr"], np.float64)
        for m in modes:
            v = mode_irradiance(m, marr, grid, cpts, cnrm, cnrm, self_shadow_bias=B, lights=lights, caster=caster,
                                prt_model=prt_model).reshape(P, D, 3)
            check["modes"][m] = v.tolist()
            if doc.get("regions"):
                for name, r in PM.region_ratios(v, cref, cerr, doc["regions"], seed=int(ctx.config.seed)).items():
                    for k in ("mean_ratio", "mean_ratio_stderr"):
                        if r[k] is not None and math.isfinite(r[k]):
                            summary[f"{m}.region.{name}.{k}"] = float(r[k])
        if doc.get("regions"):
            check["regions"] = {name: {"points": idx, **{m: PM.region_ratios(
                np.asarray(check["modes"][m]), cref, cerr, {name: idx}, seed=int(ctx.config.seed))[name]
                for m in modes}} for name, idx in doc["regions"].items()}
    t_check = time.perf_counter() - t0
    ctx.report(0.5)

    # ---- what each mode samples: textures (as uploaded) and GI fetches per point
    resources = {}
    for m in modes:
        resources[m] = (_prt_resources(arrays, grid, lights, caster) if m == "prt" else
                        prepare_mode(m, arrays, grid, self_shadow_bias=B, mask_meta=mask_meta))
        summary[f"{m}.texture_bytes"] = float(resources[m].texture_bytes)
        if len(pts["position"]):
            f = gi_fetches(m, resources[m], marr, grid, pts["position"], pts["normal"], pts["view"])
            summary[f"{m}.gi_fetches_per_pixel"] = float(f.mean()) if f.size else 0.0
            summary[f"{m}.gi_fetches_max"] = float(f.max()) if f.size else 0.0
    ctx.report(0.6)

    # ---- previews
    t0 = time.perf_counter()
    rdoc = ref["reference_cameras"] if "reference_cameras" in ref else {"cameras": [], "previews": []}
    arts: list[Artifact] = []
    info = _previews(ctx, settings, ref, rdoc, modes, resources, lights, summary, arts, warnings)
    t_previews = time.perf_counter() - t0

    cameras = rstats.get("cameras") or []
    if check is not None:
        arts.append(Artifact("check_points", jsonable(check), format="json",
                             description="reference and every mode's indirect irradiance at the check points "
                                         "([point][normal] RGB)", meta={"modes": modes, "points": len(check["points"])}))
    # the artifact holds no wall times (they live in the stats): the same bake gives the same bytes on any worker
    untimed = {k: v for k, v in summary.items() if not _timing(k)}
    previews = [{**c, "modes": {m: {k: v for k, v in d.items() if not _timing(k)} for m, d in c["modes"].items()}}
                for c in info.get("per_camera", [])]
    metrics_json = {"modes": modes, "summary": untimed, "points": {m: per_mode.get(m) for m in modes},
                    "surface_points": int(len(pts["position"])), "sampling": rstats.get("sampling"),
                    "cameras": cameras, "renderer": {k: v for k, v in info.items() if k != "per_camera"},
                    "previews": previews, "settings": settings.__dict__,
                    "reference": {k: rstats.get(k) for k in ("spp", "bounces", "rr_depth", "preview_spp",
                                                            "camera_source")},
                    "heatmap_vmax": HEATMAP_VMAX,
                    "tone_map": "exposure 0.18/median reference luminance, ACES (Narkowicz), sRGB"}
    arts.append(Artifact("eval_metrics", jsonable(metrics_json), format="json",
                         description="evaluate metrics per mode (at the surface points, with standard errors) and "
                                     "per preview camera"))
    arts.append(Artifact("eval_cameras", jsonable({"cameras": rdoc.get("cameras", []),
                                                    "source": rdoc.get("source")}), format="json",
                         description="the review cameras"))
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

