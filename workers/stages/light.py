"""Stage ``light``: multi-bounce probe irradiance from the cached probe-ray hits (DDGI-I §3.4-3.5).

Radiance along each probe ray (DESIGN stage 2):

- a miss sees the sky (``scene.sky``, linear RGB radiance);
- a back-face hit of a single-sided surface carries 0 (DDGI-P §4.1);
- a front-face hit carries ``emission + albedo/π · (E_direct + E_indirect)`` where ``E_direct`` is the
  irradiance from the resolved lights with shadow rays (computed once: geometry and lights do not
  change between bounces) and ``E_indirect`` is the previous bounce's probe irradiance sampled at the
  hit with DDGI visibility weights (:func:`workers.kernels.ddgi.sample_irradiance`), each cage probe
  also tested with an occlusion ray from the hit's biased point (:func:`probe_visibility`; once,
  since nothing moves between bounces) — Chebyshev alone leaks a few % through thin walls.

Each bounce re-shades the cached hits; nothing is re-traced except the shadow rays of the first.
Offline, so each bounce is the full Monte Carlo estimate of DDGI-I eq 1 with no hysteresis
(α = 0): per octahedral texel direction n, ``E(n) = π · Σ_r max(0, n·ω_r) L_r / Σ_r max(0, n·ω_r)``
(the cosine-weighted mean radiance times π, exact for constant radiance: a furnace gives π·L).
Bounces: a fixed count (``light.bounces``) or until the estimated light still to come (the geometric
tail of each probe's per-bounce increments, :mod:`workers.kernels.convergence`) is below
``light.tolerance`` of its value at every probe that matters (capped at ``light.max_bounces``; a bake that
stops short carries the warning ``not_converged``). OFF probes stay at 0.

Outputs: ``irradiance`` 2D atlas (ny·(n+2), nz·nx·(n+2), 4) float32 RGBA (rgb irradiance, a = 1),
octahedral n×n per probe with its border (grid.pack_atlas); ``probe_sh`` (nz, ny, nx, 9|4, 3) float32
radiance SH per probe (three.js order, :mod:`workers.kernels.sh`); ``sh_l1_r``, ``sh_l1_g``,
``sh_l1_b`` (nz, ny, nx, 4) float32 volumes holding each channel's L0 and L1 coefficients, the
form leaking probe GI samples with hardware trilinear filtering; with ``light.sh_order`` 2 (the default) also
``sh_l2`` (7·(nz+2), ny, nx, 4) float32, all 9 coefficients in the three.js LightProbeGrid layout
(:func:`workers.kernels.sh.sh_l2_atlas`, proto/bundle.md 5.1), what leaking probe GI samples by default.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from workers.kernels.convergence import probe_sums, relative_tail
from workers.kernels.ddgi import cage_probes, cage_rays, sample_irradiance
from workers.kernels.grid import OFF, pack_atlas, unpack_atlas
from workers.kernels.materials import albedo_warnings
from workers.kernels.octahedral import accumulate_octahedral, add_border, oct_texel_directions
from workers.kernels.sh import sh_l2_atlas, sh_project
from workers.kernels.shading import direct_irradiance, surface_at_hits
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageOutput


@dataclass
class HitSurfaces:
    """The shading inputs of the front-face probe-ray hits, computed once per geometry.

    ``index`` (H,) flat ray indices (into P·R) of the front-face hits; ``position``, ``normal`` (unit,
    facing the probe), ``view`` (unit, toward the probe), ``albedo``, ``emission`` : (H, 3) float32;
    ``miss`` (P, R) bool; P, R.
    """

    index: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    miss: np.ndarray
    P: int
    R: int


def hit_surfaces(scene, dirs: np.ndarray, hits: np.ndarray, tri: np.ndarray) -> HitSurfaces:
    """Shading data of the front-face hits of the cached probe rays (trace stage outputs).

    dirs : (R, 3); hits : (P, R, 4) t, u, v, backface; tri : (P, R) int32 (-1 = miss).
    """
    P, R = tri.shape
    u, v, back = hits[..., 1], hits[..., 2], hits[..., 3] > 0.5
    front = (tri >= 0) & ~back
    index = np.flatnonzero(front)
    s = surface_at_hits(scene, tri.ravel()[index], u.ravel()[index], v.ravel()[index])
    d = np.tile(dirs, (P, 1))[index]
    n = s["normal"].astype(np.float32)
    n = np.where((np.einsum("ij,ij->i", n, d) > 0)[:, None], -n, n)   # shade the side the ray arrived on
    pos = s["position"].astype(np.float32)
    # visit hits in spatial order (a coarse 3D grid): the probe sampler then reads neighbouring probes
    # from cache (about 1.6x faster than ray order); the order does not change any result
    lo, hi = pos.min(axis=0) if len(pos) else 0, pos.max(axis=0) if len(pos) else 1
    cell = np.floor((pos - lo) / np.maximum(hi - lo, 1e-6) * 63.999).astype(np.int64)
    order = np.argsort(cell[:, 0] + 64 * (cell[:, 1] + 64 * cell[:, 2]), kind="stable")
    return HitSurfaces(index=index[order], position=pos[order], normal=n[order], view=(-d[order]).astype(np.float32),
                       albedo=s["albedo"][order].astype(np.float32), emission=s["emission"][order].astype(np.float32),
                       miss=tri < 0, P=P, R=R)


SAMPLE_THREADS = 2
"""Threads for the probe sampler (its numba kernel releases the GIL)."""


VISIBILITY_CHUNK = 1 << 20
"""Hits per batch of visibility rays (8 rays each), bounding memory."""


def probe_visibility(surf: HitSurfaces, grid: dict, positions: np.ndarray, states: np.ndarray, caster,
                     bias: float) -> tuple[np.ndarray, int]:
    """(H, 8) uint8: whether each cage probe of each hit is visible from the hit's biased point.

    Ray-traced, once per geometry (hits and probes do not move between bounces), and applied on top of
    the DDGI weights: DDGI's Chebyshev test keeps a 5% floor, which the weight normalization amplifies
    into visible leaks through thin walls when the visible side's probes have small trilinear weights
    (a sealed room next to a lit one). Offline we can afford the exact answer. Returns the mask and
    the number of rays traced (OFF probes are not traced).
    """
    H = surf.position.shape[0]
    vis = np.zeros((H, 8), np.uint8)
    rays = 0
    for a in range(0, H, VISIBILITY_CHUNK):
        b = min(H, a + VISIBILITY_CHUNK)
        biased, cage = cage_probes(surf.position[a:b], surf.normal[a:b], surf.view[a:b], grid["counts"],
                                   grid["origin"], grid["spacing"], bias)
        live, o, dirs, tfar, slot = cage_rays(biased, cage, positions, states)   # biased point -> live probe
        occluded = caster.occluded(o, dirs, tfar=tfar)
        live.reshape(-1)[slot[occluded]] = 0
        vis[a:b] = live
        rays += int(slot.shape[0])
    return vis, rays


def _sample_threaded(surf: HitSurfaces, grid: dict, positions, states, irr, depth, bias, visible) -> np.ndarray:
    """:func:`sample_irradiance` over the hits in SAMPLE_THREADS contiguous chunks (same result as one call)."""
    from concurrent.futures import ThreadPoolExecutor

    n = surf.position.shape[0]
    out = np.empty((n, 3), np.float32)
    bounds = np.linspace(0, n, SAMPLE_THREADS + 1).astype(int)

    def work(i):
        a, b = bounds[i], bounds[i + 1]
        out[a:b] = sample_irradiance(surf.position[a:b], surf.normal[a:b], surf.view[a:b], grid["counts"],
                                     grid["origin"], grid["spacing"], positions, states, irr, depth, bias,
                                     visible=visible[a:b])

    with ThreadPoolExecutor(SAMPLE_THREADS) as pool:
        list(pool.map(work, range(SAMPLE_THREADS)))
    return out


def irradiance_maps(dirs: np.ndarray, radiance: np.ndarray, n: int, states: np.ndarray) -> np.ndarray:
    """(P, n+2, n+2, 3) octahedral irradiance with border from per-ray radiance (P, R, 3). DDGI-I eq 1, α = 0."""
    maps = math.pi * accumulate_octahedral(dirs, radiance, oct_texel_directions(n), 1.0)
    maps[states == OFF] = 0.0
    return add_border(maps).astype(np.float32)


def integrate(surf: HitSurfaces, e_direct: np.ndarray, dirs: np.ndarray, sky, grid: dict, positions: np.ndarray,
              states: np.ndarray, depth: np.ndarray, n: int, *, bounces: int | None, max_bounces: int,
              tolerance: float, bias: float, visible: np.ndarray, report=lambda f: None):
    """Iterate bounces until converged. Returns ``(irradiance (P,n+2,n+2,3), radiance (P,R,3), history,
    residuals)``: ``history`` the whole grid's relative change per bounce, ``residuals`` the estimated light
    still to come per bounce, as a fraction of the probe's own value, at the worst probe that matters
    (:func:`workers.kernels.convergence.relative_tail`). With ``bounces`` None it stops once the residual is
    below ``tolerance`` (capped at ``max_bounces``).

    e_direct : (H, 3) direct irradiance at the front-face hits; grid : counts, origin, spacing;
    positions : (P, 3) relocated; states : (P,); depth : (P, m+2, m+2, 2) depth moments with border;
    visible : (H, 8) ray-traced cage visibility (:func:`probe_visibility`).
    """
    P, R = surf.P, surf.R
    sky = np.asarray(sky, np.float32)
    base = surf.emission + surf.albedo / math.pi * e_direct
    radiance = np.zeros((P * R, 3), np.float32)
    radiance[surf.miss.ravel()] = sky
    irr = np.zeros((P, n + 2, n + 2, 3), np.float32)
    history: list[float] = []
    residuals: list[float] = []
    deltas: list[np.ndarray] = []
    cap = bounces if bounces is not None else max_bounces
    for b in range(1, cap + 1):
        if b == 1:
            indirect = 0.0
        else:
            indirect = _sample_threaded(surf, grid, positions, states, irr, depth, bias, visible)
        radiance[surf.index] = base + surf.albedo / math.pi * indirect
        new = irradiance_maps(dirs, radiance.reshape(P, R, 3), n, states)
        step = np.abs(new - irr)
        total = float(np.abs(new).sum())
        change = float(step.sum()) / total if total > 0 else 0.0
        history.append(change)
        deltas = (deltas + [probe_sums(step)])[-3:]
        residual, _ = relative_tail(deltas, probe_sums(new))     # the light still to come, per probe
        residuals.append(residual)
        irr = new
        report(b / cap)
        if bounces is None and residual < tolerance:
            break
    return irr, radiance.reshape(P, R, 3), history, residuals


def run_light(ctx: StageContext) -> StageOutput:
    sec = ctx.config.light
    scene = ctx.scene
    place = ctx.inputs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    counts = grid["counts"]
    nx, ny, nz = counts
    tr = ctx.inputs["trace"]
    dirs = tr["ray_directions"]
    hits, tri = tr["ray_hits"], tr["ray_tri"]
    states = tr["probe_states"].reshape(-1)
    m = ctx.config.trace.depth_texels + 2
    depth = unpack_atlas(tr["depth_moments"], counts, m)
    positions = ctx.inputs["relocate"]["probe_positions_relocated"].reshape(-1, 3).astype(np.float32)
    lit = ctx.inputs["ingest"]["lights"]

    t0 = time.perf_counter()
    surf = hit_surfaces(scene, dirs, hits, tri)
    bounds = np.asarray(ctx.inputs["ingest"].stats["bounds"])
    eps = 1e-4 * max(float(np.linalg.norm(bounds[1] - bounds[0])), 1e-3)
    caster = caster_for_scene(scene)
    e_direct = direct_irradiance(surf.position, surf.normal, lit["lights"], caster, eps)
    t_direct = time.perf_counter() - t0
    t0 = time.perf_counter()
    visible, vis_rays = probe_visibility(surf, grid, positions, states, caster, sec.self_shadow_bias)
    t_vis = time.perf_counter() - t0
    ctx.report(0.1)

    t1 = time.perf_counter()
    irr, radiance, history, residuals = integrate(
        surf, e_direct, dirs, lit["sky"], grid, positions, states, depth, sec.irradiance_texels,
        bounces=sec.bounces, max_bounces=sec.max_bounces, tolerance=sec.tolerance, bias=sec.self_shadow_bias,
        visible=visible, report=lambda f: ctx.report(0.1 + 0.85 * f))
    t_bounces = time.perf_counter() - t1

    sh = sh_project(dirs, radiance, order=sec.sh_order).astype(np.float32)     # (P, 9|4, 3)
    sh[states == OFF] = 0.0
    shv = sh.reshape(nz, ny, nx, sh.shape[1], 3)
    rgba = np.concatenate([irr, np.ones(irr.shape[:-1] + (1,), np.float32)], axis=-1)
    active = states != OFF
    stats = {
        # residuals: the light still to come (fraction), None while not yet estimable (< 3 bounces): JSON has no inf
        "bounces": len(history), "change_per_bounce": history,
        "residual_per_bounce": [r if math.isfinite(r) else None for r in residuals],
        "residual": (residuals[-1] if math.isfinite(residuals[-1]) else None) if residuals else 0.0,
        "converged": bool(residuals) and residuals[-1] < sec.tolerance,
        "front_hits": int(surf.index.size), "shadow_rays": int(surf.index.size) * len(lit["lights"]),
        "direct_seconds": t_direct, "bounce_seconds": t_bounces,
        "visibility_rays": vis_rays, "visibility_seconds": t_vis,
        "mean_irradiance": irr[active][:, 1:-1, 1:-1].mean(axis=(0, 1, 2)).tolist() if active.any() else [0, 0, 0],
    }
    warnings = albedo_warnings(scene, getattr(scene, "max_albedo", None), getattr(scene, "specular_gi", "metals"))
    if not stats["converged"]:
        res = stats["residual"]
        shown = "not yet estimable" if res is None else f"{res:.1%} of the probe's light"
        why = (f"light.bounces = {sec.bounces} stops it" if sec.bounces is not None
               else f"light.max_bounces = {sec.max_bounces} was reached")
        warnings.append({"code": "not_converged", "message": (
            f"the bounced light did not converge after {len(history)} bounces ({why}): the light still to come "
            f"is {shown} at the worst probe (tolerance {sec.tolerance:.1%}); indirect light reads low there. "
            "A very bright closed room (albedo near 1) converges slowly: raise light.max_bounces, or clamp with "
            "scene.max_albedo")})
    if warnings:
        stats["warnings"] = warnings
    n2 = sec.irradiance_texels + 2
    return StageOutput(
        artifacts=[
            Artifact("irradiance", pack_atlas(rgba, counts), description="octahedral probe irradiance with border",
                     meta={"tile": n2, "texels": sec.irradiance_texels}),
            Artifact("probe_sh", shv, format="npy", description="radiance SH per probe (three.js order), linear RGB"),
            *[Artifact(f"sh_l1_{c}", np.ascontiguousarray(shv[..., :4, i]),
                       description=f"L0 + L1 radiance SH of the {c} channel per probe")
              for i, c in enumerate("rgb")],
            *([Artifact("sh_l2", sh_l2_atlas(shv), meta={"layout": "three.js LightProbeGrid", "texels": 7,
                                                          "padding": 1},
                        description="L2 radiance SH per probe: 9 coefficients x rgb in 7 padded RGBA sub-volumes "
                                    "stacked along z (three.js LightProbeGrid layout)")]
              if shv.shape[3] == 9 else []),
        ],
        stats=stats,
    )
