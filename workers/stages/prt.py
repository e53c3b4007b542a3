"""Stage ``prt``: a relightable, data-driven transfer (PRT §3-5; DESIGN stage 6).

Reads ingest (bounds), place (grid), relocate (probe positions), trace (cached probe-ray hits, depth
moments, states) and light (only for ordering and cache keys; its settings come from ``config.light``).
Off unless ``config.prt.enabled``: then it returns no artifacts and stats ``{"enabled": false}``.

1. **Scenario** (PRT §4.1): N = ``prt.configurations`` random lighting configurations from
   ``prt.scenario`` (:func:`workers.kernels.prt_scenario.random_light_configurations`), seeded by the bake seed;
   positions in ``scenario.box`` (default: the scene bounds), redrawn when inside geometry; spots aim at
   a random point of the scene bounds.
2. **Measurement points** (§4.1): M = ``prt.measurement_points`` blue-noise points on the front faces of
   the triangles, by sample elimination [Yuksel15] from 5·M·S uniform area-weighted candidates, keeping
   only candidates that one of the first 64 configurations lights (with non-zero albedo): points no
   light of the scenario reaches (the outside of a room) carry no information. With supersampling
   S > 1 (§5.1), M·S points are kept and grouped by their nearest of M points chosen by a second
   elimination; a measurement point's direct value is its group's mean.
3. **Dataset**. Per configuration k, the direct vector x_k (M, 3) is the outgoing radiance
   ``albedo/π · E_direct`` at the measurement points (shadow rays, :func:`shading.direct_irradiance`). The
   indirect targets are computed exactly as the light stage would for those lights *alone*: **emission
   excluded and sky 0**, so that the target is linear in the lights (an emissive surface or a sky would
   add a constant that no transfer from x could produce). The front-face probe-ray hits are shaded once
   (:func:`light.hit_surfaces`); for each configuration only ``E_direct`` at the hits changes, and the
   bounces re-shade the cached hits (nothing is re-traced but shadow rays) with the light stage's bounce
   settings (``light.bounces`` or convergence to ``light.tolerance``, per configuration).
   Targets: (a) the probes' radiance SH (P, K, 3) (``light.sh_order``), what the light stage stores as
   ``probe_sh``; (b) lightmap texels (``prt.lightmap``² texels, 0 = none): TEXCOORD_1 charts where the
   scene has them (one chart per glTF node), xatlas UVs for the other triangles, packed at a uniform
   texel density; a texel's value is the DDGI irradiance (:func:`ddgi.sample_irradiance`, view direction =
   the normal, with the light stage's ray-traced cage visibility, :func:`light.probe_visibility`) of that
   configuration's converged probes at the texel's surface point.

   Speed: a bounce is linear in the probe irradiance, so the DDGI sampler is turned into a sparse
   matrix once (:func:`ddgi_weights`: 8 probes x 4 bilinear texels per point, read back from the real
   sampler) and configurations are solved in batches, 3 colour columns each: every bounce is one sparse
   product and one octahedral accumulation for the whole batch. Tests check it against
   :func:`workers.stages.light.integrate`.
4. **Fit** (§4.2, eq 7-10, 14): :func:`workers.kernels.prt.fit` per target — normalized by ‖x‖,
   mean-subtracted, optional gamma (§5.3), SVD, ``n = prt.basis`` slots (the mean counts as one, as in
   PRT), ridge λ = ``prt.ridge`` with an intercept on the ‖x‖ column (see the kernel's doc: without it
   eq 14 cannot reproduce even linear data), columns whose light the points barely see dropped
   (``kernels.prt.OUTLIER_RATIO``); mono (default: shared basis, one transfer per colour channel) or
   multi.

Artifacts (stage ``prt``; the layout is documented in ``proto/bundle.md`` by the lead):

========================= ================================ ===========================================
name                      shape, format                    content
========================= ================================ ===========================================
``prt``                   json                             the PRT section: settings, sizes, artifact
                                                           names, per-target fit statistics
``prt_lights``            json                             ``{"configurations": [[light, ...], ...]}``
``prt_points``            npy (M·S, 9) float32             position xyz (m), normal xyz, albedo rgb of
                                                           each measurement sample, grouped by point
``prt_point_offsets``     npy (M + 1,) int32               point m averages rows offsets[m]:offsets[m+1]
``prt_sh_transfer``       npy (C, n, D + 1) float32        mono: C = 3 (R, G, B), D = M; multi: C = 1,
                                                           D = 3M (x interleaved rgb); acts on [x, ‖x‖]
``prt_sh_basis_c{k}_g{g}`` ktx2 (nz, ny, nx, 4) float32   SH coefficient k of slots 4g..4g+3 (mono;
                                                           slot 0 = mean); multi: slot g's rgb, a = 0
``prt_lm_transfer``       npy (C, n, D + 1) float32        as prt_sh_transfer, for the lightmap
``prt_lm_basis_g{g}``     ktx2 (R, R, 4) float32           lightmap slots 4g..4g+3 (multi: slot g rgb),
                                                           dilated 2 texels
``prt_lm_mask``           ktx2 (R, R) uint8 (R8)           0 empty, 1 sampled texel, 2 dilated
``prt_lm_uv``             npy (T, 3, 2) float32            the lightmap UV of every triangle corner
========================= ================================ ===========================================

Relighting (:mod:`workers.prt_relight`): x from the new lights at the measurement points, then per
channel ``u = T_c [x_c, ‖x_c‖]`` (row 0 gives u_0 = ‖x_c‖), ``y_c = Σ_j u_j · slot_j`` (g⁻¹ with gamma).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

from workers.kernels import prt as kprt
from workers.kernels.bounce import integrate
from workers.kernels.gather import MatrixGather, ddgi_weights
from workers.kernels.grid import OFF, unpack_atlas
from workers.kernels.lightmap import DILATE_TEXELS, dilate, lightmap_texels
from workers.kernels.probe_hits import HitSurfaces, hit_surfaces, probe_visibility
from workers.kernels.prt_scenario import (measurement_direct, measurement_points, random_light_configurations,
                                         triangle_areas)
from workers.kernels.sh import sh_count, sh_project
from workers.kernels.shading import direct_irradiance
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageError, StageOutput

PRT_SEED_SALT = 0x505254
"""Mixed with the bake seed for the stage's random stream ("PRT")."""
BATCH_BYTES = 256 << 20
"""Bytes of per-ray radiance (P·R·3·4 per configuration) a batch of configurations may hold."""
DATASET_BYTES = 4 << 30
"""Refuse (StageError prt_too_large) a dataset plus DDGI matrices larger than this."""
USABLE_TEST_CONFIGS = 64
"""Measurement candidates must be lit by one of the first this many configurations to be kept."""


# ------------------------------------------------------------------------------------- dataset solver
def solve_batch(surf: HitSurfaces, W: sp.csr_matrix, e_direct: np.ndarray, dirs: np.ndarray, states: np.ndarray,
                n: int, *, bounces: int | None, max_bounces: int, tolerance: float, sh_order: int,
                W_texels: sp.csr_matrix | None = None):
    """The light stage's bounce integrator (:func:`workers.kernels.bounce.integrate`, emission 0, sky 0) for B
    lighting configurations at once, E_indirect by the sparse DDGI matrix ``W``.

    e_direct : (B, H, 3) direct irradiance at the front-face hits per configuration.
    Returns ``(sh (B, P, K, 3) float32, texels (B, T, 3) float32 or None, bounces (B,) int,
    maps (B, P, n+2, n+2, 3) float32)``: the probes' radiance SH (OFF probes 0), the DDGI irradiance at
    the rows of ``W_texels``, the bounce count and the converged irradiance maps of each configuration.
    """
    P, R = surf.P, surf.R
    B = e_direct.shape[0]
    t = n + 2
    K = sh_count(sh_order)
    sh_out = np.zeros((B, P, K, 3), np.float32)
    tex_out = None if W_texels is None else np.zeros((B, W_texels.shape[0], 3), np.float32)
    maps_out = np.zeros((B, P, t, t, 3), np.float32)
    off = states == OFF

    def retire(ids, radiance, maps, b):
        sh = sh_project(dirs, radiance, order=sh_order).astype(np.float32)
        sh[off] = 0.0
        sh_out[ids] = sh.reshape(P, K, -1, 3).transpose(2, 0, 1, 3)
        maps_out[ids] = maps.reshape(P, t, t, -1, 3).transpose(3, 0, 1, 2, 4)
        if W_texels is not None:
            tex_out[ids] = (W_texels @ maps.reshape(P * t * t, -1)).reshape(-1, len(ids), 3).transpose(1, 0, 2)

    log = integrate(surf.index, surf.miss, surf.albedo, e_direct, dirs, states, n, MatrixGather(W), retire,
                    bounces=bounces, max_bounces=max_bounces, tolerance=tolerance)
    return sh_out, tex_out, log.bounces, maps_out


# ------------------------------------------------------------------------------------------- the stage
@dataclass
class PrtDataset:
    """What the fit sees (PRT §4.1), plus what tests and benchmarks need to check it.

    configs : N lists of lights; points : measurement samples (see :func:`measurement_points`);
    direct : (N, M, 3) float64 direct vectors; sh : (N, P, K, 3) float32 probe radiance SH;
    texels : (N, L, 3) float32 lightmap texel irradiance, or None; lightmap : :func:`lightmap_texels`
    output or None; probes : dict of what the light stage's math needs (``surf``, ``grid``,
    ``positions``, ``states``, ``depth``, ``dirs``, ``n``, ``bias``, ``caster``, ``eps``);
    bounces : (N,) int; timings : dict of seconds.
    """

    configs: list
    points: dict
    direct: np.ndarray
    sh: np.ndarray
    texels: np.ndarray | None
    lightmap: dict | None
    probes: dict
    bounces: np.ndarray
    timings: dict


def prt_dataset(ctx: StageContext) -> PrtDataset:
    """Steps 1-3 of the module doc: scenario, measurement points and the dataset of direct/indirect pairs."""
    sec = ctx.config.prt
    lsec = ctx.config.light
    scene = ctx.scene
    timings = {}
    t0 = time.perf_counter()
    place = ctx.inputs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    tr = ctx.inputs["trace"]
    dirs, hits, tri = tr["ray_directions"], tr["ray_hits"], tr["ray_tri"]
    states = tr["probe_states"].reshape(-1)
    depth = unpack_atlas(tr["depth_moments"], grid["counts"], ctx.config.trace.depth_texels + 2)
    positions = ctx.inputs["relocate"]["probe_positions_relocated"].reshape(-1, 3).astype(np.float32)
    bounds = np.asarray(ctx.inputs["ingest"].stats["bounds"], np.float64)
    eps = 1e-4 * max(float(np.linalg.norm(bounds[1] - bounds[0])), 1e-3)   # as the light stage
    n_irr = lsec.irradiance_texels
    bias = lsec.self_shadow_bias
    if triangle_areas(scene.triangles).sum() <= 0:
        raise StageError("no_surface", "the scene's triangles have no area to place measurement points on")
    caster = caster_for_scene(scene)
    rng = np.random.default_rng([ctx.config.seed, PRT_SEED_SALT])

    # 1. lighting scenario (PRT §4.1)
    scen = sec.scenario
    box = (scen.box.min, scen.box.max) if scen.box is not None else (bounds[0], bounds[1])
    configs = random_light_configurations(rng, scen.model_dump(), sec.configurations, box[0], box[1],
                                          inside=caster.inside_parity, target_box=(bounds[0], bounds[1]))
    # 2. measurement points (§4.1, §5.1), on surfaces some configuration lights
    probe_configs = configs[:USABLE_TEST_CONFIGS]

    def lit_by_scenario(pos, nrm, alb):
        lit = np.zeros(pos.shape[0], bool)
        for lights in probe_configs:
            lit |= np.any(direct_irradiance(pos, nrm, lights, caster, eps) > 0, axis=1)
        return lit & np.any(alb > 0, axis=1)

    points = measurement_points(scene, sec.measurement_points, sec.supersampling, rng, usable=lit_by_scenario)
    timings["points_seconds"] = time.perf_counter() - t0
    ctx.report(0.05)

    # 3. dataset: shading data of the cached hits once, the DDGI sampler as matrices once
    t1 = time.perf_counter()
    surf = hit_surfaces(scene, dirs, hits, tri)
    visible, _ = probe_visibility(surf, grid, positions, states, caster, bias)   # as the light stage
    W = ddgi_weights(surf.position, surf.normal, surf.view, grid, positions, states, depth, n_irr, bias, visible)
    lm = None
    W_lm = None
    N = sec.configurations
    K = sh_count(lsec.sh_order)
    if sec.lightmap > 0:
        lm = lightmap_texels(scene, sec.lightmap)
    texels = int(lm["covered"].sum()) if lm is not None else 0
    need = N * 3 * 4 * (surf.P * K + texels) + 32 * 8 * (texels + surf.index.size)
    if need > DATASET_BYTES:
        raise StageError("prt_too_large", f"the PRT dataset would need {need / 2 ** 30:.1f} GiB ({N} configurations "
                         f"x ({surf.P} probes x {K} SH + {texels} lightmap texels) x 3 channels, plus the DDGI "
                         "matrices); lower prt.configurations or prt.lightmap "
                         f"(limit {DATASET_BYTES / 2 ** 30:.0f} GiB)")
    if lm is not None:
        texel_points = SimpleNamespace(position=lm["position"], normal=lm["normal"], view=lm["normal"])
        lm["visible"], _ = probe_visibility(texel_points, grid, positions, states, caster, bias)
        W_lm = ddgi_weights(lm["position"], lm["normal"], lm["normal"], grid, positions, states, depth, n_irr, bias,
                            lm["visible"])
    timings["setup_seconds"] = time.perf_counter() - t1
    ctx.report(0.1)

    t2 = time.perf_counter()
    P, R = surf.P, surf.R
    direct = np.zeros((N, sec.measurement_points, 3), np.float64)
    sh_all = np.zeros((N, P, K, 3), np.float32)
    tex_all = np.zeros((N, W_lm.shape[0], 3), np.float32) if W_lm is not None else None
    n_bounces = np.zeros(N, np.int64)
    batch = int(np.clip(BATCH_BYTES // max(P * R * 3 * 4, 1), 1, 64))
    direct_s = 0.0
    for a in range(0, N, batch):
        ids = range(a, min(N, a + batch))
        td = time.perf_counter()
        e = np.stack([direct_irradiance(surf.position, surf.normal, configs[k], caster, eps) for k in ids])
        for k in ids:
            direct[k] = measurement_direct(points, configs[k], caster, eps)
        direct_s += time.perf_counter() - td
        sh, tex, cnt, _ = solve_batch(surf, W, e, dirs, states, n_irr, bounces=lsec.bounces,
                                      max_bounces=lsec.max_bounces, tolerance=lsec.tolerance,
                                      sh_order=lsec.sh_order, W_texels=W_lm)
        sh_all[a:a + len(ids)] = sh
        if tex_all is not None:
            tex_all[a:a + len(ids)] = tex
        n_bounces[a:a + len(ids)] = cnt
        ctx.report(0.1 + 0.8 * min(N, a + batch) / N)
    timings["dataset_seconds"] = time.perf_counter() - t2
    timings["direct_seconds"] = direct_s
    probes = {"surf": surf, "grid": grid, "positions": positions, "states": states, "depth": depth, "dirs": dirs,
              "n": n_irr, "bias": bias, "caster": caster, "eps": eps, "visible": visible}
    return PrtDataset(configs=configs, points=points, direct=direct, sh=sh_all, texels=tex_all, lightmap=lm,
                      probes=probes, bounces=n_bounces, timings=timings)


def run_prt(ctx: StageContext) -> StageOutput:
    if not ctx.config.prt.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    t0 = time.perf_counter()
    return prt_output(ctx, prt_dataset(ctx), t0)


def prt_output(ctx: StageContext, ds: PrtDataset, t0: float | None = None) -> StageOutput:
    """Step 4 and the artifacts: fit the basis and transfer of each target and pack them."""
    sec = ctx.config.prt
    lsec = ctx.config.light
    t0 = time.perf_counter() if t0 is None else t0
    timings = dict(ds.timings)
    configs, points, direct, sh_all, tex_all, lm = ds.configs, ds.points, ds.direct, ds.sh, ds.texels, ds.lightmap
    grid = ds.probes["grid"]
    nx, ny, nz = grid["counts"]
    N, P, K = sh_all.shape[:3]
    eps = ds.probes["eps"]
    surf = ds.probes["surf"]
    n_bounces = ds.bounces

    # 4. basis and transfer per target (§4.2)
    t3 = time.perf_counter()
    fit_sh = kprt.fit(direct, sh_all.reshape(N, P * K, 3), sec.basis, sec.ridge, sec.gamma, sec.channels)
    artifacts: list[Artifact] = []
    sh_names = []
    for k, group in enumerate(kprt.sh_volumes(fit_sh.slots, sec.channels, grid["counts"], K)):
        sh_names.append([name for name, _ in group])
        for g, (name, vol) in enumerate(group):
            artifacts.append(Artifact(name, np.ascontiguousarray(vol, np.float32),
                                      description=f"PRT probe basis: SH coefficient {k}, slot group {g}",
                                      meta={"coefficient": k, "group": g, "channels": sec.channels}))
    artifacts.append(Artifact("prt_sh_transfer", fit_sh.transfer, format="npy",
                              description="PRT transfer to the probe SH basis coefficients (PRT eq 14)"))
    stats_sh = kprt.fit_stats(fit_sh, direct, sh_all.reshape(N, P * K, 3))
    lm_info = None
    if lm is not None and tex_all is not None and tex_all.shape[1] > 0:
        fit_lm = kprt.fit(direct, tex_all, sec.basis, sec.ridge, sec.gamma, sec.channels)
        res = sec.lightmap
        cov = lm["covered"]
        c_ = 1 if sec.channels == "mono" else 3
        imgs = np.zeros((fit_lm.n, c_, res, res), np.float32)
        imgs[:, :, cov] = fit_lm.slots.reshape(fit_lm.n, -1, c_).transpose(0, 2, 1)
        imgs, grown = dilate(imgs, cov, DILATE_TEXELS)                 # linear: relit maps dilate too
        imgs = imgs[:, 0] if c_ == 1 else np.ascontiguousarray(np.moveaxis(imgs, 1, -1))
        mask = np.where(cov, 1, np.where(grown, 2, 0)).astype(np.uint8)
        lm_names = []
        for name, tex in kprt.lm_textures(imgs, sec.channels):
            lm_names.append(name)
            artifacts.append(Artifact(name, np.ascontiguousarray(tex, np.float32),
                                      description="PRT lightmap basis (mono: four slots per texel, slot 0 = mean)"))
        artifacts += [
            Artifact("prt_lm_transfer", fit_lm.transfer, format="npy",
                     description="PRT transfer to the lightmap basis coefficients (PRT eq 14)"),
            Artifact("prt_lm_mask", mask, description="lightmap texels: 0 empty, 1 sampled, 2 dilated"),
            Artifact("prt_lm_uv", lm["uv"], format="npy", description="lightmap UV per triangle corner"),
        ]
        lm_info = {"resolution": res, "texels": int(cov.sum()), "dilated": int((mask == 2).sum()),
                   "uv_source": lm["source"], "texels_per_metre": lm["texels_per_metre"],
                   "basis": lm_names, "transfer": "prt_lm_transfer", "mask": "prt_lm_mask", "uv": "prt_lm_uv",
                   "unit": "irradiance (lux x colour): DDGI sample of the probes, view = normal",
                   **kprt.fit_stats(fit_lm, direct, tex_all)}
    timings["fit_seconds"] = time.perf_counter() - t3

    pts = points
    table = np.concatenate([pts["position"], pts["normal"], pts["albedo"]], axis=1).astype(np.float32)
    section = {
        "version": 1, "channels": sec.channels, "gamma": sec.gamma, "ridge": sec.ridge, "basis": sec.basis,
        "configurations": N, "measurement_points": sec.measurement_points, "supersampling": sec.supersampling,
        "shadow_eps": eps, "points": "prt_points", "point_offsets": "prt_point_offsets", "lights": "prt_lights",
        "direct": "outgoing radiance albedo/pi * E_direct at the measurement points, averaged per point",
        "normalization": "u = T [x, |x|] per channel (row 0 gives u_0 = |x|); y = sum_j u_j * slot_j",
        "emission": "excluded (sky 0): the transfer covers the given lights only",
        "sh": {"order": lsec.sh_order, "coefficients": K, "counts": [nx, ny, nz], "basis": sh_names,
               "transfer": "prt_sh_transfer", "unit": "radiance SH per probe (three.js order), as probe_sh",
               **stats_sh},
        "lightmap": lm_info,
    }
    artifacts += [
        Artifact("prt", section, format="json", description="PRT section: settings, sizes, artifact names"),
        Artifact("prt_lights", {"configurations": configs}, format="json",
                 description="the dataset's random lighting configurations"),
        Artifact("prt_points", table, format="npy",
                 description="measurement samples: position xyz, normal xyz, albedo rgb (grouped by point)"),
        Artifact("prt_point_offsets", pts["offsets"], format="npy",
                 description="point m averages samples offsets[m]:offsets[m+1]"),
    ]
    timings["total_seconds"] = time.perf_counter() - t0
    stats = {
        "enabled": True, "configurations": N, "measurement_points": sec.measurement_points,
        "supersampling": sec.supersampling, "basis": sec.basis, "channels": sec.channels,
        "usable_surface_fraction": points["usable_fraction"], "front_hits": int(surf.index.size),
        "bounces_mean": float(n_bounces.mean()),
        "bounces_max": int(n_bounces.max(initial=0)),
        "sh_energy_kept": stats_sh["energy_kept"], "sh_train_rmse": stats_sh["train_rmse"],
        "lightmap_texels": lm_info["texels"] if lm_info else 0,
        "warnings": (lm["warnings"] if lm else []) + (
            ["no configuration lit any measurement point: the transfer is zero"] if fit_sh.columns == 0 else []),
        **timings,
    }
    if lm_info:
        stats["lm_energy_kept"] = lm_info["energy_kept"]
        stats["lm_train_rmse"] = lm_info["train_rmse"]
    ctx.report(1.0)
    return StageOutput(artifacts=artifacts, stats=stats)
