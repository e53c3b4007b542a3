"""PRT's dataset and its fit (PRT §4.1-4.2): pairs of direct vectors and indirect targets, then basis + transfer.

1. **Scenario** (PRT §4.1): N random lighting configurations
   (:func:`workers.kernels.prt_scenario.random_light_configurations`); positions in the scenario's box,
   redrawn when inside geometry; spots aim at a random point of the scene bounds. A share ``near_surface``
   of the point/spot lights stands ``near_distance`` metres off a surface point (along its normal,
   :func:`workers.kernels.prt_scenario.near_surface_sampler`): lights far from every surface never make the
   concentrated direct field of a lamp next to a wall, and the transfer cannot extrapolate to it.
2. **Measurement points** (§4.1, §5.1): M blue-noise points on the front faces
   (:func:`workers.kernels.prt_scenario.measurement_points`), keeping only candidates that one of the first
   USABLE_TEST_CONFIGS configurations lights (with non-zero albedo): points no light of the scenario reaches
   (the outside of a room) carry no information.
3. **Dataset**. Per configuration k, the direct vector x_k (M, 3) is the outgoing radiance
   ``albedo/π · E_direct`` at the measurement points (:func:`workers.kernels.prt_scenario.measurement_direct`).
   The indirect targets are what the light stage computes for those lights *alone*: **emission excluded and
   sky 0**, so that the target is linear in the lights (an emissive surface or a sky would add a constant that
   no transfer from x could produce). The front-face probe-ray hits are shaded once
   (:func:`workers.kernels.probe_hits.hit_surfaces`) as the light stage shades them — E_direct about the bent
   shading normal, E_indirect times the horizon factor, the near-field occlusion (light stage 8; its occluders'
   emission excluded like the rest) —; per configuration only ``E_direct`` at the hits changes, and the light
   stage's bounce integrator (:func:`workers.kernels.bounce.integrate`, with the light stage's
   ``bounces`` / ``tolerance``, each configuration stopped by its own residual) re-shades the cached hits.
   Targets: (a) the probes' radiance SH (P, K, 3), what the light stage stores as ``probe_sh``; (b) lightmap
   texels (:func:`workers.kernels.lightmap.lightmap_texels`): the DDGI irradiance of the converged probes at
   the texel's surface point (view direction = the normal, with the ray-traced cage visibility,
   :func:`workers.kernels.probe_hits.probe_visibility`).

   Speed: a bounce is linear in the probe irradiance, so the DDGI sampler is turned into a sparse matrix once
   (:func:`workers.kernels.gather.ddgi_weights`) and configurations are solved in batches, 3 colour columns
   each: every bounce is one sparse product and one octahedral accumulation for the whole batch.
4. **Fit** (§4.2, eq 7-10, 14; :func:`fit_targets`): :func:`workers.kernels.prt.fit` per target, the probe basis
   packed into volumes and the lightmap basis into dilated images (:func:`workers.kernels.lightmap.dilate`).

Ray casting comes in as a ``caster`` (shadow rays, inside tests). Consumers: stages/prt. Inverse: none.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

from workers.kernels import prt as kprt
from workers.kernels.bounce import integrate
from workers.kernels.gather import MatrixGather, SamplerGather, ddgi_weights
from workers.kernels.grid import OFF
from workers.kernels.lightmap import DILATE_TEXELS, dilate, lightmap_texels
from workers.kernels.probe_hits import HitSurfaces, hit_surfaces, near_occlusion, probe_visibility
from workers.kernels.prt_scenario import (measurement_direct, measurement_points, near_surface_sampler,
                                         random_light_configurations)
from workers.kernels.sh import sh_count, sh_project_probes
from workers.kernels.shading import direct_irradiance, horizon_factor

__all__ = ["PrtDataset", "PrtTooLarge", "build_dataset", "solve_batch", "fit_targets"]

BATCH_BYTES = 256 << 20
"""Bytes of per-ray radiance (P·R·3·4 per configuration) a batch of configurations may hold."""
DATASET_BYTES = 4 << 30
"""Refuse (:class:`PrtTooLarge`) a dataset plus DDGI matrices larger than this."""
USABLE_TEST_CONFIGS = 64
"""Measurement candidates must be lit by one of the first this many configurations to be kept."""


class PrtTooLarge(ValueError):
    """The dataset would not fit in DATASET_BYTES (the stage answers ``prt_too_large``)."""


@dataclass
class PrtDataset:
    """What the fit sees (PRT §4.1), plus what tests and benchmarks need to check it.

    configs : N lists of lights; points : measurement samples (see
    :func:`workers.kernels.prt_scenario.measurement_points`); direct : (N, M, 3) float64 direct vectors;
    sh : (N, P, K, 3) float32 probe radiance SH; texels : (N, L, 3) float32 lightmap texel irradiance, or None;
    lightmap : :func:`workers.kernels.lightmap.lightmap_texels` output (plus ``visible``) or None; probes : dict
    of what the light stage's math needs (``surf``, ``grid``, ``positions``, ``states``, ``depth``, ``dirs``,
    ``n``, ``bias``, ``caster``, ``eps``, ``visible``); bounces : (N,) int; timings : dict of seconds.
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


def solve_batch(surf: HitSurfaces, W: sp.csr_matrix, e_direct: np.ndarray, dirs: np.ndarray, states: np.ndarray,
                n: int, *, bounces: int | None, max_bounces: int, tolerance: float, sh_order: int,
                W_texels: sp.csr_matrix | None = None, indirect_scale: np.ndarray | None = None, near=None):
    """The light stage's bounce integrator (:func:`workers.kernels.bounce.integrate`, emission 0, sky 0) for B
    lighting configurations at once, E_indirect by the sparse DDGI matrix ``W`` (or ``W`` a gather callable: the
    light stage's SH gather, :class:`workers.kernels.gather.SamplerGather` ``read="sh"``).

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
        sh = sh_project_probes(dirs, radiance, order=sh_order).astype(np.float32)
        sh[off] = 0.0
        sh_out[ids] = sh.reshape(P, K, -1, 3).transpose(2, 0, 1, 3)
        maps_out[ids] = maps.reshape(P, t, t, -1, 3).transpose(3, 0, 1, 2, 4)
        if W_texels is not None:
            tex_out[ids] = (W_texels @ maps.reshape(P * t * t, -1)).reshape(-1, len(ids), 3).transpose(1, 0, 2)

    gather = MatrixGather(W) if sp.issparse(W) else W
    log = integrate(surf.index, surf.miss, surf.albedo, e_direct, dirs, states, n, gather, retire,
                    bounces=bounces, max_bounces=max_bounces, tolerance=tolerance, indirect_scale=indirect_scale,
                    near=near)
    return sh_out, tex_out, log.bounces, maps_out


def build_dataset(scene, caster, rng: np.random.Generator, *, grid: dict, dirs, hits, tri, states, depth, positions,
                  bounds, scenario: dict, box, configurations: int, n_points: int, supersampling: int,
                  lightmap: int, light, report=lambda f: None) -> PrtDataset:
    """Steps 1-3 of the module doc.

    Parameters
    ----------
    scene : NormalizedScene; caster : ``occluded``, ``inside_parity`` (:mod:`workers.raycast`); rng : the
        stage's random stream.
    grid : ``counts``, ``origin``, ``spacing``; dirs (R, 3) or ProbeRays, hits (P, R, 4), tri (P, R): the trace stage's
        cached probe rays; states (P,); depth (P, m+2, m+2, 2) depth moments with border; positions (P, 3)
        relocated probes, metres.
    bounds : (2, 3) float64 scene bounds, metres (spot targets; the shadow offset eps = 1e-4 x diagonal, as
        the light stage).
    scenario : dict (``prt.scenario``); box : (lo, hi) where lights are placed; configurations (N),
        n_points (M), supersampling (S), lightmap (texels per side, 0 = none): ``prt`` settings.
    light : ``BakeConfig.light`` (irradiance_texels, self_shadow_bias, bounces, max_bounces, tolerance, sh_order).
    report : ``report(fraction)``.
    """
    timings = {}
    t0 = time.perf_counter()
    eps = 1e-4 * max(float(np.linalg.norm(bounds[1] - bounds[0])), 1e-3)   # as the light stage
    n_irr = light.irradiance_texels
    bias = light.self_shadow_bias
    # 1. lighting scenario (PRT §4.1)
    near = None
    if scenario.get("near_surface", 0.0) > 0:
        near = near_surface_sampler(scene, rng, scenario["near_distance"])
    configs = random_light_configurations(rng, scenario, configurations, box[0], box[1],
                                          inside=caster.inside_parity, target_box=(bounds[0], bounds[1]), near=near)
    # 2. measurement points (§4.1, §5.1), on surfaces some configuration lights
    probe_configs = configs[:USABLE_TEST_CONFIGS]

    def lit_by_scenario(pos, nrm, alb):
        lit = np.zeros(pos.shape[0], bool)
        for lights in probe_configs:
            lit |= np.any(direct_irradiance(pos, nrm, lights, caster, eps) > 0, axis=1)
        return lit & np.any(alb > 0, axis=1)

    points = measurement_points(scene, n_points, supersampling, rng, usable=lit_by_scenario)
    timings["points_seconds"] = time.perf_counter() - t0
    report(0.05)

    # 3. dataset: shading data of the cached hits once, the DDGI sampler as matrices once
    t1 = time.perf_counter()
    surf = hit_surfaces(scene, dirs, hits, tri)
    # shaded as the light stage shades them (workers/stages/light.py): E_direct about the bent normal N' with lights
    # below the geometric plane rejected, E_indirect times the horizon factor, the near-field occlusion (its
    # occluders' emission left out: the transfer is linear in the lights, PRT §4)
    frame = dict(geo_normals=surf.geo_normal, smooth_normals=surf.smooth_normal, bent=surf.bent)
    horizon = horizon_factor(surf.normal, surf.geo_normal, surf.smooth_normal, surf.bent).astype(np.float32)
    horizon = None if not (horizon < 1).any() else horizon
    near = None
    if light.near_radius > 0 and light.near_rays > 0:
        near = near_occlusion(scene, surf.position, surf.normal, surf.geo_normal, caster,
                              light.near_radius * float(min(grid["spacing"])), light.near_rays, eps)
        near.a *= np.float32(light.near_strength)
        near.emission = np.zeros_like(near.emission)
    visible, _ = probe_visibility(surf, grid, positions, states, caster, bias)   # as the light stage
    if light.gather == "sh":    # the light stage's gather (light.gather): each cage probe's L2 SH at the hit's normal
        W = SamplerGather(surf.position, surf.normal, surf.view, grid, positions, states, depth, bias, visible,
                          n=n_irr, read="sh")
    else:
        W = ddgi_weights(surf.position, surf.normal, surf.view, grid, positions, states, depth, n_irr, bias, visible)
    lm = None
    W_lm = None
    N = configurations
    K = sh_count(light.sh_order)
    if lightmap > 0:
        lm = lightmap_texels(scene, lightmap)
    texels = int(lm["covered"].sum()) if lm is not None else 0
    need = N * 3 * 4 * (surf.P * K + texels) + 32 * 8 * (texels + surf.index.size)
    if need > DATASET_BYTES:
        raise PrtTooLarge(f"the PRT dataset would need {need / 2 ** 30:.1f} GiB ({N} configurations "
                          f"x ({surf.P} probes x {K} SH + {texels} lightmap texels) x 3 channels, plus the DDGI "
                          "matrices); lower prt.configurations or prt.lightmap "
                          f"(limit {DATASET_BYTES / 2 ** 30:.0f} GiB)")
    if lm is not None:
        texel_points = SimpleNamespace(position=lm["position"], normal=lm["normal"], view=lm["normal"])
        lm["visible"], _ = probe_visibility(texel_points, grid, positions, states, caster, bias)
        W_lm = ddgi_weights(lm["position"], lm["normal"], lm["normal"], grid, positions, states, depth, n_irr, bias,
                            lm["visible"])
    timings["setup_seconds"] = time.perf_counter() - t1
    report(0.1)

    t2 = time.perf_counter()
    P, R = surf.P, surf.R
    direct = np.zeros((N, n_points, 3), np.float64)
    sh_all = np.zeros((N, P, K, 3), np.float32)
    tex_all = np.zeros((N, W_lm.shape[0], 3), np.float32) if W_lm is not None else None
    n_bounces = np.zeros(N, np.int64)
    batch = int(np.clip(BATCH_BYTES // max(P * R * 3 * 4, 1), 1, 64))
    direct_s = 0.0
    for a in range(0, N, batch):
        ids = range(a, min(N, a + batch))
        td = time.perf_counter()
        e = np.stack([direct_irradiance(surf.position, surf.normal, configs[k], caster, eps, **frame) for k in ids])
        for k in ids:
            direct[k] = measurement_direct(points, configs[k], caster, eps)
        direct_s += time.perf_counter() - td
        sh, tex, cnt, _ = solve_batch(surf, W, e, dirs, states, n_irr, bounces=light.bounces,
                                      max_bounces=light.max_bounces, tolerance=light.tolerance,
                                      sh_order=light.sh_order, W_texels=W_lm, indirect_scale=horizon, near=near)
        sh_all[a:a + len(ids)] = sh
        if tex_all is not None:
            tex_all[a:a + len(ids)] = tex
        n_bounces[a:a + len(ids)] = cnt
        report(0.1 + 0.8 * min(N, a + batch) / N)
    timings["dataset_seconds"] = time.perf_counter() - t2
    timings["direct_seconds"] = direct_s
    probes = {"surf": surf, "grid": grid, "positions": positions, "states": states, "depth": depth, "dirs": dirs,
              "n": n_irr, "bias": bias, "caster": caster, "eps": eps, "visible": visible, "shading": frame,
              "horizon": horizon, "near": near}
    return PrtDataset(configs=configs, points=points, direct=direct, sh=sh_all, texels=tex_all, lightmap=lm,
                      probes=probes, bounces=n_bounces, timings=timings)


def fit_targets(ds: PrtDataset, *, basis: int, ridge: float, gamma: float | None, channels: str, lightmap: int,
                norm: str = "l2", ridge_folds: int = 0):
    """Step 4 (PRT §4.2): basis and transfer of each target, packed for the bundle.

    Returns a namespace: ``sh`` (the :class:`workers.kernels.prt.PrtFit` of the probe SH), ``sh_volumes``
    (:func:`workers.kernels.prt.sh_volumes`), ``sh_stats`` (:func:`workers.kernels.prt.fit_stats`), and ``lm``:
    None, or a namespace with ``fit``, ``textures`` ``[(name, (R, R, 4) float32)]`` (the basis images dilated
    DILATE_TEXELS texels), ``mask`` (R, R) uint8 (0 empty, 1 sampled, 2 dilated) and ``stats``.
    """
    N, P, K = ds.sh.shape[:3]
    sh_target = ds.sh.reshape(N, P * K, 3)
    fit_sh = kprt.fit(ds.direct, sh_target, basis, ridge, gamma, channels, norm, ridge_folds)   # PRT eq 7-10, eq 14
    out = SimpleNamespace(sh=fit_sh, sh_volumes=kprt.sh_volumes(fit_sh.slots, channels, ds.probes["grid"]["counts"], K),
                          sh_stats=kprt.fit_stats(fit_sh, ds.direct, sh_target), lm=None)
    lm, tex_all = ds.lightmap, ds.texels
    if lm is not None and tex_all is not None and tex_all.shape[1] > 0:
        fit_lm = kprt.fit(ds.direct, tex_all, basis, ridge, gamma, channels, norm, ridge_folds)
        cov = lm["covered"]
        c_ = 1 if channels == "mono" else 3
        imgs = np.zeros((fit_lm.n, c_, lightmap, lightmap), np.float32)
        imgs[:, :, cov] = fit_lm.slots.reshape(fit_lm.n, -1, c_).transpose(0, 2, 1)
        imgs, grown = dilate(imgs, cov, DILATE_TEXELS)                      # linear: relit maps dilate too
        imgs = imgs[:, 0] if c_ == 1 else np.ascontiguousarray(np.moveaxis(imgs, 1, -1))
        mask = np.where(cov, 1, np.where(grown, 2, 0)).astype(np.uint8)
        out.lm = SimpleNamespace(fit=fit_lm, textures=kprt.lm_textures(imgs, channels), mask=mask,
                                 stats=kprt.fit_stats(fit_lm, ds.direct, tex_all))
    return out
