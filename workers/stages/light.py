"""Stage ``light``: multi-bounce probe irradiance from the cached probe-ray hits (DDGI-I §3.4-3.5).

An adapter: it reads the trace, relocate, place and ingest outputs and calls the kernels —
:func:`workers.kernels.probe_hits.hit_surfaces` (the front-face hits, shaded once),
:func:`workers.kernels.shading.direct_irradiance` (E_direct with shadow rays, once),
:func:`workers.kernels.probe_hits.probe_visibility` (ray-traced cage visibility, once: Chebyshev alone leaks a
few % through thin walls) and the bounce integrator :func:`workers.kernels.bounce.integrate_one` (radiance
``emission + albedo/π · (E_direct + E_indirect)`` at front-face hits, the sky at misses, 0 at back faces;
DDGI-I eq 1 with α = 0 per bounce; E_indirect by the DDGI sampler, :class:`workers.kernels.gather.SamplerGather`:
its weights over each cage probe's L2 SH irradiance at the hit's normal, the SH projected from the bounce's own rays
(``light.gather = "sh"``, light stage 11; ``"octahedral"`` reads the probes' 8-texel maps as DDGI's runtime does,
which reads a room lit through a door 10-20% bright where its walls stand at an angle to the grid:
docs/architecture.md, "The gather reads the probes' SH")).
Bent shading normals: each hit is shaded as Cycles 3.4 would for a viewer at the probe
(:func:`workers.kernels.probe_hits.hit_surfaces`): closure normal ``N' = ensure_valid_reflection(Ng, view, N)``;
E_direct about N' with lights below the geometric plane rejected and, where N' was bent, Cycles' bump shadowing
term; E_indirect gathered about N' and multiplied by the horizon factor h (:func:`workers.kernels.shading.
horizon_factor`: ``(1 + N'·Ng)/2``, the part of a cosine lobe about N' above the geometric plane under uniform
radiance; on bent hits a quadrature that includes the bump term), since the probes' irradiance holds light from
behind the surface that the surface itself cannot see. Flat-shaded hits (N'·Ng > 1 − 1e-6) get h = 1 exactly and
bake bit-identically (stats ``bent_hits``, ``horizon_hits``, ``horizon_mean``). h assumes uniform radiance: where the
tilted lobe dips below the plane into bright geometry the probes still see, E_indirect stays somewhat high (a bent
floor under a sun: 3%, tests/workers/test_light.py). The point lights' hot spots (below) are shaded about the
interpolated normal, as before.
Near-field occlusion (:func:`workers.kernels.probe_hits.near_occlusion`, once per geometry): ``light.near_rays``
cosine-distributed rays per hit out to ``light.near_radius`` × the smallest spacing find the part a of the hit's lobe
that nearby geometry covers (the probes, up to a cell away, report the far field there) and the occluders' albedo
and emission; each bounce shades ``E_indirect = (1 − s·a)·G + s·a·(π·L'_e + ρ'·(E_direct + E_indirect'))``, s =
``light.near_strength`` (a fit, docs/architecture.md), the hit's previous bounce standing in for the nearby surface's
irradiance (:func:`workers.kernels.bounce.integrate` ``near``). Hits with nothing within the radius: G exactly
(stats ``near_hits``, ``near_rays``, ``near_mean`` the mean a over all hits before the weight, ``near_seconds``).
The hot spots a point / spot light makes on a surface next to it (direct irradiance above 32x the light's median at
the hits) are sampled from the light (:mod:`workers.kernels.light_spots`): the rays carry the bounded part, virtual
point lights the excess, added to every bounce's maps and to the SH (stats ``spot_lights``, ``spot_rays``).
L2 deringing (:func:`workers.kernels.sh.sh_l2_floor`): each probe's L2 SH changed as little as possible so that its
L2 irradiance is at least 0.75 of its own octahedral map at every texel direction (no change where L2 does not ring);
then, where it still dips below 0 between those directions, its L1 and L2 bands scaled down just enough that it is at
least 0.2% of its mean everywhere (:func:`workers.kernels.sh.sh_l2_nonnegative`; stats ``sh_windowed``: the probe
channels changed).
Adaptive rays (:mod:`workers.kernels.adaptive_rays`): before any bounce, the probes whose few rays see a small
bright thing (the relative noise of their first-bounce light, pooled over their neighbours) get up to
``light.extra_sets`` more sets of the trace's R rays, ``light.extra_rays`` × the live probes' count in all, traced here
under fresh rotations (seeded by the bake's seed) and shaded as the trace's own; a probe's maps and SH are the mean
of its sets (stats ``extra_rays``, ``extra_probes``, ``extra_noise_max``, ``extra_seconds``).
Bounces: a fixed count (``light.bounces``) or until the light unaccounted for once the series' geometric tail is
added (:mod:`workers.kernels.convergence`, "The tail is added, not waited for": light stage 12, 9-31% fewer bounces
at the same or smaller error) is below ``light.tolerance`` at every probe that matters, and then that tail is added to
the maps and the rays (capped at ``light.max_bounces``; a bake that stops short carries the warning
``not_converged``). OFF probes stay at 0 in
``irradiance`` and ``probe_sh``; in the volumes the leaking mode samples without visibility (``sh_l1_*``, ``sh_l2``)
they take their live neighbours' values (:func:`workers.kernels.grid.dilate_off`), so a solid's surfaces are not
darkened by the 0 of the probes buried in it (stats ``off_dilated``).

Outputs (formats: :mod:`workers.kernels.precision`, GI error: tests/bench/bench_formats.py; proto/bundle.md 5.1):
``irradiance`` 2D atlas (ny·(n+2), nz·nx·(n+2), 3) E5B9G9R9_UFLOAT_PACK32 (shared exponent; else (…, 4) RGBA16F
with a = 1, or RGBA32F), octahedral n×n per probe with border, stored without the border ((ny·n, nz·nx·n, ·),
``meta.stored_border`` 0: readers add it back, :mod:`proto.atlas`); ``probe_sh`` (nz, ny, nx, 9|4, 3) half-float table (R16_SFLOAT, else R32_SFLOAT), radiance SH (three.js order, :mod:`workers.kernels.sh`);
``sh_l1_{r,g,b}`` (nz, ny, nx, 4) RGBA16F, each channel's L0 and L1 (leaking L1); with ``light.sh_order`` 2 (default)
``sh_l2`` (7·(nz+2), ny, nx, 4) RGBA16F, three.js LightProbeGrid layout (:func:`workers.kernels.sh.sh_l2_atlas`);
internal ``sh_l1_full``, the float32 L1 volumes (nz, ny, nx, 4, 3) the masks stage reads.
"""
from __future__ import annotations

import math
import time

import numpy as np

from workers.kernels import precision
from workers.kernels.adaptive_rays import (allocate_sets, extra_patterns, extra_rows, first_bounce_noise, merge_rows,
                                           pooled)
from workers.kernels.bounce import integrate_one
from workers.kernels.gather import SamplerGather
from workers.kernels.grid import OFF, dilate_off, pack_atlas, unpack_atlas
from workers.kernels.light_spots import split_direct, spot_correction, spot_thresholds
from workers.kernels.materials import albedo_warnings, double_sided_triangles
from workers.kernels.octahedral import oct_texel_directions
from workers.kernels.probe_hits import concat_hits, hit_surfaces, near_occlusion, probe_visibility
from workers.kernels.sampling import ProbeRays, rotated_patterns
from workers.kernels.sh import sh_l2_atlas, sh_l2_floor, sh_l2_nonnegative, sh_project_probes
from workers.kernels.shading import direct_irradiance, horizon_factor
from workers.raycast import caster_for_scene
from workers.raycast.probes import trace_probes
from workers.stages.base import Artifact, StageContext, StageOutput
from workers.stages.trace import probe_rays_of

ZSTD_LEVEL = 9
"""Zstandard level of the stored probe data: the irradiance atlas is a third of a DDGI bundle; level 9 stores it
about 8% smaller than the default 3 for about 0.05 s per MB of raw texels (zdm2 at 32x16x32)."""
EXTRA_SEED_TAG = 0xE7A5
EXTRA_PATTERNS = 64
"""Fresh rotations of the ray pattern for the extra rows; a probe's sets take consecutive ones from a hash of the probe
(:func:`workers.kernels.adaptive_rays.extra_patterns`)."""


def _extra_rays(ctx, scene, caster, eps, surf, per_light, c_spot, dirs, states, positions, counts):
    """The adaptive rays (:mod:`workers.kernels.adaptive_rays`): ``(surf, per_light, dirs, states, parents, q_max)``
    with the extra rows' hits, direct light, patterns and states after the probes' own (``parents`` (E,) their
    probes; E = 0: the inputs unchanged). The extra patterns are fresh rotations, seeded by the bake's seed."""
    sec, lit = ctx.config.light, ctx.inputs["ingest"]["lights"]
    none = np.zeros(0, np.int64)
    if sec.extra_rays <= 0 or sec.extra_sets <= 0:
        return surf, per_light, dirs, states, none, 0.0
    e_first = split_direct(per_light, c_spot) if per_light else np.zeros_like(surf.position)
    first = surf.emission + surf.albedo / np.float32(math.pi) * e_first              # the first bounce (module doc)
    q = pooled(first_bounce_noise(surf.index, surf.miss, first, lit["sky"], dirs.rays), counts)
    parents = extra_rows(allocate_sets(q, states, sec.extra_rays, sec.extra_sets))
    q_max = float(q.max(initial=0.0))
    if parents.size == 0:
        return surf, per_light, dirs, states, none, q_max
    rng = np.random.default_rng([ctx.config.seed, EXTRA_SEED_TAG])
    K = dirs.patterns.shape[0]
    extra = rotated_patterns(dirs.rays, EXTRA_PATTERNS, rng)
    rows = ProbeRays(extra, extra_patterns(parents, EXTRA_PATTERNS))
    t, tri, u, v, back, _ = trace_probes(caster, positions[parents], rows, double_sided_triangles(scene))
    hx = np.stack([t, u, v, back.astype(np.float32)], axis=-1)
    sx = hit_surfaces(scene, rows, hx, tri)
    del hx, t, tri, u, v, back
    fx = dict(geo_normals=sx.geo_normal, smooth_normals=sx.smooth_normal, bent=sx.bent)
    px = [direct_irradiance(sx.position, sx.normal, [lt], caster, eps, **fx) for lt in lit["lights"]]
    for i in range(len(per_light)):          # in place: the caller's list drops the trace's arrays as they are joined
        per_light[i] = np.concatenate([per_light[i], px[i]])
        px[i] = None
    all_rays = ProbeRays(np.concatenate([dirs.patterns, extra]), np.concatenate([dirs.pattern, K + rows.pattern]))
    return (concat_hits(surf, sx), per_light, all_rays, np.concatenate([states, states[parents]]), parents, q_max)


def run_light(ctx: StageContext) -> StageOutput:
    sec = ctx.config.light
    scene = ctx.scene
    place = ctx.inputs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing", "layers") if k in place}
    counts = grid["counts"]
    nx, ny, nz = counts
    tr = ctx.inputs["trace"]
    dirs = probe_rays_of(tr)
    hits, tri = tr["ray_hits"], tr["ray_tri"]
    states = tr["probe_states"].reshape(-1)
    m = ctx.config.trace.depth_texels + 2
    full = "depth_moments_full" if "depth_moments_full" in tr else "depth_moments"   # float32 (trace stage 2)
    depth = unpack_atlas(np.asarray(tr[full], np.float32), counts, m)
    positions = ctx.inputs["relocate"]["probe_positions_relocated"].reshape(-1, 3).astype(np.float32)
    lit = ctx.inputs["ingest"]["lights"]

    t0 = time.perf_counter()
    tr.release("depth_moments", "depth_moments_full")       # the atlas, unpacked into depth
    surf = hit_surfaces(scene, dirs, hits, tri)
    hits = tri = tr.release("ray_hits", "ray_tri")          # (None) the hits are in surf now: 1.3 GB at 64x32x64
    bounds = np.asarray(ctx.inputs["ingest"].stats["bounds"])
    eps = 1e-4 * max(float(np.linalg.norm(bounds[1] - bounds[0])), 1e-3)
    caster = caster_for_scene(scene)
    # bent shading normals, as Cycles shades a hit for a viewer at the probe (module doc): E_direct about N' with
    # lights below the geometric plane rejected and the bump term on bent hits; E_indirect x the horizon factor
    frame = dict(geo_normals=surf.geo_normal, smooth_normals=surf.smooth_normal, bent=surf.bent)
    per_light = [direct_irradiance(surf.position, surf.normal, [lt], caster, eps, **frame) for lt in lit["lights"]]
    c_spot = spot_thresholds(per_light, lit["lights"])      # from the trace's own rays (the hot spots, below)
    t_direct = time.perf_counter() - t0
    t0 = time.perf_counter()        # adaptive rays (workers.kernels.adaptive_rays): more where few see bright things
    surf, per_light, dirs, states_all, parents, q_max = _extra_rays(ctx, scene, caster, eps, surf, per_light, c_spot,
                                                                    dirs, states, positions, counts)
    t_extra = time.perf_counter() - t0
    t0 = time.perf_counter()
    frame = dict(geo_normals=surf.geo_normal, smooth_normals=surf.smooth_normal, bent=surf.bent)
    e_direct = sum(per_light[1:], per_light[0]) if per_light else np.zeros_like(surf.position)
    horizon = horizon_factor(surf.normal, surf.geo_normal, surf.smooth_normal, surf.bent).astype(np.float32)
    n_bent, n_horizon = int(surf.bent.sum()), int((horizon < 1).sum())
    horizon = None if n_horizon == 0 else horizon          # flat shading: 1 everywhere, bit-identical to no factor
    t_direct += time.perf_counter() - t0
    t0 = time.perf_counter()        # near-field occlusion (workers.kernels.probe_hits.near_occlusion)
    near, near_mean = None, 0.0
    if sec.near_radius > 0 and sec.near_rays > 0:
        near = near_occlusion(scene, surf.position, surf.normal, surf.geo_normal, caster,
                              sec.near_radius * float(min(grid["spacing"])), sec.near_rays, eps)
        near_mean = float(near.a.sum(dtype=np.float64) / max(surf.index.size, 1))
        near.a *= np.float32(sec.near_strength)       # the fitted weight (proto/models.py LightSection)
    t_near = time.perf_counter() - t0
    surf.geo_normal = surf.smooth_normal = surf.bent = frame = None
    t0 = time.perf_counter()
    visible, vis_rays = probe_visibility(surf, grid, positions, states, caster, sec.self_shadow_bias)
    t_vis = time.perf_counter() - t0
    ctx.report(0.1)
    t0 = time.perf_counter()        # point lights' hot spots sampled from the light (workers.kernels.light_spots)
    e_direct = split_direct(per_light, c_spot) if per_light else e_direct
    dmaps, dsh_l2, n_spots, spot_rays = spot_correction(     # L2 for the SH gather, whatever the stored order
        scene, caster, positions, states != OFF, lit["lights"], c_spot, double_sided_triangles(scene),
        grid["spacing"], sec.irradiance_texels, eps, 2 if sec.gather == "sh" else sec.sh_order, seed=ctx.config.seed)
    dsh = dsh_l2[:, :(sec.sh_order + 1) ** 2]
    del per_light
    t_spots, t1 = time.perf_counter() - t0, time.perf_counter()
    gather = SamplerGather(surf.position, surf.normal, surf.view, grid, positions, states, depth,
                           sec.self_shadow_bias, visible, n=sec.irradiance_texels,
                           read=sec.gather)                                      # the sampler's weights, once
    surf.position = surf.normal = surf.view = visible = depth = None                  # in the weights now
    t_weights = time.perf_counter() - t1
    irr, radiance, history, residuals = integrate_one(
        surf.index, surf.miss, surf.albedo, e_direct, dirs, states_all, sec.irradiance_texels, gather,
        emission=surf.emission, sky=lit["sky"], bounces=sec.bounces, max_bounces=sec.max_bounces,
        tolerance=sec.tolerance, report=lambda f: ctx.report(0.1 + 0.85 * f), correction=dmaps,
        indirect_scale=horizon, near=near, parents=parents,
        correction_sh=dsh_l2.astype(np.float32) if gather.reads_sh else None)
    t_bounces = time.perf_counter() - t1
    sh = merge_rows(sh_project_probes(dirs, radiance, order=sec.sh_order), parents) + dsh   # (P, 9|4, 3)
    if sh.shape[1] == 9:        # deringing: L2 not below β of the probe's own map (workers.kernels.sh.sh_l2_floor)
        n = sec.irradiance_texels
        sh = sh_l2_floor(sh, oct_texel_directions(n).reshape(-1, 3), irr[:, 1:-1, 1:-1].reshape(len(sh), n * n, 3))
        sh, n_windowed = sh_l2_nonnegative(sh)  # and not below 0 between those texels (windowed where it rings)
    else:
        n_windowed = 0
    sh = sh.astype(np.float32)
    sh[states == OFF] = 0.0
    shv = sh.reshape(nz, ny, nx, sh.shape[1], 3)
    # the runtime volumes (leaking samples them without visibility): OFF probes dilated from live neighbours
    shv_rt, dilated = dilate_off(shv, (states == OFF).reshape(nz, ny, nx))
    rgba = np.concatenate([irr, np.ones(irr.shape[:-1] + (1,), np.float32)], axis=-1)
    active = states != OFF
    stats = {
        # residuals: the light unaccounted for (fraction; with a fixed count the light still to come), None while not
        # yet estimable (< 4 bounces; fixed count < 3): JSON has no inf
        "bounces": len(history), "change_per_bounce": history,
        "residual_per_bounce": [r if math.isfinite(r) else None for r in residuals],
        "residual": (residuals[-1] if math.isfinite(residuals[-1]) else None) if residuals else 0.0,
        "converged": bool(residuals) and residuals[-1] < sec.tolerance,
        "off_dilated": dilated, "sh_windowed": n_windowed,
        "front_hits": int(surf.index.size), "bent_hits": n_bent, "horizon_hits": n_horizon,
        "horizon_mean": float(horizon.mean()) if horizon is not None else 1.0, "shadow_rays": int(surf.index.size) * len(lit["lights"]),
        "direct_seconds": t_direct, "bounce_seconds": t_bounces, "weights_seconds": t_weights,
        "visibility_rays": vis_rays, "visibility_seconds": t_vis,
        "near_rays": near.rays if near is not None else 0, "near_seconds": t_near,
        "near_hits": int(near.index.size) if near is not None else 0,
        "near_mean": near_mean,
        "extra_rays": int(parents.size) * int(dirs.rays), "extra_probes": int(np.unique(parents).size),
        "extra_noise_max": q_max, "extra_seconds": t_extra,
        "spot_lights": int(n_spots), "spot_rays": int(spot_rays), "spot_seconds": t_spots, "gather": sec.gather,
        "mean_irradiance": irr[active][:, 1:-1, 1:-1].mean(axis=(0, 1, 2)).tolist() if active.any() else [0, 0, 0],
    }
    warnings = albedo_warnings(scene, getattr(scene, "max_albedo", None), getattr(scene, "specular_gi", "metals"))
    if not stats["converged"]:
        res = stats["residual"]
        shown = "not yet estimable" if res is None else f"{res:.1%} of the probe's light"
        why = (f"light.bounces = {sec.bounces} stops it" if sec.bounces is not None
               else f"light.max_bounces = {sec.max_bounces} was reached")
        warnings.append({"code": "not_converged", "message": (
            f"the bounced light did not converge after {len(history)} bounces ({why}): the light unaccounted "
            f"for is {shown} at the worst probe (tolerance {sec.tolerance:.1%}); indirect light reads low there. "
            "A very bright closed room (albedo near 1) converges slowly: raise light.max_bounces, or clamp with "
            "scene.max_albedo")})
    if warnings:
        stats["warnings"] = warnings
    # shared exponent, 4 B/texel (not R11G11B10F: up to 0.9% on flat light); RGBA16F where it cannot hold the values
    # the tile borders are copies (octahedral.add_border): stored without them, readers add them back (proto/atlas.py)
    irr, irr_vk, irr_meta = precision.rgb9e5(pack_atlas(rgba[:, 1:-1, 1:-1], counts))
    # probe_sh: a half-float table (R16_SFLOAT; R32_SFLOAT where half cannot hold it), as sh_l2 stores the same
    # coefficients; nothing in the pipeline reads it but the masks stage, whose L2 cluster volumes are half floats
    # of selections of it (identical from either)
    sh_data, _, sh_meta = precision.half(shv.reshape(-1))
    sh_data = sh_data.reshape(shv.shape)
    arts = [Artifact("irradiance", irr, vk_format=irr_vk, zstd_level=ZSTD_LEVEL, description="octahedral probe irradiance with border",
                     meta={"tile": sec.irradiance_texels + 2, "texels": sec.irradiance_texels, "stored_border": 0,
                           **irr_meta}),
            Artifact("probe_sh", sh_data, table=True, meta=sh_meta, zstd_level=ZSTD_LEVEL,
                     description="radiance SH per probe (three.js order), linear RGB"),
            Artifact("sh_l1_full", np.ascontiguousarray(shv_rt[..., :4, :]), table=True, meta={"internal": True})]
    for i, c in enumerate("rgb"):
        data, vk, meta = precision.half(np.ascontiguousarray(shv_rt[..., :4, i]))
        arts.append(Artifact(f"sh_l1_{c}", data, vk_format=vk, meta=meta, zstd_level=ZSTD_LEVEL,
                             description=f"L0 + L1 radiance SH of the {c} channel per probe (OFF probes dilated)"))
    if shv.shape[3] == 9:
        data, vk, meta = precision.half(sh_l2_atlas(shv_rt))
        arts.append(Artifact("sh_l2", data, vk_format=vk, zstd_level=ZSTD_LEVEL, meta={"layout": "three.js LightProbeGrid", "texels": 7,
                                                               "padding": 1, **meta},
                             description="L2 radiance SH per probe: 9 coefficients x rgb in 7 padded RGBA "
                                         "sub-volumes stacked along z (three.js LightProbeGrid layout)"))
    return StageOutput(artifacts=arts, stats=stats)
