"""Stage ``trace``: the final probe rays — classification, depth moments, and cached hits.

From the relocated positions, ``rays_per_probe`` rays per probe on a spherical Fibonacci pattern under seeded random
rotations (DDGI-I §3.2): ``trace.ray_rotations`` of them, spread so that the 8 corners of every grid cell cast
different ones (:func:`workers.kernels.sampling.pattern_of_grid`). One rotation for all probes (1, DDGI's per
frame) makes every probe see a small bright opening through the same few directions: offline, with one "frame",
that error is the same at neighbouring probes, and interpolation and the bounces add it up (sun-window turned 90°:
the dark room read 1.10-1.15 of Cycles, 1.00-1.07 at 1024 rays).

- **Classification** (DDGI-P §6.1-6.2, Fig 10, offline subset; :mod:`workers.kernels.classification`):
  OFF inside geometry, ACTIVE with a front face within one cell diagonal, SLEEPING otherwise.
- **Depth moments** (DDGI-I §3.5 eq 2, DDGI-P §4.1; :mod:`workers.kernels.depth_moments`): per probe an
  octahedral ``depth_texels``² map of the mean distance and distance², misses at ``max_distance`` (the
  diagonal of the scene bounds joined with the grid box), with the 1-texel border.
- **Hits** (internal, for the light and PRT stages): per ray the distance, triangle, barycentrics
  and back-face flag, so later stages re-shade without re-tracing.

Outputs: ``probe_states`` (nz, ny, nx, 1) uint8 volume (0 OFF, 1 ACTIVE, 2 SLEEPING);
``depth_moments`` 2D atlas (ny·(n+2), nz·nx·(n+2), 2) (grid.pack_atlas), stored without its tile borders
((ny·n, nz·nx·n, 2), ``meta.stored_border`` 0: readers add them back, :mod:`proto.atlas`), RG16F where half floats hold it, else
RG32F (:func:`workers.kernels.precision.half`; its GI error in tests/bench/bench_formats.py), every texel beyond the
probe's reach (the farthest any shading point can be from it, with the runtime's self-shadow bias
``light.self_shadow_bias``) clamped to it (:func:`workers.kernels.depth_moments.clamp_far`, ``meta.far_clamp``) and
the OFF probes' maps 0 (no reader reads them: the DDGI sampler and mode_ddgi.glsl skip OFF probes first); internal
``depth_moments_full``, the float32 atlas the light and PRT stages integrate with;
``ray_directions`` (K, R, 3) float32 patterns and ``ray_pattern`` (P,) uint8 (probe p's rays are
``ray_directions[ray_pattern[p]]``; :class:`workers.kernels.sampling.ProbeRays`), ``ray_hits`` (P, R, 4) float32 (t
(inf on miss), u, v, backface)
and ``ray_tri`` (P, R) int32.
"""
from __future__ import annotations

import numpy as np

from workers.kernels.classification import classify
from workers.kernels.ddgi import bias_scale
from workers.kernels.depth_moments import clamp_far, depth_moments, max_ray_distance, reach
from workers.kernels.grid import ACTIVE, OFF, SLEEPING, pack_atlas
from workers.kernels import precision
from workers.kernels.materials import double_sided_triangles
from workers.kernels.sampling import ProbeRays, pattern_of_grid, rotated_patterns
from workers.raycast import caster_for_scene
from workers.raycast.probes import trace_probes
from workers.stages.base import Artifact, StageContext, StageOutput

STAGE_SEED_TAG = 0x7ACE
ZSTD_LEVEL = 9
"""Zstandard level of the stored depth moments (the largest artifact of a DDGI bundle): about 5% smaller than the
default 3 for about 0.02 s per MB of raw texels (zdm2 at 32x16x32)."""


def probe_rays_of(trace) -> ProbeRays:
    """The probe rays of a trace stage's outputs (``trace["ray_directions"]`` (K, R, 3), ``trace["ray_pattern"]``
    (P,)): :class:`workers.kernels.sampling.ProbeRays`."""
    return ProbeRays(np.asarray(trace["ray_directions"], np.float32), np.asarray(trace["ray_pattern"], np.int64))


def run_trace(ctx: StageContext) -> StageOutput:
    sec = ctx.config.trace
    place = ctx.inputs["place"].stats
    counts, origin, spacing = place["counts"], np.asarray(place["origin"]), np.asarray(place["spacing"])
    nx, ny, nz = counts
    scene = ctx.scene
    positions = ctx.inputs["relocate"]["probe_positions_relocated"].reshape(-1, 3).astype(np.float64)
    caster = caster_for_scene(scene)
    rng = np.random.default_rng([ctx.config.seed, STAGE_SEED_TAG])
    patterns = rotated_patterns(sec.rays_per_probe, sec.ray_rotations, rng)
    dirs = ProbeRays(patterns, pattern_of_grid(counts, sec.ray_rotations))
    t, tri, u, v, back, ray_seconds = trace_probes(caster, positions, dirs, double_sided_triangles(scene))
    ctx.report(0.5)
    diag = float(np.linalg.norm(spacing))
    states = classify(t, back, diag if diag > 0 else np.inf, sec.backface_fraction)
    dmax = max_ray_distance(ctx.inputs["ingest"].stats["bounds"], counts, origin, spacing)
    depth = depth_moments(t, back, dirs, sec.depth_texels, sec.depth_sharpness, dmax)
    ctx.report(0.9)
    hits = np.stack([t, u, v, back.astype(np.float32)], axis=-1).astype(np.float32)
    internal = {"internal": True}
    stats = {
        "probes": int(positions.shape[0]), "rays": int(t.size), "ray_seconds": ray_seconds,
        "rays_per_second": t.size / ray_seconds if ray_seconds > 0 else None,
        "off": int((states == OFF).sum()), "active": int((states == ACTIVE).sum()),
        "sleeping": int((states == SLEEPING).sum()), "max_distance": dmax,
        "hit_fraction": float((tri >= 0).mean()) if tri.size else 0.0,
    }
    n2 = sec.depth_texels + 2
    atlas = pack_atlas(depth, counts)
    # stored: texels beyond what any shading point can be from the probe clamped to that reach (depth_moments.py
    # "Far clamp"), so the far texels are constant and Zstandard stores them almost for free; the bias is the
    # runtime's (DDGI-P eq 2, light.self_shadow_bias)
    bias = bias_scale(spacing, ctx.config.light.self_shadow_bias)
    limit = reach(positions, counts, origin, spacing, bias, ctx.inputs["ingest"].stats["bounds"], place.get("layers"))
    clamped, share = clamp_far(depth, limit)
    clamped[states == OFF] = 0.0            # never read: every reader skips OFF probes before their moments
    stats["depth_clamped_share"] = share
    # the tile borders are copies (octahedral.add_border): stored without them, readers add them back (proto/atlas.py)
    stored, vk, prec = precision.half(pack_atlas(clamped[:, 1:-1, 1:-1], counts))
    del clamped
    return StageOutput(
        artifacts=[
            Artifact("probe_states", states.reshape(nz, ny, nx, 1),
                     description="probe states: 0 off, 1 active, 2 sleeping", meta={"states": ["off", "active", "sleeping"]}),
            Artifact("depth_moments", stored, vk_format=vk, zstd_level=ZSTD_LEVEL,
                     description="octahedral mean distance and squared distance per probe, with border, metres",
                     meta={"tile": n2, "texels": sec.depth_texels, "stored_border": 0, "max_distance": dmax,
                           "far_clamp": {
                         "bias": bias, "reach_min": float(limit.min(initial=0.0)),
                         "reach_max": float(limit.max(initial=0.0)), "clamped_share": share, "off_zero": True},
                         **prec}),
            Artifact("depth_moments_full", atlas, description="depth_moments in float32 (light and PRT stages)",
                     meta={"tile": n2, "texels": sec.depth_texels, "max_distance": dmax, **internal}),
            Artifact("ray_directions", patterns, format="npy", meta=internal,
                     description="the probe rays' direction patterns (K, R, 3): probe p casts ray_pattern[p]"),
            Artifact("ray_pattern", dirs.pattern.astype(np.uint8), format="npy", meta=internal,
                     description="per probe, the index of its direction pattern in ray_directions"),
            Artifact("ray_hits", hits, format="npy", description="per probe ray: t, u, v, backface", meta=internal),
            Artifact("ray_tri", tri.astype(np.int32), format="npy", description="per probe ray: triangle or -1",
                     meta=internal),
        ],
        stats=stats,
    )
