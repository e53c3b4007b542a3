"""Stage ``visibility``: the θ field of MD §3.4 step 1, computed in slabs that any worker can take.

The field is a refined grid of S samples per cell axis (:mod:`workers.kernels.visibility`); for each
sample and each of the 8 corner probes of its cell, θ ∈ [0, 1] from occlusion rays to the relocated
probe position; samples inside geometry are flagged "don't care". It is split along z into
``visibility.slabs`` shards (``visibility.0``, ``visibility.1``, …; one RQ job each, run in parallel
by as many workers as there are), then joined by ``visibility`` itself. A sample's θ depends only
on the sample, never on the split or the worker count, so 1 and 3 workers give identical artifacts.

Outputs (joined): ``theta_0123`` and ``theta_4567`` (Z, Y, X, 4) uint8 RGBA8 volumes holding θ·255
for corners 0-3 and 4-7 (corner c has offset (c & 1, c >> 1 & 1, c >> 2 & 1) in its cell), and
``dont_care`` (Z, Y, X, 1) uint8 (1 = inside geometry, weight 0 in MD eq 5-6); zstd-supercompressed.
Sample (x, y, z) sits at ``origin + spacing * ((x, y, z) + 0.5) / S`` (texel centres of the volume).
"""
from __future__ import annotations

import numpy as np

from workers.kernels.materials import double_sided_triangles
from workers.kernels.visibility import field_shape, join_slabs, slab_ranges, theta_slab
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageOutput, samples_per_cell

ZSTD_LEVEL = 3


def shard_range(Z: int, S: int, shard: int, count: int) -> tuple[int, int]:
    """The z rows of shard ``shard`` of ``count``: whole cell layers; empty past the last layer."""
    ranges = slab_ranges(Z, S, count) if Z > 0 else []
    return ranges[shard] if shard < len(ranges) else (Z, Z)


def run_visibility_slab(ctx: StageContext) -> StageOutput:
    sec = ctx.config.visibility
    place = ctx.inputs["place"].stats
    counts, origin, spacing = place["counts"], place["origin"], place["spacing"]
    S = samples_per_cell(ctx.config, place)
    Z, Y, X = field_shape(counts, S)
    z0, z1 = shard_range(Z, S, ctx.shard, ctx.shard_count)
    positions = ctx.inputs["relocate"]["probe_positions_relocated"].reshape(-1, 3)
    states = ctx.inputs["trace"]["probe_states"].reshape(-1)
    if z1 > z0:
        scene = ctx.scene
        caster = caster_for_scene(scene)
        theta, dont_care, stats = theta_slab(caster, counts, origin, spacing, positions, states, S, (z0, z1),
                                             rays=sec.rays, jitter=sec.jitter, seed=ctx.config.seed,
                                             double_sided_tris=double_sided_triangles(scene),
                                             layers=place.get("layers"))
    else:
        theta, dont_care, stats = np.zeros((0, Y, X, 8), np.uint8), np.zeros((0, Y, X), bool), {"rays": 0}
    ctx.report(1.0)
    internal = {"internal": True}
    return StageOutput(
        artifacts=[Artifact("theta_part", theta, format="npy", meta=internal),
                   Artifact("dont_care_part", dont_care.astype(np.uint8), format="npy", meta=internal)],
        stats={"z_range": [z0, z1], "samples": int(theta.shape[0] * Y * X), **_jsonable(stats)},
    )


def _jsonable(stats: dict) -> dict:
    return {k: (v.item() if hasattr(v, "item") else v) for k, v in stats.items()}


def run_visibility(ctx: StageContext) -> StageOutput:
    sec = ctx.config.visibility
    place = ctx.inputs["place"].stats
    shards = sorted((n for n in ctx.inputs if n.startswith("visibility.")), key=lambda n: int(n.split(".")[1]))
    parts = [(ctx.inputs[n]["theta_part"], ctx.inputs[n]["dont_care_part"].astype(bool)) for n in shards]
    theta, dont_care = join_slabs(parts)
    S = samples_per_cell(ctx.config, place)
    Z, Y, X = field_shape(place["counts"], S)
    assert theta.shape == (Z, Y, X, 8), (theta.shape, (Z, Y, X))
    ctx.report(1.0)
    rays = sum(ctx.inputs[n].stats.get("rays", 0) for n in shards)
    ray_seconds = sum(ctx.inputs[n].stats.get("ray_seconds", 0.0) for n in shards)
    stats = {
        "shape": [Z, Y, X], "samples_per_cell": S, "slabs": len(shards), "rays": rays,
        "ray_seconds": ray_seconds, "dont_care_fraction": float(dont_care.mean()) if dont_care.size else 0.0,
        "visible_fraction": (np.count_nonzero((theta > 127) & ~dont_care[..., None]) / (8 * int((~dont_care).sum()))
                             if (~dont_care).any() else 0.0),   # the mean over care samples, without their copy
    }
    meta = {"samples_per_cell": S, "corners": "c -> offset (c&1, c>>1&1, c>>2&1)"}
    return StageOutput(
        artifacts=[
            Artifact("theta_0123", np.ascontiguousarray(theta[..., :4]), zstd_level=ZSTD_LEVEL, meta=meta,
                     description="θ·255 of cell corners 0-3 per refined-grid sample (MD §3.4 step 1)"),
            Artifact("theta_4567", np.ascontiguousarray(theta[..., 4:]), zstd_level=ZSTD_LEVEL, meta=meta,
                     description="θ·255 of cell corners 4-7 per refined-grid sample"),
            Artifact("dont_care", dont_care.astype(np.uint8)[..., None], zstd_level=ZSTD_LEVEL,
                     description="1 where the sample is inside geometry (weight 0)"),
        ],
        stats=stats,
    )
