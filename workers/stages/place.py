"""Stage ``place``: the probe grid (DESIGN stage 1, before tracing).

With neither ``counts`` nor ``spacing`` (the default) the grid is chosen from the scene by planning rays
(:mod:`workers.kernels.autogrid`: the box of its enclosed spaces, a spacing from its room sizes under
``place.budget`` probes, visibility samples per cell from its thinnest walls); the stats' ``auto`` (the
manifest's ``grid.auto``) records what was chosen and why. Otherwise a regular grid over the scene bounds
(or the config's box) from ``counts`` or ``spacing`` (:func:`workers.kernels.grid.grid_layout`).

All of it in the bake frame (:mod:`workers.kernels.frame`): the pipeline hands this stage, and every probe stage
after it, the scene turned about +Y by ``place.yaw`` or the yaw fitted to its walls; the stats' ``frame`` (the
manifest's ``grid.frame``) records the turn, its world → bake matrix and why.

Output ``probe_positions``: (nz, ny, nx, 3) float32 KTX2 volume (R32G32B32_SFLOAT),
bake-frame metres; texel (i, j, k) = probe at origin + spacing * (i, j, k) (proto/bundle.md 5).
"""
from __future__ import annotations

import numpy as np

from proto.models import MAX_PROBES, PlaceSection
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


COARSE_FACTOR = 16.0 / 3.0
"""The automatic grid warns (``grid_coarse``) when the default budget holds its spacing above this many times what
the scene's free space asks for: 4x the room scale / 6 (the wanted spacing before it became room scale / 8, with
more margin; the factor keeps the warning where it was). truck-town (a 2 km town) is 18x; sealed-box (an open scene,
3.8x, its light within 1% of Cycles in bench_fidelity) is not flagged: the wanted spacing is a target with margin,
and the masks keep thin walls tight at any spacing; what a far coarser grid loses is the light's detail."""

ENCLOSED_COARSE_FACTOR = 2.0
"""The same for an enclosed scene (rooms): near their walls the light changes faster than a budget-bound grid
resolves. bench_fidelity's enclosed scenes where the budget binds: corridor-l 1.45x, living-room 1.38x, sun-window
1.79x read 0.96-1.06 of Cycles in every region; apartments (2.49x) read 1.22 / 1.20 in the dark room 5 / 10 cm from
the shared wall on a uniform grid (1.05 / 1.03 rectilinear: autogrid step 4b, from the same factor) and zdm2 (2.97x)
1.12 at its shaded walls (2026-12-06). Between 1.8 and 2.5 the threshold is not measured more finely."""


def coarse_grid_warning(auto: dict, budget: int) -> dict | None:
    """``{"code": "grid_coarse", "message"}`` when the automatic grid at the DEFAULT ``place.budget`` is budget-bound
    with a spacing over :data:`COARSE_FACTOR` x the wanted one (:data:`ENCLOSED_COARSE_FACTOR` x in an enclosed
    scene; ``auto``: :func:`choose_grid`'s record), else None.

    Right by default: a user who set nothing gets told that the defaults cannot deliver the spacing this scene
    needs (the light loses its detail and reads high close to walls; the leaking and DDGI modes cross walls thinner
    than a cell), and what to do. A budget the user chose (a preset, a smaller preview) is a choice, recorded in
    ``grid.auto.reason``, not a warning."""
    wanted, spacing = float(auto.get("spacing_wanted") or 0.0), float(auto.get("spacing") or 0.0)
    enclosed = auto.get("kind") == "enclosed"
    factor = ENCLOSED_COARSE_FACTOR if enclosed else COARSE_FACTOR
    if not auto.get("budget_bound") or int(budget) != PlaceSection().budget or wanted <= 0 \
            or spacing <= factor * wanted:
        return None
    need = int(budget * (spacing / wanted) ** 3)
    near = (" Within about a spacing of a wall the light reads high where it changes faster than the grid resolves "
            "(measured 1.1-1.2x Cycles 5-10 cm from walls in interiors at 2.5-3x the rooms' spacing)."
            if enclosed else "")
    if enclosed and auto.get("rectilinear"):
        near = (" Layers stand in front of both faces of the thin walls and slabs (a rectilinear grid: within 5% of "
                "Cycles 5-10 cm from them, measured); near thick walls and other surfaces the light can read high "
                "where it changes faster than the grid resolves (1.1x Cycles measured).")
    return {"code": "grid_coarse", "message": (
        f"the automatic probe grid is {spacing:.3g} m apart where this scene's rooms ask for {wanted:.3g} m: the "
        f"default budget of {budget} probes binds (that spacing needs about {need} probes). The light loses its detail "
        f"(and the leaking and DDGI modes cross walls thinner than a cell).{near} Set place.box to the part of the "
        f"scene that matters, or raise place.budget (at most {MAX_PROBES})")}


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
    layers = auto.pop("layers", None) if auto is not None else None
    positions = grid_positions(counts, origin, spacing, layers)
    ctx.report(1.0)
    stats = {"counts": counts.tolist(), "origin": origin.tolist(), "spacing": spacing.tolist(), "probes": n}
    if layers is not None:                             # a rectilinear grid (workers.kernels.grid; proto/bundle.md 5)
        stats["layers"] = layers
    if ctx.frame is not None:                          # the bake frame (workers.pipeline.framed_scene); grid.frame
        stats["frame"] = ctx.frame
    if auto is not None:
        stats["auto"] = auto
        warning = coarse_grid_warning(auto, section.budget)
        if warning:
            stats["warnings"] = [warning]
    return StageOutput(
        artifacts=[Artifact("probe_positions", positions, description="probe grid positions, bake frame (grid.frame), metres",
                            meta={"counts": counts.tolist()})],
        stats=stats,
    )
