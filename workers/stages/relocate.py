"""Stage ``relocate``: move probes out of geometry (DDGI-P §5, Fig 7).

Each iteration traces ``rays_per_probe`` rays per probe on a spherical Fibonacci pattern under a
fresh random rotation (seeded), then applies the Fig 7 optimizer per probe:

- more than ``backface_fraction`` of the rays hit back faces → the probe is inside something:
  move along the direction of the closest back face as far as the offset limit allows (Fig 7's
  per-axis scale solve, minus 1 mm), or not at all if that cannot get through it;
- else, if the closest front face is nearer than ``0.1 × min spacing`` (RTXGI's
  ``probeMinFrontfaceDistance`` test), step ``min(0.2 × min spacing, farthest front-face distance)``
  toward the farthest front face, unless that direction is within 60° of the closest front face.
  (Fig 7 uses 0.2 scene units; we scale it with the grid so it means the same at any scene scale.)

A new offset is kept only when it stays within ``max_offset × spacing`` on every axis (RTXGI).
Back faces of double-sided materials count as front faces (a thin double-sided plane has no inside).

Outputs: ``probe_offsets`` and ``probe_positions_relocated``, (nz, ny, nx, 3) float32 volumes,
world-space metres (offset = relocated − grid position).
"""
from __future__ import annotations

import time

import numpy as np

from workers.kernels.grid import base_positions
from workers.kernels.materials import double_sided_triangles  # noqa: F401  (re-exported to trace, visibility)
from workers.kernels.sampling import fibonacci_sphere, random_rotation
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageOutput

STAGE_SEED_TAG = 0x5E10CA7E




def trace_probes(caster, positions: np.ndarray, dirs: np.ndarray, double_sided: np.ndarray):
    """Trace the same direction set from every probe.

    positions : (P, 3) world space; dirs : (R, 3) unit. Returns ``t (P, R)`` float32 (inf on miss),
    ``tri (P, R)`` int32, ``u, v (P, R)`` float32, ``backface (P, R)`` bool (hit the back of a
    single-sided triangle), and the seconds spent in the ray caster.
    """
    P, R = positions.shape[0], dirs.shape[0]
    origins = np.repeat(positions.astype(np.float32), R, axis=0)
    d = np.tile(dirs.astype(np.float32), (P, 1))
    t0 = time.perf_counter()
    hits = caster.intersect(origins, d)
    seconds = time.perf_counter() - t0
    tri = hits.tri.reshape(P, R)
    hit = tri >= 0
    back = hits.backface.reshape(P, R) & hit
    if double_sided.any():
        back &= ~double_sided[np.where(hit, tri, 0)]
    return (hits.t.reshape(P, R), tri, hits.u.reshape(P, R), hits.v.reshape(P, R), back, seconds)


def relocation_step(offsets: np.ndarray, t: np.ndarray, back: np.ndarray, dirs: np.ndarray,
                    limit: np.ndarray, min_spacing: float, backface_fraction: float) -> np.ndarray:
    """One iteration of DDGI-P Fig 7 for all probes (vectorized). Returns the new offsets (P, 3).

    offsets : (P, 3) current offsets; t : (P, R) hit distances (inf = miss); back : (P, R);
    dirs : (R, 3) the ray directions of this iteration; limit : (3,) per-axis offset limit, metres.
    """
    P, R = t.shape
    full = offsets.copy()
    n_back = back.sum(axis=1)
    inside = n_back / R > backface_fraction
    # --- inside: move through the closest back face (Fig 7, first branch)
    if inside.any():
        tb = np.where(back, t, np.inf)[inside]
        ib = np.argmin(tb, axis=1)
        # closestBackfaceDirection: the ray direction scaled by the back face's distance, so that a
        # scale factor <= 1 means the offset limit does not reach past the back face (Fig 7)
        d = dirs[ib].astype(np.float64) * tb[np.arange(ib.size), ib][:, None]
        cur = offsets[inside]
        with np.errstate(divide="ignore", invalid="ignore"):
            pos = (-cur + limit) / d                                           # positiveOffset
            neg = (-cur - limit) / d                                           # negativeOffset
        combined = np.where(np.isnan(pos), np.inf, np.maximum(pos, neg))       # per-axis max scaling
        scale = combined.min(axis=1) - 1e-3                                    # epsilon: millimetre
        scale = np.where((scale <= 1.0) | ~np.isfinite(scale), 0.0, scale)     # cannot get through: stay
        full[inside] = cur + d * scale[:, None]
    # --- outside, too close to a front face: step toward the farthest front face
    out = ~inside
    if out.any():
        tf = np.where(back, np.nan, t)[out]                                    # front faces and misses
        tf_close = np.where(np.isnan(tf), np.inf, tf)
        tf_far = np.where(np.isnan(tf), -np.inf, tf)
        closest = tf_close.min(axis=1)
        i_close = np.argmin(tf_close, axis=1)
        i_far = np.argmax(tf_far, axis=1)
        far_dist = tf_far.max(axis=1)
        move = closest < 0.1 * min_spacing                                     # RTXGI probeMinFrontfaceDistance
        d_close, d_far = dirs[i_close].astype(np.float64), dirs[i_far].astype(np.float64)
        move &= np.einsum("ij,ij->i", d_far, d_close) <= 0.5                  # not the same surface
        step = np.minimum(0.2 * min_spacing, np.where(np.isfinite(far_dist), far_dist, np.inf))
        idx = np.flatnonzero(out)[move]
        full[idx] = offsets[idx] + d_far[move] * step[move][:, None]
    # keep a new offset only within the limit on every axis (RTXGI)
    ok = np.all(np.abs(full) <= limit + 1e-9, axis=1)
    return np.where(ok[:, None], full, offsets)


def run_relocate(ctx: StageContext) -> StageOutput:
    sec = ctx.config.trace
    place = ctx.inputs["place"].stats
    counts, origin, spacing = place["counts"], np.asarray(place["origin"]), np.asarray(place["spacing"])
    scene = ctx.scene
    base = base_positions(counts, origin, spacing)
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
    for it in range(iters):
        dirs = (pattern.astype(np.float64) @ random_rotation(rng).T).astype(np.float32)
        t, _, _, _, back, s = trace_probes(caster, base + offsets, dirs, ds)
        rays += t.size
        ray_seconds += s
        offsets = relocation_step(offsets, t, back, dirs, limit, min_spacing, sec.backface_fraction)
        ctx.report((it + 1) / max(iters, 1))
    nx, ny, nz = counts
    moved = np.any(offsets != 0, axis=1)
    rel = np.abs(offsets) / np.where(spacing > 0, spacing, 1.0)
    stats = {
        "probes": P, "iterations": iters, "rays": rays, "ray_seconds": ray_seconds,
        "rays_per_second": rays / ray_seconds if ray_seconds > 0 else None,
        "moved": int(moved.sum()), "max_offset_fraction": float(rel.max()) if P else 0.0,
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
