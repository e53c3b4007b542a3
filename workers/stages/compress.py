"""Stage ``compress``: the mask volumes as per-cell blocks in an atlas + one indirection (MD §3.4.2).

Inputs: ``masks`` (``masks_0123``, and ``masks_4567`` when K > 4: (Z, Y, X, 4) uint8 RGBA8 over the
refined grid), ``place`` stats (counts, origin, spacing), ``visibility.samples_per_cell`` (S) and
``masks.compress_tolerance`` (0 = lossless). The layout is :mod:`workers.kernels.compress`'s module doc.

Outputs:

* ``mask_atlas_0123`` (+ ``mask_atlas_4567``): (bz·T, by·T, bx·T, 4) R8G8B8A8_UNORM 3D, zstd 3; T = S
  (``LAYOUT = "cell"``: a cell's own S³ samples, all the own-cell lookup reads), ``meta.block_size``;
  block (bx_, by_, bz_) occupies texels [bx_·T, bx_·T + T) × … and holds the bordered block of the cells
  pointing at it. Sample with LINEAR filtering.
* ``mask_indirection``: (cz, cy, cx, 4) R8G8B8A8_UNORM 3D, zstd 3; texel (i, j, k) of cell (i, j, k) =
  (bx_, by_, bz_, 0), block coordinates in the block grid (read with ``texelFetch(...) * 255``).

Every artifact's ``meta`` holds S, ``block_size`` T, ``block_grid`` (bx, by, bz), ``atlas_size``, ``cells``
and the sampling formula. Stats: blocks, unique blocks, atlas blocks, bytes, ratio, the max error bound
and the max |compressed − dense| of trilinear samples at 10k seeded points of the grid box.
"""
from __future__ import annotations

import time

import numpy as np
import pyzstd

from workers.kernels.compress import compress_masks, sample_error
from workers.stages.base import Artifact, StageContext, StageError, StageOutput, samples_per_cell

ZSTD_LEVEL = 3
ERROR_POINTS = 10000
# "cell": S^3 blocks, a cell's own samples: all the runtime's own-cell lookup reads (kernels/compress.py);
# "shared" (S+1)^3 and "bordered" (S+2)^3 carry neighbour layers the lookup no longer reads.
LAYOUT = "cell"
VOLUMES = ("0123", "4567")


def run_compress(ctx: StageContext) -> StageOutput:
    masks = ctx.inputs["masks"]
    place = ctx.inputs["place"].stats
    counts, origin, spacing = place["counts"], place["origin"], place["spacing"]
    S = samples_per_cell(ctx.config, place)
    tol = float(ctx.config.masks.compress_tolerance)
    names = [n for n in VOLUMES if f"masks_{n}" in masks]
    if "0123" not in names:
        raise StageError("no_masks", "stage masks produced no masks_0123 volume")
    vols = [np.ascontiguousarray(masks[f"masks_{n}"]) for n in names]
    t0 = time.perf_counter()
    try:
        cm = compress_masks(vols, counts, S, tol, layout=LAYOUT)
    except ValueError as e:
        raise StageError("bad_masks", str(e)) from e
    t1 = time.perf_counter()
    ctx.report(0.7)
    err = sample_error(vols, cm, counts, origin, spacing, S, n=ERROR_POINTS, seed=ctx.config.seed)
    t2 = time.perf_counter()
    dense_z = sum(len(pyzstd.compress(v.tobytes(), ZSTD_LEVEL)) for v in vols)
    comp_z = sum(len(pyzstd.compress(a.tobytes(), ZSTD_LEVEL)) for a in cm.atlases) \
        + len(pyzstd.compress(cm.indirection.tobytes(), ZSTD_LEVEL))
    ctx.report(1.0)
    stats = {
        **cm.stats,
        "max_sample_error": err, "error_points": ERROR_POINTS,
        "dense_zstd_bytes": dense_z, "compressed_zstd_bytes": comp_z, "zstd_ratio": dense_z / comp_z,
        "compress_seconds": t1 - t0, "error_seconds": t2 - t1,
    }
    meta = {**cm.meta, "volumes": [f"mask_atlas_{n}" for n in names]}
    arts = [Artifact(f"mask_atlas_{n}", a, zstd_level=ZSTD_LEVEL, meta=meta,
                     description=f"mask atlas (MD §3.4.2) of masks_{n}: per-cell blocks of the cell's "
                                 "S^3 samples, identical blocks merged")
            for n, a in zip(names, cm.atlases)]
    arts.append(Artifact("mask_indirection", cm.indirection, zstd_level=ZSTD_LEVEL, meta=meta,
                         description="per cell: its block's (x, y, z) in the mask atlas block grid, a = 0"))
    return StageOutput(artifacts=arts, stats=stats)
