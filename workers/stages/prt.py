"""Stage ``prt``: a relightable, data-driven transfer (PRT §3-5; DESIGN stage 6).

Reads ingest (bounds), place (grid), relocate (probe positions), trace (cached probe-ray hits, float32 depth moments,
states), light (for ordering and cache keys; settings from ``config.light``). Off unless ``config.prt.enabled``.

An adapter: scenario, measurement points, dataset (the light stage's bounce integrator, per configuration alone:
emission excluded, sky 0) and fit are :mod:`workers.kernels.prt_dataset`, seeded by the bake seed.
Artifacts (stage ``prt``; the layout is documented in ``proto/bundle.md`` by the lead):

========================= ================================ ===========================================
name                      shape, format                    content
========================= ================================ ===========================================
``prt``                   json                             the PRT section: settings, sizes, names, fits
``prt_lights``            json                             ``{"configurations": [[light, ...], ...]}``
``prt_points``            table (M·S, 9) float32           position (m), normal, albedo per sample, by point
``prt_point_offsets``     table (M + 1,) int32             point m averages rows offsets[m]:offsets[m+1]
``prt_sh_transfer``       table (C, n, D + 1) float32      mono: C = 3 (R, G, B), D = M; multi: C = 1,
                                                           D = 3M (x interleaved rgb); acts on [x, ‖x‖]
``prt_sh_basis_c{k}_g{g}`` ktx2 (nz, ny, nx, 4) RGBA16F   SH coefficient k of slots 4g..4g+3 (0: mean; multi: g)
``prt_lm_transfer``       table (C, n, D + 1) float32      as prt_sh_transfer, for the lightmap
``prt_lm_basis_g{g}``     ktx2 (R, R, 4) float32           lightmap slots 4g..4g+3 (multi: g rgb), dilated
``prt_lm_mask``           ktx2 (R, R) uint8 (R8)           0 empty, 1 sampled texel, 2 dilated
``prt_lm_uv``             table (T, 3, 2) float32          the lightmap UV of every triangle corner
========================= ================================ ===========================================
(table: a KTX2 one-channel 2D texture, R32_SFLOAT / R32_SINT, of the array's rows; proto/bundle.md 3)
Relighting (:mod:`workers.prt_relight`): ``u = T_c [x_c, ‖x_c‖]``, ``y_c = Σ_j u_j · slot_j`` (PRT eq 14).
"""
from __future__ import annotations

import time

import numpy as np

from workers.kernels import precision
from workers.kernels.frame import frame_of, to_frame
from workers.kernels.grid import unpack_atlas
from workers.kernels.prt_dataset import PrtDataset, PrtTooLarge, build_dataset, fit_targets
from workers.kernels.prt_scenario import triangle_areas
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageError, StageOutput
from workers.stages.trace import probe_rays_of

PRT_SEED_SALT = 0x505254
"""Mixed with the bake seed for the stage's random stream ("PRT")."""


def _full_depth(tr) -> str:
    return "depth_moments_full" if "depth_moments_full" in tr else "depth_moments"   # float32 (trace stage 2)


def _basis(name: str, vol, k: int, g: int, channels: str) -> Artifact:
    """A probe-SH basis volume, in half floats where they hold it (its PRT error: tests/bench/bench_formats.py)."""
    data, vk, prec = precision.half(vol)
    return Artifact(name, data, vk_format=vk, description=f"PRT probe basis: SH coefficient {k}, slot group {g}",
                    meta={"coefficient": k, "group": g, "channels": channels, **prec})


def prt_dataset(ctx: StageContext) -> PrtDataset:
    """Steps 1-3 (:func:`workers.kernels.prt_dataset.build_dataset`) on the bake's inputs."""
    sec, scene, tr = ctx.config.prt, ctx.scene, ctx.inputs["trace"]
    grid = {k: v for k, v in ctx.inputs["place"].stats.items() if k in ("counts", "origin", "spacing", "layers")}
    bounds = np.asarray(ctx.inputs["ingest"].stats["bounds"], np.float64)
    if triangle_areas(scene.triangles).sum() <= 0:
        raise StageError("no_surface", "the scene's triangles have no area to place measurement points on")
    scen = sec.scenario
    box = (scen.box.min, scen.box.max) if scen.box is not None else (bounds[0], bounds[1])
    M = frame_of({"frame": ctx.frame})
    if scen.box is not None and M is not None:       # a world box: its bounding box in the bake frame
        corners = np.array([[(box[1] if c >> a & 1 else box[0])[a] for a in range(3)] for c in range(8)], np.float64)
        turned = to_frame(corners, M)
        box = (turned.min(axis=0), turned.max(axis=0))
    try:
        return build_dataset(
            scene, caster_for_scene(scene), np.random.default_rng([ctx.config.seed, PRT_SEED_SALT]), grid=grid,
            dirs=probe_rays_of(tr), hits=tr["ray_hits"], tri=tr["ray_tri"], states=tr["probe_states"].reshape(-1),
            depth=unpack_atlas(np.asarray(tr[_full_depth(tr)], np.float32), grid["counts"],
                               ctx.config.trace.depth_texels + 2),
            positions=ctx.inputs["relocate"]["probe_positions_relocated"].reshape(-1, 3).astype(np.float32),
            bounds=bounds, scenario=scen.model_dump(), box=box, configurations=sec.configurations,
            n_points=sec.measurement_points, supersampling=sec.supersampling, lightmap=sec.lightmap,
            light=ctx.config.light, report=ctx.report)
    except PrtTooLarge as e:
        raise StageError("prt_too_large", str(e)) from None


def run_prt(ctx: StageContext) -> StageOutput:
    if not ctx.config.prt.enabled:
        return StageOutput(artifacts=[], stats={"enabled": False})
    t0 = time.perf_counter()
    return prt_output(ctx, prt_dataset(ctx), t0)


def prt_output(ctx: StageContext, ds: PrtDataset, t0: float | None = None) -> StageOutput:
    """Step 4 (:func:`workers.kernels.prt_dataset.fit_targets`) and the artifacts."""
    sec, lsec, timings = ctx.config.prt, ctx.config.light, dict(ds.timings)
    t0 = time.perf_counter() if t0 is None else t0
    points, lm, (N, P, K), t3 = ds.points, ds.lightmap, ds.sh.shape[:3], time.perf_counter()
    fitted = fit_targets(ds, basis=sec.basis, ridge=sec.ridge, gamma=sec.gamma, channels=sec.channels,
                         lightmap=sec.lightmap, norm=sec.norm, ridge_folds=sec.ridge_folds)
    artifacts = [_basis(name, vol, k, g, sec.channels) for k, group in enumerate(fitted.sh_volumes)
                 for g, (name, vol) in enumerate(group)]
    artifacts.append(Artifact("prt_sh_transfer", np.asarray(fitted.sh.transfer, np.float32), table=True,
                              description="PRT transfer to the probe SH basis coefficients (PRT eq 14)"))
    lm_info = None
    if fitted.lm is not None:
        artifacts += [Artifact(name, np.ascontiguousarray(tex, np.float32),
                               description="PRT lightmap basis (mono: four slots per texel, slot 0 = mean)")
                      for name, tex in fitted.lm.textures]
        artifacts += [
            Artifact("prt_lm_transfer", np.asarray(fitted.lm.fit.transfer, np.float32), table=True,
                     description="PRT transfer to the lightmap basis coefficients (PRT eq 14)"),
            Artifact("prt_lm_mask", fitted.lm.mask, description="lightmap texels: 0 empty, 1 sampled, 2 dilated"),
            Artifact("prt_lm_uv", np.asarray(lm["uv"], np.float32), table=True, description="lightmap UV per corner"),
        ]
        lm_info = {"resolution": sec.lightmap, "texels": int(lm["covered"].sum()),
                   "dilated": int((fitted.lm.mask == 2).sum()), "uv_source": lm["source"],
                   "texels_per_metre": lm["texels_per_metre"], "basis": [name for name, _ in fitted.lm.textures],
                   "transfer": "prt_lm_transfer", "mask": "prt_lm_mask", "uv": "prt_lm_uv",
                   "unit": "irradiance (lux x colour): DDGI sample of the probes, view = normal", **fitted.lm.stats}
    timings["fit_seconds"] = time.perf_counter() - t3
    table = np.concatenate([points["position"], points["normal"], points["albedo"]], axis=1).astype(np.float32)
    section = {
        "version": 1, "channels": sec.channels, "gamma": sec.gamma, "ridge": sec.ridge, "basis": sec.basis,
        "norm": sec.norm, "ridge_folds": sec.ridge_folds, "configurations": N, "measurement_points": sec.measurement_points,
        "supersampling": sec.supersampling, "shadow_eps": ds.probes["eps"], "points": "prt_points",
        "point_offsets": "prt_point_offsets", "lights": "prt_lights",
        "direct": "outgoing radiance albedo/pi * E_direct at the measurement points, averaged per point",
        "normalization": f"u = T [x, |x|] per channel, |x| its {sec.norm} norm (row 0: u_0 = |x|); y = Σ_j u_j slot_j",
        "emission": "excluded (sky 0): the transfer covers the given lights only",
        "sh": {"order": lsec.sh_order, "coefficients": K, "counts": list(ds.probes["grid"]["counts"]),
               "basis": [[name for name, _ in group] for group in fitted.sh_volumes], "transfer": "prt_sh_transfer",
               "unit": "radiance SH per probe (three.js order), as probe_sh", **fitted.sh_stats},
        "lightmap": lm_info,
    }
    artifacts += [
        Artifact("prt", section, format="json", description="PRT section: settings, sizes, artifact names"),
        Artifact("prt_lights", {"configurations": ds.configs}, format="json",
                 description="the dataset's random lighting configurations"),
        Artifact("prt_points", table, table=True, description="measurement samples: position, normal, albedo"),
        Artifact("prt_point_offsets", np.asarray(points["offsets"], np.int32), table=True, description="samples of "
                 "point m: offsets[m]:offsets[m+1]"),
    ]
    timings["total_seconds"] = time.perf_counter() - t0
    stats = {
        "enabled": True, "configurations": N, "measurement_points": sec.measurement_points,
        "supersampling": sec.supersampling, "basis": sec.basis, "channels": sec.channels,
        "usable_surface_fraction": points["usable_fraction"], "front_hits": int(ds.probes["surf"].index.size),
        "bounces_mean": float(ds.bounces.mean()), "bounces_max": int(ds.bounces.max(initial=0)),
        "sh_energy_kept": fitted.sh_stats["energy_kept"], "sh_train_rmse": fitted.sh_stats["train_rmse"],
        "lightmap_texels": lm_info["texels"] if lm_info else 0, "warnings": (lm["warnings"] if lm else []) + (
            ["no configuration lit any measurement point: the transfer is zero"] if fitted.sh.columns == 0 else []),
        **timings,
    }
    if lm_info:
        stats.update(lm_energy_kept=lm_info["energy_kept"], lm_train_rmse=lm_info["train_rmse"])
    ctx.report(1.0)
    return StageOutput(artifacts=artifacts, stats=stats)
