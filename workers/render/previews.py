"""Preview pictures of the reference and evaluate stages (headless moderngl; pictures only, no point metric).

- :func:`reference_previews`: per review camera the G-buffer (:class:`workers.render.gbuffer.GBufferRenderer`), a
  low-spp path-traced reference image (:func:`workers.kernels.reference.reference_at_gbuffer`) and the per-light
  shadow masks the deferred pass needs.
- :func:`mode_previews`: per stored preview camera, each GI mode's deferred pass (:mod:`workers.render.shading`,
  the proto/glsl mode shaders) on the reference's G-buffer: the tone-mapped image, its error heatmap (MD Fig 3
  bottom row, :data:`HEATMAP_VMAX`), the pass's wall time (median of ``repeats`` after a warm-up; with ``repeats``
  0, the default, the wall time of the preview's second draw: no draw beyond the two pictures), image-space RMSE (MD §4.2),
  FLIP and leak against the (noisy) preview reference, and a contact sheet.
- :func:`prt_resources`: the PRT mode's textures and uniforms for the bake's lights.
- :func:`denoised_radiance`: the preview reference with its path-traced part denoised (Intel Open Image Denoise,
  ``pyoidn``): the picture the dashboard shows and the heatmaps compare against. Pictures only: ``image_rmse``,
  ``flip`` and ``image_leak`` stay against the noisy image, and every point metric comes from the reference's points.

Without EGL both return no pictures and the warning ``previews_unavailable``. Consumers: stages ``reference``
and ``evaluate``.
"""
from __future__ import annotations

import math
import time

import numpy as np

from workers.kernels import metrics as MT
from proto.gi_modes import MAX_LIGHTS
from workers.kernels.reference_layout import pack_gbuffer, unpack_gbuffer

__all__ = ["HEATMAP_VMAX", "GBUFFER_FETCHES", "reference_previews", "mode_previews", "mode_resources",
           "prt_resources", "png_supported", "denoised_radiance"]

HEATMAP_VMAX = 0.25  # LDR error at the red end of the heatmaps
GBUFFER_FETCHES = 4  # position, normal, albedo, emission (+1 per 4 lights: shadow mask)

_PNG_OK: bool | None = None


def png_supported() -> bool:
    """Whether proto.bundle.write_artifact writes format="png" (it refuses it until the lead adds it)."""
    global _PNG_OK
    if _PNG_OK is None:
        import tempfile

        from proto import bundle

        with tempfile.TemporaryDirectory() as d:
            try:
                bundle.write_artifact(d, "probe", MT.png_bytes(np.zeros((1, 1, 3), np.uint8)), "evaluate",
                                      format="png")
                _PNG_OK = True
            except Exception:
                _PNG_OK = False
    return _PNG_OK


def _picture(name: str, img: np.ndarray, description: str, meta=None) -> tuple:
    """``(name, data, format, description, meta)`` of a picture in [0, 1]: PNG bytes, else a uint8 npy array."""
    img = MT.to_uint8(img)
    if png_supported():
        return name, MT.png_bytes(img), "png", description, {**(meta or {}), "shape": list(img.shape)}
    return name, np.ascontiguousarray(img), "npy", description + " (PNG pending: uint8 image)", dict(meta or {})


def denoised_radiance(image: np.ndarray, gb: dict) -> np.ndarray | None:
    """The preview reference's exitant radiance with its path-traced part denoised; None without a denoiser.

    ``image`` (H, W, 9) float32: e_direct, e_indirect, radiance (:func:`reference_previews`); ``gb``: the G-buffer
    (:func:`workers.kernels.reference_layout.unpack_gbuffer`: ``albedo``, ``normal``, ``emission``, ``shaded``).
    Returns (H, W, 3) float32 ``emission + albedo/π·E_direct + D(albedo/π·E_indirect)``: only the indirect term is
    noisy (the punctual lights' direct light is exact at each pixel, shadow rays included), so only it goes through
    the denoiser D, Intel Open Image Denoise's RT filter (HDR, the G-buffer's albedo and world normal as clean
    auxiliary images), and hard shadows keep their edges. Unshaded pixels keep the image's radiance.

    Measured (two-rooms, the default 160 x 120 preview, against 512 spp of the same G-buffer, tone-mapped): the
    4-spp image's RMSE 0.215 (0.269 in the dark room, mostly salt-and-pepper), denoised 0.027 (0.034), which is about
    the 512-spp image's own noise; the dark room's mean 0.988-1.013 of the 512-spp one, as the noisy image's
    (0.982-1.009); 16 spp noisy 0.13. OIDN takes 35-70 ms on this machine. ``pyoidn`` ships x86-64 Linux wheels only:
    elsewhere this returns None and the previews show the noisy image, as they did before (2026-12-06).
    """
    try:
        import pyoidn
    except Exception:                                           # not installed, or no library for this machine
        return None
    img = np.asarray(image, np.float32)
    alb = np.clip(np.asarray(gb["albedo"], np.float32), 0.0, 1.0)
    nrm = np.asarray(gb["normal"], np.float32)
    sel = np.asarray(gb["shaded"], bool)
    inv_pi = np.float32(1.0 / math.pi)
    noisy = np.where(sel[..., None], alb * inv_pi * img[..., 3:6], 0.0).astype(np.float32)
    try:
        clean = pyoidn.denoise(np.ascontiguousarray(noisy), np.ascontiguousarray(alb), np.ascontiguousarray(nrm),
                               hdr=True, clean_aux=True)
    except Exception:                                           # e.g. a CPU the library does not support
        return None
    exact = np.asarray(gb["emission"], np.float32) + alb * inv_pi * img[..., 0:3]
    out = exact + np.maximum(np.asarray(clean, np.float32), 0.0)
    return np.where(sel[..., None], out, img[..., 6:9]).astype(np.float32)


def reference_previews(scene, cams, lights, sky, caster, eps, *, spp: int, bounces: int, seed: int,
                       rr_depth: int | None, progress) -> tuple[list[dict], list[dict]]:
    """The reference's preview of each camera in ``cams``: ``[{"name", "gbuffer" (H, W, 16) float32
    (:func:`workers.kernels.reference_layout.pack_gbuffer`), "image" (H, W, 9) float32 (e_direct, e_indirect,
    radiance), "shadow" (H, W, L) uint8 (per-light visibility)}]`` and the warnings.

    Camera i's path tracing uses seed ``seed + 1000 + i``; ``progress(cam)`` gives its report callback.
    """
    from workers.kernels.reference import reference_at_gbuffer
    from workers.render.context import RenderUnavailable, create_context
    from workers.render.gbuffer import GBufferRenderer
    from workers.render.shading import shadow_masks

    try:
        gl = create_context()
    except RenderUnavailable as e:
        return [], [{"code": "previews_unavailable",
                     "message": f"no preview images: {e} (the metrics do not need them)"}]
    out = []
    try:
        gbr = GBufferRenderer(scene, gl, caster=caster)
        try:
            for ci, cam in enumerate(cams):
                gb = gbr.render(cam)
                ref = reference_at_gbuffer(scene, gb, lights, sky=sky, caster=caster, eps=eps, spp=spp,
                                           bounces=bounces, seed=seed + 1000 + ci, rr_depth=rr_depth,
                                           report=progress(cam))
                sel = gb.shaded
                sm = np.ones(gb.shape + (len(lights),), np.uint8)
                if lights and sel.any():
                    sm[sel] = shadow_masks(gb.position[sel].astype(np.float64), gb.normal[sel].astype(np.float64),
                                           lights, caster, eps)
                img = np.concatenate([ref["e_direct"], ref["e_indirect"], ref["radiance"]], axis=-1)
                out.append({"name": cam.name, "gbuffer": pack_gbuffer(gb), "image": img.astype(np.float32),
                            "shadow": np.ascontiguousarray(sm)})
        finally:
            gbr.release()
    finally:
        gl.release()
    return out, []


def prt_resources(arrays, grid, lights, caster, sh_order=None):
    """The ``prt`` mode's :class:`workers.render.shading.ModeResources` for ``lights``: the transfer of the
    bake's PRT model applied to the direct light at its measurement points (PRT §4, gamma-encoded, with the
    ‖x‖ intercept column)."""
    from workers.kernels import prt as kprt
    from workers.prt_relight import PrtModel, direct_vector
    from workers.render.shading import prepare_mode

    model = PrtModel.from_arrays(arrays)
    x = direct_vector(model, list(lights), caster)
    xg = kprt.gamma_encode(x, model.gamma)
    xa = np.concatenate([xg, kprt.direct_norm(xg, 0, model.norm)[None]], axis=0).astype(np.float32)
    u = np.einsum("cnm,mc->nc", model.sh.transfer, xa)
    return prepare_mode("prt", arrays, grid, prt_model=model, prt_coefficients=u, sh_order=sh_order)


def mode_resources(modes, arrays, grid, lights, caster, self_shadow_bias: float, mask_meta) -> dict:
    """Each mode's :class:`workers.render.shading.ModeResources` (textures as uploaded, uniforms, defines)."""
    from workers.render.shading import prepare_mode

    return {m: (prt_resources(arrays, grid, lights, caster) if m == "prt" else
                prepare_mode(m, arrays, grid, self_shadow_bias=self_shadow_bias, mask_meta=mask_meta)) for m in modes}


def mode_previews(ref, rdoc: dict, modes: list[str], resources: dict, lights, summary: dict, *, previews: int,
                  repeats: int, flip: bool, report, frame=None) -> tuple[list[tuple], dict, list[dict]]:
    """The evaluate stage's previews (module doc).

    ``ref``: the reference stage's artifacts (``reference_<cam>_{gbuffer,image,shadow}``, stats ``preview_spp``);
    ``rdoc``: its ``reference_cameras``; ``resources``: each mode's ModeResources. Adds the per-mode image and
    timing metrics (means over cameras) to ``summary``. Returns the pictures, in order, as ``(name, image
    data, format, description, meta)`` (PNG, else npy), the renderer's info (``{}`` when nothing was rendered; else
    with ``per_camera``) and the warnings. ``report(fraction)`` after each camera. ``frame``: the bake frame
    (:func:`workers.render.shading.frame_matrix`: (3, 3) row-major world -> bake, the manifest's ``grid.frame``; None
    = identity) the deferred pass evaluates the modes in; the G-buffers, cameras and ``lights`` stay world.
    """
    from workers.render.cameras import Camera
    from workers.render.context import RenderUnavailable, create_context, renderer_info
    from workers.render.shading import GBufferInputs, ShadingRenderer

    names = list(rdoc.get("previews") or [])
    cams = {c["name"]: Camera.from_dict(c) for c in rdoc.get("cameras", [])}
    names = [n for n in names if n in cams and f"reference_{n}_gbuffer" in ref]
    if not previews or not names:
        return [], {}, []
    try:
        gl = create_context()
    except RenderUnavailable as e:
        return [], {}, [{"code": "previews_unavailable", "message": f"no preview images or pass timings: {e}"}]
    pictures, per_camera, sheet_rows = [], [], []
    try:
        shader = ShadingRenderer(gl, lights, frame=frame)
        try:
            for m in modes:
                shader.set_mode(resources[m])
            for ci, name in enumerate(names):
                cam = cams[name]
                gb = unpack_gbuffer(np.asarray(ref[f"reference_{name}_gbuffer"], np.float32))
                img = np.asarray(ref[f"reference_{name}_image"], np.float32)
                sm = np.asarray(ref[f"reference_{name}_shadow"], np.uint8)
                sel = gb["shaded"]
                shader.set_gbuffer(GBufferInputs(gb["position"], gb["normal"], gb["albedo"], gb["emission"], sel, sm))
                ref_rad, ref_ind = img[..., 6:9], img[..., 3:6]
                k = MT.exposure_for(ref_rad, sel)
                ref_ldr = MT.tonemap(ref_rad, k)            # the image metrics' reference (noisy: never denoised)
                shown = denoised_radiance(img, gb)
                show_ldr = ref_ldr if shown is None else MT.tonemap(shown, k)   # the pictures' reference
                spp = ref.stats.get("preview_spp")
                tiles = [("reference" if shown is None else "reference (denoised)", show_ldr)]
                heat = [("error scale 0-%.2f" % HEATMAP_VMAX,
                         MT.heatmap(np.linspace(0, HEATMAP_VMAX, sel.shape[1])[None].repeat(sel.shape[0], 0),
                                    HEATMAP_VMAX))]
                pictures.append(_picture(
                    f"eval_{name}_reference", show_ldr,
                    f"path-traced preview reference ({spp} spp"
                    + (")" if shown is None else ", indirect light denoised with Intel Open Image Denoise: a picture; "
                       "the metrics use the reference's points") + f", {name}",
                    {"camera": name, "exposure": k, "denoised": shown is not None}))
                # repeats 0 (the default): no extra draw; the pass time is that of the second draw below (the first
                # one of a mode may include its shader's JIT compilation on llvmpipe)
                timings = shader.time_passes(modes, cam.position, repeats, warmup=ci == 0) if repeats > 0 else {}
                cm = {"camera": name, "pixels": int(sel.sum()), "exposure": k, "denoised": shown is not None,
                      "modes": {}}
                for m in modes:
                    rad = shader.render(m, 0, cam.position)
                    t0 = time.perf_counter()
                    ind = shader.render(m, 1, cam.position)                      # draw + read back (= finish)
                    if m not in timings:
                        dt = time.perf_counter() - t0
                        timings[m] = {"median_s": dt, "min_s": dt, "repeats": 1}
                    ldr = MT.tonemap(rad, k)
                    err = MT.pixel_error(ldr, show_ldr)                          # MD §4.2 E(x): the heatmap
                    fl = MT.flip_mean(ldr, ref_ldr, sel) if flip and sel.any() else None
                    cm["modes"][m] = {"image_rmse": MT.rmse(ldr, ref_ldr, sel), "flip": fl,
                                      "image_leak": MT.leak_score(ind, ref_ind, sel)["leak"],
                                      "pass_ms": timings[m]["median_s"] * 1e3, "pass_ms_min": timings[m]["min_s"] * 1e3}
                    tiles.append((m, ldr))
                    hm = MT.heatmap(err, HEATMAP_VMAX, sel)
                    heat.append((f"{m} error", hm))
                    pictures.append(_picture(f"eval_{name}_{m}", ldr, f"{m} GI, {name}", {"camera": name, "mode": m}))
                    pictures.append(_picture(f"eval_{name}_{m}_error", hm,
                                             f"{m} per-pixel error E(x) (MD §4.2) against the "
                                             f"{'denoised ' if shown is not None else ''}preview reference, "
                                             f"0..{HEATMAP_VMAX}", {"camera": name, "mode": m, "vmax": HEATMAP_VMAX,
                                                                    "denoised": shown is not None}))
                sheet_rows.append(tiles + heat)
                per_camera.append(cm)
                report((ci + 1) / len(names))
            info = renderer_info(gl)
        finally:
            shader.release()
    finally:
        gl.release()
    tiles = [t for row in sheet_rows for t in row]
    pictures.append(_picture("eval_contact", MT.contact_sheet(tiles, columns=len(modes) + 1),
                             "contact sheet: per camera the preview reference and each mode, then error heatmaps"))
    _preview_summary(modes, per_camera, len(lights), summary)
    info["per_camera"] = per_camera
    return pictures, info, []


def _preview_summary(modes, per_camera, n_lights: int, summary: dict) -> None:
    """Per-mode means over the cameras, fetches per pass, and the pass-time ratios, into ``summary``."""
    for m in modes:
        for key in ("image_rmse", "flip", "image_leak", "pass_ms", "pass_ms_min"):
            xs = [c["modes"][m][key] for c in per_camera if c["modes"][m][key] is not None]
            if xs:
                summary[f"{m}.{key}"] = float(np.mean(xs))
        if f"{m}.pass_ms" in summary and f"{m}.gi_fetches_per_pixel" in summary:
            groups = max(1, math.ceil(n_lights / MAX_LIGHTS))   # a further group of 8 lights: position + normal
            summary[f"{m}.pass_fetches_per_pixel"] = (summary[f"{m}.gi_fetches_per_pixel"] + GBUFFER_FETCHES
                                                      + 2 * (groups - 1) + math.ceil(n_lights / 4))
    for a, b in (("mask", "leaking"), ("ddgi", "mask"), ("mask_normalized", "leaking")):
        if f"{a}.pass_ms" in summary and summary.get(f"{b}.pass_ms"):
            summary[f"ratio.{a}_over_{b}.pass_ms"] = summary[f"{a}.pass_ms"] / summary[f"{b}.pass_ms"]
