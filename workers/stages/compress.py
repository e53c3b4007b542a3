"""Stage ``compress``: the mask volumes as per-cell, per-channel blocks in an atlas + one indirection (MD §3.4.2).

Inputs: ``masks`` (``masks_0123``, and ``masks_4567`` when K > 4: (Z, Y, X, 4) uint8 RGBA8 over the
refined grid, K in their meta), ``place`` stats (counts, origin, spacing), ``visibility.samples_per_cell`` (S) and
``masks.compress_tolerance`` (0 = lossless). The layout is :mod:`workers.kernels.mask_atlas`'s module doc.

Outputs (``proto/bundle.md`` 5.2):

* ``mask_atlas``: (bz·S, by·S, bx·S) R8_UNORM 3D, zstd: the distinct non-constant S³ blocks of one mask channel of
  one cell; sample with LINEAR filtering.
* ``mask_indirection``: (2·G·cz, cy, cx, 4) R8G8B8A8_UNORM 3D, zstd, G = ceil(K/4): per cell and channel a 16-bit
  code (low bytes in the first cz slices of a group, high bytes in the next): 0 → m = 0, 1 → m = 1, c ≥ 2 →
  atlas slot c − 2 (read with ``texelFetch(...) * 255``).

Both artifacts' ``meta`` hold S, ``block_size``, ``block_grid``, ``atlas_size``, ``cells``, ``clusters``, ``groups``
and the formulas. Stats: channel blocks, constant ones, unique and atlas blocks, bytes raw and as stored (zstd),
the ratios (dense RGBA8 bytes / atlas + indirection bytes), the max error bound and the max |compressed − dense|
of the runtime lookup at 10k seeded points of the grid box against the uncompressed masks.
"""
from __future__ import annotations

import time

import numpy as np
import pyzstd

from proto.ktx2 import zstd_frame
from workers.kernels.compress import lookup_blend, mask_lookups, texture_linear
from workers.kernels.mask_atlas import compress_channels, sample_channel_atlas
from workers.stages.base import Artifact, StageContext, StageError, StageOutput, samples_per_cell

ZSTD_LEVEL = 17      # zdm2's 4.35 MB atlas: 478.5 KB at 19 (2.7 s), 494.0 KB at 17 (1.2 s), 500.1 KB at 16,
                    # 563.0 KB at 15, 574.3 KB at 12 (0.2 s): 17 keeps within 3.3% of the best for 1.5 s less on
                    # the bake's critical path (+15 KB of a 16.5 MB bundle); the stats' sizes are the stored frames
ERROR_POINTS = 10000
VOLUMES = ("0123", "4567")


def lookup_error(vols, ca, grid, seed) -> tuple[float, float]:
    """``(reads, blended)``: max |atlas − dense| of the runtime mask lookup's reads (1 sample along a random unit
    d = n + v, and at the point) and of their blend, at ``ERROR_POINTS`` seeded points of the grid box, over the K
    channels, coordinates in float64: the error the compression adds to the masks. The reads are within
    ``max_block_error``; the blend (compress.lookup_blend) can amplify it where the offset read is nearly empty."""
    rng = np.random.default_rng(seed)
    counts, origin, spacing = (np.asarray(grid[k], np.float64) for k in ("counts", "origin", "spacing"))
    layers = grid.get("layers")
    pts = origin + rng.random((ERROR_POINTS, 3)) * spacing * np.maximum(counts - 1, 0)
    d = rng.normal(size=(ERROR_POINTS, 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    K, S = ca.meta["clusters"], ca.meta["samples_per_cell"]
    dense = np.concatenate(vols, axis=3)
    ts, _ = mask_lookups(pts, counts, origin, spacing, S, d, 1.0, np.float64, layers)
    want = [texture_linear(dense, (t + 0.5) / np.array(dense.shape[2::-1], np.float64))[:, :K] for t in ts]
    got = sample_channel_atlas(ca.atlas, ca.indirection, ca.meta, pts, grid["counts"], origin, spacing,
                               np.float64, dirs=d, samples=1.0, blend=False, layers=layers)
    reads = max(float(np.abs(w - g).max()) for w, g in zip(want, got))
    return reads, float(np.abs(lookup_blend(want) - lookup_blend(got)).max())


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
    K = int(masks.stats["clusters"])
    t0 = time.perf_counter()
    try:
        ca = compress_channels(vols, counts, S, K, tol)
    except ValueError as e:
        raise StageError("bad_masks", str(e)) from e
    t1 = time.perf_counter()
    ctx.report(0.7)
    read_err, err = lookup_error(vols, ca, place, ctx.config.seed)
    t2 = time.perf_counter()
    dense_z = sum(len(pyzstd.compress(v.tobytes(), 3)) for v in vols)          # for comparison only: level 3
    # the frames the artifacts store (proto.ktx2.zstd_frame keeps them: writing them below does not compress again)
    atlas_z = len(zstd_frame(np.ascontiguousarray(ca.atlas).tobytes(), ZSTD_LEVEL))
    ind_z = len(zstd_frame(np.ascontiguousarray(ca.indirection).tobytes(), ZSTD_LEVEL))
    ctx.report(1.0)
    stats = {
        **ca.stats,
        "max_read_error": read_err, "max_sample_error": err, "error_points": ERROR_POINTS, "zstd_level": ZSTD_LEVEL,
        "dense_zstd3_bytes": dense_z, "atlas_zstd_bytes": atlas_z, "indirection_zstd_bytes": ind_z,
        "compressed_zstd_bytes": atlas_z + ind_z,
        "ratio_stored": ca.stats["dense_bytes"] / (atlas_z + ind_z),
        "compress_seconds": t1 - t0, "error_seconds": t2 - t1,
    }
    arts = [Artifact("mask_atlas", ca.atlas, zstd_level=ZSTD_LEVEL, meta=ca.meta,
                     description="mask atlas (MD §3.4.2, per channel): the distinct non-constant S^3 blocks of one "
                                 "mask channel of a cell"),
            Artifact("mask_indirection", ca.indirection, zstd_level=ZSTD_LEVEL, meta=ca.meta,
                     description="per cell and mask channel a 16-bit code (low bytes, then high bytes, per group of "
                                 "4 channels): 0 = m 0, 1 = m 1, c >= 2 = atlas slot c - 2")]
    return StageOutput(artifacts=arts, stats=stats)
