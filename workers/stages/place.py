"""Stage ``place``: the probe grid (DESIGN stage 1, before tracing).

With neither ``counts`` nor ``spacing`` (the default) the grid is chosen from the scene by planning rays
(:mod:`workers.kernels.autogrid`: the box of its enclosed spaces, a spacing from its room sizes under
``place.budget`` probes, visibility samples per cell from its thinnest walls); the stats' ``auto`` (the
manifest's ``grid.auto``) records what was chosen and why. Otherwise:

A regular grid over the scene bounds (or the config's box), padded by ``padding`` x extent
on each side. ``counts`` puts the outermost probes on the faces of the box; ``spacing``
uses ``ceil(extent / spacing) + 1`` probes per axis, centred on the box. An axis with zero
extent (a flat scene) gets its probes in that plane.

Output ``probe_positions``: (nz, ny, nx, 3) float32 KTX2 volume (R32G32B32_SFLOAT),
world-space metres; texel (i, j, k) = probe at origin + spacing * (i, j, k) (proto/bundle.md).
"""
from __future__ import annotations

import math

import numpy as np

from proto.models import MAX_PROBES, PlaceSection
from workers.kernels.autogrid import analyze_free_space, choose_grid
from workers.kernels.materials import double_sided_triangles
from workers.raycast import caster_for_scene
from workers.stages.base import Artifact, StageContext, StageError, StageOutput


def grid_layout(bounds: np.ndarray, section: PlaceSection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Counts (3,) int, origin (3,) float64 and spacing (3,) float64 of the probe grid.

    bounds : (2, 3) float, world-space box (min, max), metres.
    """
    lo, hi = (np.asarray(section.box.min), np.asarray(section.box.max)) if section.box else (bounds[0], bounds[1])
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    pad = (hi - lo) * section.padding
    lo, hi = lo - pad, hi + pad
    extent = hi - lo
    if section.counts is not None:
        counts = np.asarray(section.counts, np.int64)
        spacing = np.where(counts > 1, extent / np.maximum(counts - 1, 1), 0.0)
        origin = np.where(counts > 1, lo, (lo + hi) / 2)
    else:
        s = float(section.spacing)
        counts = np.array([math.ceil(e / s - 1e-9) + 1 if e > 0 else 1 for e in extent], np.int64)
        spacing = np.where(counts > 1, s, 0.0)
        origin = (lo + hi) / 2 - spacing * (counts - 1) / 2
    return counts, origin, spacing


def grid_positions(counts: np.ndarray, origin: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """(nz, ny, nx, 3) float32 world positions of a regular grid (x fastest in memory)."""
    nx, ny, nz = (int(c) for c in counts)
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    idx = np.stack([i, j, k], axis=-1).astype(np.float64)
    return (origin + idx * spacing).astype(np.float32)


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
