"""Stage ``relocate``: move probes out of geometry (DDGI-P §5, Fig 7).

Each of ``relocate_iterations`` iterations traces ``rays_per_probe`` rays per probe on a spherical
Fibonacci pattern under a fresh random rotation (seeded; :func:`workers.raycast.probes.trace_probes`), then
applies the Fig 7 optimizer per probe (:func:`workers.kernels.relocation.relocation_step`), with the offset
limit ``max_offset × spacing`` (RTXGI). After the first iteration only the probes that can still move are traced
(:func:`workers.kernels.relocation.settled`: not those in open air far from any surface, nor those deep in a
solid; stat ``traced``, the probe traces of all iterations). Back faces of double-sided materials count as front faces (a thin
double-sided plane has no inside). Then the probes still inside geometry move to the nearest free-space point
within ``rescue_offset × spacing`` and the grid's box (:func:`workers.kernels.relocation.rescue`;
``rescue_offset = 0``: none, as DDGI-P), keeping ``0.1 × min spacing`` from the surface they leave through; stats ``inside`` (before the rescue),
``rescued``.

Outputs: ``probe_offsets`` and ``probe_positions_relocated``, (nz, ny, nx, 3) float32 volumes,
world-space metres (offset = relocated − grid position).
"""
from __future__ import annotations

import numpy as np

from workers.kernels.grid import base_positions
from workers.kernels.materials import double_sided_triangles
from workers.kernels.relocation import RESCUE_MARGIN, relocation_step, rescue, settled
from workers.kernels.sampling import fibonacci_sphere, random_rotation
from workers.raycast import caster_for_scene
from workers.raycast.probes import trace_probes
from workers.stages.base import Artifact, StageContext, StageOutput

STAGE_SEED_TAG = 0x5E10CA7E


def run_relocate(ctx: StageContext) -> StageOutput:
    sec = ctx.config.trace
    place = ctx.inputs["place"].stats
    counts, origin, spacing = place["counts"], np.asarray(place["origin"]), np.asarray(place["spacing"])
    scene = ctx.scene
    base = base_positions(counts, origin, spacing, place.get("layers"))
    P = base.shape[0]
    positive = spacing[spacing > 0]
    min_spacing = float(positive.min()) if positive.size else 1.0
    limit = sec.max_offset * spacing
    caster = caster_for_scene(scene)
    ds = double_sided_triangles(scene)
    rng = np.random.default_rng([ctx.config.seed, STAGE_SEED_TAG])
    pattern = fibonacci_sphere(sec.rays_per_probe)
    offsets = np.zeros((P, 3))
    rays, ray_seconds = 0, 0.0
    iters = sec.relocate_iterations
    active = np.arange(P)                            # the probes this iteration traces (all, the first time)
    inside = np.zeros(P, bool)                       # inside at the last iteration that traced the probe
    traced = 0
    for it in range(iters):
        dirs = (pattern.astype(np.float64) @ random_rotation(rng).T).astype(np.float32)
        t, _, _, _, back, s = trace_probes(caster, base[active] + offsets[active], dirs, ds)
        rays += t.size
        ray_seconds += s
        traced += active.size
        new = relocation_step(offsets[active], t, back, dirs, limit, min_spacing, sec.backface_fraction)
        moved = np.any(new != offsets[active], axis=1)
        offsets[active] = new
        inside[active] = back.sum(axis=1) > sec.backface_fraction * back.shape[1]
        active = active[~settled(new, t, back, moved, limit, min_spacing, sec.backface_fraction)]
        ctx.report((it + 1) / max(iters, 1) * 0.8)
    check = np.flatnonzero(inside) if iters else None          # may still be inside: the rescue traces these
    res = {"inside": None, "rescued": 0}
    if sec.rescue_offset > sec.max_offset and P:
        offsets, res = rescue(caster, base, offsets, ds, sec.rescue_offset * spacing, RESCUE_MARGIN * min_spacing,
                              sec.backface_fraction, sec.rays_per_probe, rng, check=check,
                              box=(base.min(axis=0), base.max(axis=0)))
        rays += res["rays"]
        ray_seconds += res["ray_seconds"]
    ctx.report(1.0)
    nx, ny, nz = counts
    moved = np.any(offsets != 0, axis=1)
    rel = np.abs(offsets) / np.where(spacing > 0, spacing, 1.0)
    stats = {
        "probes": P, "iterations": iters, "traced": traced, "rays": rays, "ray_seconds": ray_seconds,
        "rays_per_second": rays / ray_seconds if ray_seconds > 0 else None,
        "moved": int(moved.sum()), "max_offset_fraction": float(rel.max()) if P else 0.0,
        "inside": res["inside"], "rescued": res["rescued"],
    }
    vol = lambda a: a.reshape(nz, ny, nx, 3).astype(np.float32)  # noqa: E731
    return StageOutput(
        artifacts=[
            Artifact("probe_offsets", vol(offsets), description="relocation offsets, world space, metres"),
            Artifact("probe_positions_relocated", vol(base + offsets),
                     description="relocated probe positions, world space, metres"),
        ],
        stats=stats,
    )
