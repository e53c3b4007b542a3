"""Stage ``place``: the probe grid (DESIGN stage 1, before tracing).

With neither ``counts`` nor ``spacing`` (the default) the grid is chosen from the scene by planning rays
(:mod:`workers.kernels.autogrid`: the box of its enclosed spaces, a spacing from its room sizes under
``place.budget`` probes, visibility samples per cell from its thinnest walls); the stats' ``auto`` (the
manifest's ``grid.auto``) records what was chosen and why. Otherwise a regular grid over the scene bounds
(or the config's box) from ``counts`` or ``spacing`` (:func:`workers.kernels.grid.grid_layout`).

Output ``probe_positions``: (nz, ny, nx, 3) float32 KTX2 volume (R32G32B32_SFLOAT),
world-space metres; texel (i, j, k) = probe at origin + spacing * (i, j, k) (proto/bundle.md).
"""
from __future__ import annotations

import numpy as np

from proto.models import MAX_PROBES
from workers.kernels.autogrid import analyze_free_space, choose_grid
from workers.kernels.grid import grid_layout, grid_positions
from workers.kernels.materials import double_sided_triangles
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageError, StageOutput


def auto_layout(ctx: StageContext, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The default grid: planned from rays (:mod:`workers.kernels.autogrid`) in the config's box or the
    scene bounds."""
    section = ctx.config.place
    box = (np.array([section.box.min, section.box.max], np.float64) if section.box is not None
           else np.asarray(bounds, np.float64))
    scene = ctx.scene
    caster = caster_for_scene(scene)
    fs = analyze_free_space(caster, box, double_sided_triangles(scene), seed=ctx.config.seed)
    ctx.report(0.8)
    return choose_grid(box, fs, budget=section.budget)


def run_place(ctx: StageContext) -> StageOutput:
    section = ctx.config.place
    bounds = ctx.inputs["ingest"].stats["bounds"]
    auto = None
    if section.counts is None and section.spacing is None:
        counts, origin, spacing, auto = auto_layout(ctx, np.asarray(bounds, np.float64))
    else:
        counts, origin, spacing = grid_layout(np.asarray(bounds, np.float64), section)
    n = int(np.prod(counts))
    if n > MAX_PROBES:
        raise StageError("too_many_probes", f"spacing {section.spacing} gives {n} probes; the limit is {MAX_PROBES}")
    positions = grid_positions(counts, origin, spacing)
    ctx.report(1.0)
    stats = {"counts": counts.tolist(), "origin": origin.tolist(), "spacing": spacing.tolist(), "probes": n}
    if auto is not None:
        stats["auto"] = auto
    return StageOutput(
        artifacts=[Artifact("probe_positions", positions, description="probe grid positions, world space, metres",
                            meta={"counts": counts.tolist()})],
        stats=stats,
    )
