"""Mask compression (MD §3.4.2; DESIGN stage 5): per-cell blocks, merged, in an atlas + indirection.

MD §3.4.2 cuts the dense mask volume into "cubes formed by 8 probes" (one per grid cell), merges
cubes with the same data and addresses them through one indirection volume texture. We add a
one-sample border to every block so that the GPU's trilinear filter inside a block of the atlas
reproduces the trilinear filter of the dense volume *everywhere* in the cell, cell faces included.

Dense input (proto/bundle.md §5, "refined grid")
------------------------------------------------
``counts = (nx, ny, nz)`` probes, ``cells = max(n - 1, 1)`` per axis (an axis with one probe is one
cell of zero extent, spacing 0), ``S`` samples per cell axis. A mask volume is an RGBA8 array
``(Z, Y, X, 4) = (cz·S, cy·S, cx·S, 4)`` uint8; sample (x, y, z) sits at
``origin + spacing · ((x, y, z) + 0.5) / S``: the texel centres of a 3D texture spanning the grid box.
K ≤ 4 masks are one volume (``masks_0123``), K > 4 two (``masks_0123``, ``masks_4567``).

Blocks
------
Three layouts (``layout``), all exact for the own-cell lookup ("Sampling"); ``lo``/``hi`` = the border
below/above, ``T = S + lo + hi``:

* ``"cell"`` (the compress stage's; MD §3.4.2's "cubes formed by 8 probes"): ``T = S``, no border. The
  own-cell lookup reads only the cell's S³ samples, so a block is exactly them: the smallest blocks, and
  a block depends on nothing outside its cell, so the most blocks repeat.
* ``"shared"``: ``T = S + 1``, ``lo = 0``, ``hi = 1``: the + neighbour's first layer too (needed when
  masks were filtered across cell faces, before the own-cell rule; kept for comparison).
* ``"bordered"`` (DESIGN stage 5 as written): ``T = S + 2``, ``lo = hi = 1``.

The block of cell (ci, cj, ck) holds the dense samples ``x ∈ [ci·S − lo, ci·S + S − 1 + hi]`` (and likewise
y, z), indices clamped to the volume (clamp-to-edge): block texel (a, b, c) = dense sample
``(clamp(ci·S − lo + a), clamp(cj·S − lo + b), clamp(ck·S − lo + c))``.
Its key is the bytes of the blocks of *all* volumes of that cell together, so one indirection texel
serves every volume. Identical keys are merged (lossless). With a tolerance ``tol > 0`` the distinct
blocks are then clustered greedily (most frequent first; a block joins the first representative whose
every byte, over all volumes, differs by at most ``floor(255·tol)``, else it becomes a representative);
the atlas stores representatives only, which are actual blocks (never averages), so the per-texel error
of a cell is exactly its block's max byte difference, reported as ``max_block_error`` (≤ tol). Because
trilinear filtering is a convex combination of texels, every filtered sample's error is ≤ that bound.

Atlas layout
------------
``U`` atlas blocks in a block grid ``(bx, by, bz)`` (:func:`atlas_layout`): every axis ≤ 256 texels
(``floor(256 / T)`` blocks) when ``U`` fits, else ≤ 2048 texels (and ≤ 256 blocks); among grids
that fit, the fewest allocated blocks, then the smallest largest axis. Atlas slot ``u`` (0 ≤ u < U;
ordered by decreasing number of cells using it, ties by first cell in C order) sits at block coordinates
``(u % bx, (u // bx) % by, u // (bx·by))``; its texel (a, b, c) is atlas texel
``(bxu·T + a, byu·T + b, bzu·T + c)``, i.e. ``atlas[bzu·T + c, byu·T + b, bxu·T + a, :]``. Unused slots are 0.
Atlas array ``(bz·T, by·T, bx·T, 4)`` uint8, one per input volume, the same layout for all.

Indirection: ``(cz, cy, cx, 4)`` uint8 (RGBA8 UNORM); texel (ci, cj, ck) = ``(bxu, byu, bzu, 0)`` of the
cell's slot (block coordinates, not texels; at most 256 blocks per axis, so each fits a byte).

Sampling (the GLSL; :func:`sample_compressed` does the same in numpy)
----------------------------------------------------------------------
::

    uniform vec3 gridOrigin, invSpacing;   // invSpacing = 1/spacing, 0 on one-probe axes
    uniform vec3 gridHalf;                 // 0, and 0.5 on one-probe axes (middle of the zero-extent cell)
    uniform vec3 gridCells;                // max(counts - 1, 1)
    uniform vec3 live;                     // 1 on axes with more than one probe, else 0
    uniform float S, T, LO;                // samples per cell; block size S + LO + HI (meta.block_size); LO = meta.border_lo
    uniform float offset;                  // samples (1): the lookup moves offset samples along d = n + v
    uniform vec3 invAtlasSize;             // 1 / meta.atlas_size = 1 / (bx·T, by·T, bz·T)
    vec3 cell = clamp(floor((p - gridOrigin) * invSpacing + gridHalf), 0.0, gridCells - 1.0);  // p's own cell
    vec3 g = (p - gridOrigin) * invSpacing + gridHalf + live * offset * (n + v) / S;   // lookup, cell units
    vec3 t = clamp(g * S - 0.5, cell * S, cell * S + S - 1.0);            // dense texel coordinate
    vec3 blk = floor(texelFetch(maskIndirection, ivec3(cell), 0).xyz * 255.0 + 0.5);
    vec3 local = t - cell * S + LO;                                       // in [LO, LO + S - 1]
    vec4 m = texture(maskAtlas0123, (blk * T + local + 0.5) * invAtlasSize);   // LINEAR filter
    // with offset > 0: the same at g without the offset term, and the two blended ("Both sides" below)

**Own-cell rule.** The texel coordinate is clamped to the point's own cell's S³ samples (as θ is read:
:mod:`workers.kernels.samplers`), so the trilinear footprint never reaches a neighbouring cell. Channels of
clusters absent from a cell are free there (canonical 0, :func:`workers.kernels.mask_fit.canonicalize`, so the
shader skips them); filtering across a face would blend the free value into the neighbour, where the cluster
may be present (with the earlier canonical 255: a bright line along a cell face of the two-rooms wall). :func:`sample_dense` reads the
dense volume by the same rule, and dense texel d is block texel ``d − cell·S + lo``, so both filters read
the same 8 values with the same weights; a block's border layers (``shared``, ``bordered``) are not read. Points outside the
grid box clamp to it. In float32 the two paths round the texel coordinate differently (|Δt| ≲ 1e-5 texel),
which is the only difference of a lossless atlas from the dense volume.

**Both sides.** With an offset (the runtime's 1 sample along n + v), the lookup reads twice in the same cell: at the
offset point (``a``) and at the point itself (``b``), and blends them by how much of ``a`` the point sees
(:func:`lookup_blend`): ``m = b + s·(a' − b)``, ``s`` from 0 where the point sees a quarter of the offset read's
clusters to 1 where it sees half (a cluster counts as seen from a mask of 0.1 up), ``a'`` the offset read of the
clusters the point sees (``a_c·min(1, b_c / 0.1)``). The offset lifts a surface's
footprint off the wall it lies on (its far side's clusters, filled into the wall's don't-care samples, would get up
to half the weight); the point's own read keeps a receiver that faces a surface closer than the offset from reading
what lies behind that surface (godot-living-room, 5 cm in front of its walls: normalized mask GI 0.84 of Cycles with
the offset alone, 1.00 with both; 10 cm: 0.90 → 1.00). On a surface, the offset read's clusters are the surface's
own side, which the footprint holds too, if only a few % at a corner of a room whose walls are thinner than a sample
(the offset read, as before: sealed-box's cavity at 4 samples a cell); past a surface the offset read holds clusters
the point does not see (the point's read). A receiver within a fraction of a sample of a surface it faces sees the
far side in its own footprint already: there the offset read still wins. Between the two, an offset that ends
INSIDE a wall thinner than two samples (a receiver facing it a few cm away) reads its don't-care samples, filled from
both sides: half the wall's far side, a share the point "sees" between the bounds; the blend took that far side in
(rooms-unequal of tests/data/fidelity, 5 cm from a 2 cm wall at 2.8 cm samples: normalized mask GI 1.6 of Cycles,
5x on the normal facing the wall; sun-window, 5 cm from an 8 cm wall at 4.2 cm samples: 1.23). Only ``a'`` enters
the blend: a cluster the point does not see at all is never taken from the offset read, one it sees from 0.1 up is
taken as before (every region and mode of bench_fidelity's two-rooms, two-rooms-vc, sealed-box, cornell, furnace,
cornell-mcguire and cornell-vinc3r is unchanged, to the last digit); both now read 1.06 and 1.02, equal to
visibility-weighted GI (MD §3.2). Plain (unnormalized) mask GI reads the own side's clusters there at their
in-wall weight (< 1): 0.74 and 0.86 of Cycles (1.05 and 0.99 before, where the leak made up for it).

Consumers: stages/compress; the viewer's mask shader (proto/glsl) via the meta of the artifacts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from proto.gi_modes import MASK_BLEND, MASK_SEEN_THRESHOLD
from workers.kernels.grid import grid_coord

__all__ = ["CompressedMasks", "atlas_layout", "compress_masks", "decompress", "cells_of",
           "sample_dense", "sample_compressed", "texture_linear", "sample_error", "mask_lookup_texel", "mask_lookups", "lookup_blend", "MASK_OVERLAP", "MASK_PRESENT", "LAYOUTS",
           "PREFERRED_TEXELS",
           "MAX_TEXELS"]

LAYOUTS = ("bordered", "shared", "cell")
_BORDERS = {"bordered": (1, 1), "shared": (0, 1), "cell": (0, 0)}   # (lo, hi)
PREFERRED_TEXELS = 256   # WebGL2's guaranteed MAX_3D_TEXTURE_SIZE
MAX_TEXELS = 2048        # the hard limit on any atlas axis
MAX_BLOCKS_PER_AXIS = 256  # block coordinates are stored as bytes in the indirection


def cells_of(counts) -> np.ndarray:
    """(3,) int64 cells per axis (x, y, z): ``max(n - 1, 1)``."""
    return np.maximum(np.asarray(counts, np.int64) - 1, 1)


@dataclass
class CompressedMasks:
    atlases: list[np.ndarray]      # per input volume, (bz·T, by·T, bx·T, 4) uint8
    indirection: np.ndarray        # (cz, cy, cx, 4) uint8: block x, y, z, 0
    slot_of_cell: np.ndarray       # (cz, cy, cx) int64 atlas slot of each cell
    meta: dict
    stats: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------- layout
def atlas_layout(n_blocks: int, block: int, preferred: int = PREFERRED_TEXELS,
                 limit: int = MAX_TEXELS) -> tuple[int, int, int]:
    """Block grid ``(bx, by, bz)`` holding ``n_blocks`` blocks of ``block`` texels per axis.

    Every axis ≤ ``preferred`` texels when the count allows (``floor(preferred/block)³ ≥ n_blocks``),
    else ≤ ``limit``, and never more than 256 blocks per axis (byte coordinates); among those, the
    fewest allocated blocks ``bx·by·bz``, then the smallest largest axis, then larger bx, then larger by.
    Raises ValueError when even ``limit`` is too small.
    """
    n = int(n_blocks)
    if n < 1 or block < 1:
        raise ValueError(f"atlas_layout: need n_blocks >= 1 and block >= 1, got {n_blocks}, {block}")
    for cap in (preferred, limit):
        m = min(cap // block, MAX_BLOCKS_PER_AXIS)
        if m < 1 or m ** 3 < n:
            continue
        bx, by = np.meshgrid(np.arange(1, m + 1), np.arange(1, m + 1), indexing="ij")
        bx, by = bx.ravel(), by.ravel()
        bz = -(-n // (bx * by))
        ok = bz <= m
        bx, by, bz = bx[ok], by[ok], bz[ok]
        total = bx * by * bz
        big = np.maximum(np.maximum(bx, by), bz)
        i = np.lexsort((-by, -bx, big, total))[0]
        return int(bx[i]), int(by[i]), int(bz[i])
    raise ValueError(f"{n} blocks of {block}^3 texels do not fit a {limit}^3 atlas")


# ---------------------------------------------------------------------------- blocks
def _block_views(volume: np.ndarray, S: int, cells, lo: int, hi: int = 1) -> np.ndarray:
    """Read-only view (cz, cy, cx, T, T, T, 4) of the blocks of an edge-padded volume: block texel a
    of cell c is dense sample ``clamp(c·S − lo + a)``, T = S + lo + hi."""
    padded = np.pad(volume, ((lo, hi), (lo, hi), (lo, hi), (0, 0)), mode="edge")
    T = S + lo + hi  # MD §3.4.2: one cube per cell ("formed by 8 probes"), plus the layout's border
    cx, cy, cz = (int(c) for c in cells)
    sz, sy, sx, sc = padded.strides
    return np.lib.stride_tricks.as_strided(
        padded, shape=(cz, cy, cx, T, T, T, padded.shape[3]),
        strides=(S * sz, S * sy, S * sx, sz, sy, sx, sc), writeable=False)


def _check_volumes(volumes, counts, S) -> tuple[list[np.ndarray], np.ndarray]:
    if isinstance(volumes, np.ndarray):
        volumes = [volumes]
    volumes = [np.asarray(v) for v in volumes]
    if not volumes:
        raise ValueError("compress_masks: no volumes")
    S = int(S)
    if S < 1:
        raise ValueError(f"samples per cell must be >= 1, got {S}")
    cells = cells_of(counts)
    want = (int(cells[2]) * S, int(cells[1]) * S, int(cells[0]) * S, 4)
    for v in volumes:
        if v.dtype != np.uint8 or v.shape != want:
            raise ValueError(f"mask volume must be uint8 {want} for counts {list(counts)} and S = {S}, "
                             f"got {v.dtype} {v.shape}")
    return volumes, cells


def _unique_blocks(views: list[np.ndarray], cells) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact merge. Returns (blocks (U, V, T, T, T, 4) uint8 in first-appearance order,
    block index per cell (cz, cy, cx) int64, cells per block (U,) int64)."""
    cx, cy, cz = (int(c) for c in cells)
    index: dict[bytes, int] = {}
    uniq: list[np.ndarray] = []
    of_cell = np.empty((cz, cy, cx), np.int64)
    for k in range(cz):
        layer = np.ascontiguousarray(np.stack([v[k] for v in views], axis=2))  # (cy, cx, V, T, T, T, 4)
        flat = layer.reshape(cy * cx, *layer.shape[2:])
        row = of_cell[k].reshape(-1)
        for i in range(cy * cx):
            key = flat[i].tobytes()
            u = index.get(key)  # MD §3.4.2: cubes with the same mask data are merged
            if u is None:
                u = index[key] = len(uniq)
                uniq.append(flat[i])
            row[i] = u
    blocks = np.stack(uniq)
    return blocks, of_cell, np.bincount(of_cell.ravel(), minlength=len(uniq))


def _summaries(blocks: np.ndarray) -> np.ndarray:
    """(U, V·8·4) float64 mean of every channel over each block octant: a lower bound on the max
    byte difference of two blocks is the largest difference of their summaries."""
    U, V, T = blocks.shape[:3]
    h = T // 2
    parts = []
    for zs in (slice(0, h), slice(h, T)):
        for ys in (slice(0, h), slice(h, T)):
            for xs in (slice(0, h), slice(h, T)):
                parts.append(blocks[:, :, zs, ys, xs, :].mean(axis=(2, 3, 4), dtype=np.float64))
    return np.ascontiguousarray(np.concatenate(parts, axis=1).reshape(U, -1))


@numba.njit(cache=True, nogil=True)
def _greedy_merge(blocks, summaries, order, thr):  # pragma: no cover - compiled
    U, B = blocks.shape
    rep_of = np.empty(U, np.int64)
    err = np.zeros(U, np.int64)
    reps = np.empty(U, np.int64)
    nrep = 0
    slack = thr + 1e-9
    for oi in range(U):
        u = order[oi]
        found = -1
        for ri in range(nrep):
            r = reps[ri]
            skip = False
            for s in range(summaries.shape[1]):
                if abs(summaries[u, s] - summaries[r, s]) > slack:
                    skip = True
                    break
            if skip:
                continue
            m = 0
            for b in range(B):
                d = abs(np.int64(blocks[u, b]) - np.int64(blocks[r, b]))
                if d > m:
                    m = d
                    if m > thr:
                        break
            if m <= thr:
                found = r
                err[u] = m
                break
        if found < 0:
            reps[nrep] = u
            nrep += 1
            rep_of[u] = u
        else:
            rep_of[u] = found
    return rep_of, err, reps[:nrep]


# ---------------------------------------------------------------------------- compress
def compress_masks(volumes, counts, S: int, tolerance: float = 0.0, layout: str = "bordered",
                   preferred: int = PREFERRED_TEXELS, limit: int = MAX_TEXELS) -> CompressedMasks:
    """Compress RGBA8 mask volumes (one, or two for K > 4) into atlases + one indirection (module doc).

    Parameters
    ----------
    volumes : (Z, Y, X, 4) uint8 array or a list of them (same shape), the refined grid of ``counts``/``S``.
    counts : (nx, ny, nz) probes. S : samples per cell axis.
    tolerance : max |Δm| (m in [0, 1]) allowed between a block and its representative; 0 = lossless.
    layout : ``"cell"`` (S³ blocks, no border), ``"shared"`` ((S+1)³, border on the + side) or
        ``"bordered"`` ((S+2)³, border on both sides); see the module doc.

    Returns a :class:`CompressedMasks` whose ``stats`` hold ``blocks`` (cells), ``unique_blocks``
    (exactly distinct), ``atlas_blocks`` (after the tolerance merge), ``max_block_error`` (max |Δm| of
    any atlas texel vs the dense texel it stands for; 0 when lossless), ``dense_bytes``,
    ``compressed_bytes`` (atlases + indirection, GPU memory), ``ratio``.
    """
    volumes, cells = _check_volumes(volumes, counts, S)
    S = int(S)
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    lo, hi = _BORDERS[layout]
    T = S + lo + hi
    if not (0.0 <= float(tolerance) <= 1.0):
        raise ValueError(f"tolerance must be in [0, 1], got {tolerance}")
    views = [_block_views(v, S, cells, lo, hi) for v in volumes]
    blocks, of_cell, n_cells = _unique_blocks(views, cells)
    U = blocks.shape[0]
    thr = int(math.floor(float(tolerance) * 255.0 + 1e-9))
    first = np.full(U, of_cell.size, np.int64)
    np.minimum.at(first, of_cell.ravel(), np.arange(of_cell.size))
    order = np.lexsort((first, -n_cells))           # most used first, then first appearance
    if thr > 0 and U > 1:
        rep_of, err, reps = _greedy_merge(blocks.reshape(U, -1), _summaries(blocks), order, thr)
    else:
        rep_of, err, reps = np.arange(U), np.zeros(U, np.int64), order
    slot_of_rep = np.full(U, -1, np.int64)
    slot_of_rep[reps] = np.arange(len(reps))
    slot_of_block = slot_of_rep[rep_of]
    slot_of_cell = slot_of_block[of_cell]
    n_slots = len(reps)

    bx, by, bz = atlas_layout(n_slots, T, preferred, limit)
    V = len(volumes)
    grid = np.zeros((bx * by * bz, V, T, T, T, 4), np.uint8)
    grid[:n_slots] = blocks[reps]
    grid = grid.reshape(bz, by, bx, V, T, T, T, 4).transpose(3, 0, 4, 1, 5, 2, 6, 7)
    atlases = [np.ascontiguousarray(grid[v].reshape(bz * T, by * T, bx * T, 4)) for v in range(V)]

    s = slot_of_cell
    indirection = np.zeros(of_cell.shape + (4,), np.uint8)  # MD §3.4.2: one indirection volume indexes the cubes
    indirection[..., 0] = s % bx
    indirection[..., 1] = (s // bx) % by
    indirection[..., 2] = s // (bx * by)

    dense_bytes = int(sum(v.nbytes for v in volumes))
    comp_bytes = int(sum(a.nbytes for a in atlases) + indirection.nbytes)
    meta = {
        "layout": layout, "samples_per_cell": S, "border_lo": lo, "border_hi": hi, "block_size": T,
        "cells": [int(c) for c in cells],
        "block_grid": [bx, by, bz],
        "atlas_size": [bx * T, by * T, bz * T],
        "atlas_blocks": int(n_slots),
        "fits_256": bool(max(bx, by, bz) * T <= 256),
        "indirection": "RGBA8 UNORM (cz, cy, cx, 4): r, g, b = the cell's block x, y, z in the block grid "
                       "(value·255), a = 0",
        "atlas_texel": f"block (bx_, by_, bz_) texel (a, b, c), 0 <= a, b, c < T, is atlas texel "
                       f"(bx_·T + a, by_·T + b, bz_·T + c) = dense sample (clamp(ci·S - {lo} + a), "
                       f"clamp(cj·S - {lo} + b), clamp(ck·S - {lo} + c)) of every cell (ci, cj, ck) using it",
        "sample": f"g(y) = (y - origin)/spacing (:= 0.5 on one-probe axes); cell = clamp(floor(g(p)), 0, cells - 1); "
                  f"t = clamp((g(p) + offset·(n + v)/S)·S - 0.5, cell·S, cell·S + S - 1) (live axes); "
                  f"uvw = (block·T + t - cell·S + {lo} + 0.5) / atlas_size; texture(atlas, uvw), LINEAR filter",
    }
    stats = {
        "layout": layout, "border_lo": lo, "border_hi": hi, "blocks": int(of_cell.size), "unique_blocks": int(U), "atlas_blocks": int(n_slots),
        "volumes": V, "block_size": T, "block_grid": [bx, by, bz], "atlas_size": [bx * T, by * T, bz * T],
        "fits_256": meta["fits_256"],
        "tolerance": float(tolerance), "max_block_error": float(err.max() / 255.0) if U else 0.0,
        "dense_bytes": dense_bytes, "compressed_bytes": comp_bytes,
        "atlas_bytes": int(sum(a.nbytes for a in atlases)), "indirection_bytes": int(indirection.nbytes),
        "ratio": dense_bytes / comp_bytes,
    }
    return CompressedMasks(atlases, indirection, slot_of_cell, meta, stats)


def decompress(atlas: np.ndarray, indirection: np.ndarray, meta: dict) -> np.ndarray:
    """The dense (Z, Y, X, 4) volume an atlas stands for: each cell's S³ interior from its block."""
    S, T, lo = int(meta["samples_per_cell"]), int(meta["block_size"]), int(meta["border_lo"])
    cz, cy, cx = indirection.shape[:3]
    b = indirection[..., :3].astype(np.int64)
    out = np.empty((cz * S, cy * S, cx * S, atlas.shape[3]), atlas.dtype)
    for k in range(cz):
        for j in range(cy):
            for i in range(cx):
                x0, y0, z0 = b[k, j, i] * T + lo
                out[k * S:(k + 1) * S, j * S:(j + 1) * S, i * S:(i + 1) * S] = \
                    atlas[z0:z0 + S, y0:y0 + S, x0:x0 + S]  # MD §3.4.2 undone: the cell's cube via the indirection
    return out


# ---------------------------------------------------------------------------- sampling
def texture_linear(tex: np.ndarray, uvw: np.ndarray) -> np.ndarray:
    """GPU ``texture()`` of a (D, H, W, C) uint8 UNORM 3D texture, LINEAR filter, CLAMP_TO_EDGE.

    uvw : (N, 3) normalized (u → width = x). Texel coordinate ``uvw·size − 0.5`` is computed in the dtype
    of ``uvw`` (float32 = GLSL highp); the weights and the blend in float64 (a GPU blends with ~8-bit
    fixed-point weights, which is not modelled). Returns (N, C) float64 in [0, 1].
    """
    uvw = np.asarray(uvw)
    ft = uvw.dtype if uvw.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    uvw = uvw.astype(ft, copy=False).reshape(-1, 3)
    size = np.array(tex.shape[2::-1], np.int64)       # (W, H, D)
    t = uvw * size.astype(ft) - ft.type(0.5)
    i0 = np.floor(t)
    f = (t - i0).astype(np.float64)
    i0 = i0.astype(np.int64)
    hi = size - 1
    x = np.stack([np.clip(i0[:, 0], 0, hi[0]), np.clip(i0[:, 0] + 1, 0, hi[0])])
    y = np.stack([np.clip(i0[:, 1], 0, hi[1]), np.clip(i0[:, 1] + 1, 0, hi[1])])
    z = np.stack([np.clip(i0[:, 2], 0, hi[2]), np.clip(i0[:, 2] + 1, 0, hi[2])])
    out = np.zeros((uvw.shape[0], tex.shape[3]), np.float64)
    for c in range(8):
        dx, dy, dz = c & 1, (c >> 1) & 1, (c >> 2) & 1
        w = ((f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
             * (f[:, 2] if dz else 1 - f[:, 2]))
        out += w[:, None] * tex[z[dz], y[dy], x[dx]]
    return out / 255.0


def _grid_g(points, counts, origin, spacing, dtype, layers=None):
    """``(g, cells, live)``: (N, 3) grid coordinates in cell units, ``(p − origin)·invSpacing + half`` (a rectilinear
    grid, ``layers``: :func:`workers.kernels.grid.grid_coord` + half, computed in float64); the (3,)
    cells per axis; (3,) 1 on axes with more than one probe and a positive spacing, else 0. invSpacing = 1/spacing and
    half = 0 on axes with more than one probe, invSpacing = 0 and half = 0.5 on one-probe axes (the
    middle of the zero-extent cell, as :func:`workers.kernels.samplers.field_uvw` takes uvw = 0.5)."""
    counts = np.asarray(counts, np.int64)
    sp = np.asarray(spacing, np.float64)
    live = (counts > 1) & (sp > 0)
    inv = np.where(live, 1.0 / np.where(live, sp, 1.0), 0.0).astype(dtype)
    half = np.where(live, 0.0, 0.5).astype(dtype)
    if layers is not None:
        g = np.where(live, grid_coord(points, counts, origin, sp, layers), 0.0).astype(dtype) + half
        return g, cells_of(counts).astype(dtype), live.astype(dtype)
    p = np.asarray(points, np.float64).reshape(-1, 3).astype(dtype)
    return (p - np.asarray(origin, np.float64).astype(dtype)) * inv + half, cells_of(counts).astype(dtype), \
        live.astype(dtype)


def mask_lookup_texel(points, counts, origin, spacing, S: int, dirs=None, samples: float = 0.0,
                      dtype=np.float32, layers=None) -> tuple[np.ndarray, np.ndarray]:
    """Where the runtime reads a refined-grid mask volume for surface points: ``(t, cell)``, both (N, 3)
    in ``dtype`` — the dense texel coordinate (sample x at t = x) and the point's own cell (module doc,
    "Sampling").

    ``cell = clamp(floor(g(p)), 0, cells − 1)``; the lookup moves ``samples`` refined samples along ``dirs``
    per axis (``g' = g(p) + samples·d/S`` on axes with more than one probe; d = n + v, the unit normal plus
    the unit direction to the viewer, as DDGI-P eq 2 biases: one sample in front of the surface, and
    towards the side the camera is on, away from a neighbouring wall at a corner);
    ``t = clamp(g'·S − 0.5, cell·S, cell·S + S − 1)``: the footprint never leaves the cell's own S³
    samples, so a channel that is free in a cell (canonical 0: the cluster has no probe there) never
    bleeds into a neighbour where it is not.
    """
    g, cells, live = _grid_g(points, counts, origin, spacing, dtype, layers)
    cell = np.clip(np.floor(g), dtype(0), cells - dtype(1))
    if samples and dirs is not None:
        d = np.asarray(dirs, np.float64).reshape(-1, 3).astype(dtype)
        g = g + live * (dtype(samples) / dtype(S)) * d
    f_s = dtype(S)
    t = np.clip(g * f_s - dtype(0.5), cell * f_s, cell * f_s + f_s - dtype(1))
    return t, cell


MASK_PRESENT = MASK_SEEN_THRESHOLD
"""A cluster whose mask at the point is at least this counts as seen there (:func:`lookup_blend`;
``proto/gi_modes.json`` ``mask_seen_threshold``, the GLSL's ``uMaskSeen``)."""
MASK_OVERLAP = MASK_BLEND
"""The both-sides blend of a mask lookup (:func:`lookup_blend`): the offset read wins fully where the point sees at
least ``MASK_OVERLAP[1]`` of its clusters, the read at the point where at most ``MASK_OVERLAP[0]``, linear between
(``proto/gi_modes.json`` ``mask_blend``, the GLSL's ``uMaskBlend``)."""


def mask_lookups(points, counts, origin, spacing, S: int, dirs=None, samples: float = 0.0,
                 dtype=np.float32, layers=None) -> tuple[list[np.ndarray], np.ndarray]:
    """The texel coordinates one runtime mask lookup reads, and the point's own cell: ``([t], cell)`` at the point
    when there is no offset, else ``([t', t], cell)`` — ``t'`` moved ``samples`` refined samples along ``dirs``
    (:func:`mask_lookup_texel`) and ``t`` at the point, combined by :func:`lookup_blend` (module doc, "Both
    sides").
    """
    t, cell = mask_lookup_texel(points, counts, origin, spacing, S, None, 0.0, dtype, layers)
    if not samples or dirs is None:
        return [t], cell
    t_off, _ = mask_lookup_texel(points, counts, origin, spacing, S, dirs, samples, dtype, layers)
    return [t_off, t], cell


def lookup_blend(reads: list[np.ndarray]) -> np.ndarray:
    """Combine the reads of :func:`mask_lookups`, (N, C) each in [0, 1] (all the lookup's channels): one read is
    the value; of two, the offset read ``a`` and the read at the point ``b``,

        a'_c = a_c·min(1, b_c / τ),   seen = Σ_c a'_c / Σ_c a_c,   s = clamp((seen − lo) / (hi − lo), 0, 1),
        m = b + s·(a' − b)

    (``τ`` = :data:`MASK_PRESENT`, ``lo, hi`` = :data:`MASK_OVERLAP`; GLSL ``gi_mask.glsl`` ``giMasks``): ``seen`` is
    the share of the offset read's clusters that the point sees too. A surface point's offset read holds the clusters
    of its own side, which its footprint (partly in the wall it lies on, partly beyond a wall thinner than a sample)
    also holds, if only at a corner's few %: the offset read. An offset that crossed a surface (a receiver facing a
    wall closer than the offset) reads the clusters behind it, which the point does not see (≲ 1%): the point's read.
    An offset that ends inside a wall thinner than two samples reads its don't-care samples, filled from both sides:
    the point sees part of them (seen between the bounds), and of the rest, the far side's clusters, which the point
    does not see, ``a'`` keeps nothing: only clusters the point sees come from the offset read (the module doc,
    "Both sides").
    """
    if len(reads) == 1:
        return reads[0]
    a, b = reads
    lo, hi = MASK_OVERLAP
    a_seen = a * np.minimum(b / MASK_PRESENT, 1.0)
    seen = a_seen.sum(axis=1) / np.maximum(a.sum(axis=1), 1e-6)
    s = np.clip((seen - lo) / (hi - lo), 0.0, 1.0)[:, None]
    return b + s * (a_seen - b)


def sample_dense(volume: np.ndarray, points, counts, origin, spacing, dtype=np.float32, *, dirs=None,
                 samples: float = 0.0, layers=None) -> np.ndarray:
    """Trilinear sample of a dense refined-grid mask volume at world points by the lookup rule of
    :func:`mask_lookups` (the point's own cell's samples; with ``samples`` refined samples along ``dirs``, that
    read and the read at the point blended by :func:`lookup_blend` over this volume's channels: the GLSL blends
    over all of a lookup's channels, the same for K <= 4; :func:`workers.kernels.samplers.mask_values` over all).

    Returns (N, C) float64 in [0, 1]. ``dtype``: float precision of the coordinate math (float32 = GLSL).
    """
    counts = np.asarray(counts, np.int64)
    S = volume.shape[2] // int(cells_of(counts)[0])
    ts, _ = mask_lookups(points, counts, origin, spacing, S, dirs, samples, dtype, layers)
    dims = np.array(volume.shape[2::-1], np.float64).astype(dtype)
    return lookup_blend([texture_linear(volume, (t + dtype(0.5)) / dims) for t in ts])


def sample_compressed(atlas: np.ndarray, indirection: np.ndarray, meta: dict, points, counts, origin,
                      spacing, S: int, dtype=np.float32, *, dirs=None, samples: float = 0.0,
                      layers=None) -> np.ndarray:
    """Sample a compressed mask atlas at world points exactly as the GLSL of the module doc does
    (the lookup rule of :func:`mask_lookups`: one indirection fetch, one or two atlas reads, :func:`lookup_blend`
    over this atlas's channels, as the GLSL for K <= 4).

    atlas : (bz·T, by·T, bx·T, 4) uint8; indirection : (cz, cy, cx, 4) uint8; meta : the compress meta
    (``block_size``, ``border_lo``). Coordinate math in ``dtype`` (float32 = GLSL highp).
    Returns (N, 4) float64 in [0, 1].
    """
    T, lo, hi = int(meta["block_size"]), int(meta["border_lo"]), int(meta.get("border_hi", 1))
    S = int(S)
    if T != S + lo + hi:
        raise ValueError(f"block size {T} does not match S = {S}, border_lo = {lo} and border_hi = {hi}")
    one, f_s = dtype(1), dtype(S)
    ts, cell = mask_lookups(points, counts, origin, spacing, S, dirs, samples, dtype, layers)
    ci = cell.astype(np.int64)
    # floor(texelFetch·255 + 0.5): MD §3.4.2's "one additional sampling call" at run time
    blk = indirection[ci[:, 2], ci[:, 1], ci[:, 0], :3].astype(dtype)
    inv_size = one / np.array(atlas.shape[2::-1], np.float64).astype(dtype)
    reads = []
    for t in ts:
        local = t - cell * f_s + dtype(lo)                                   # in [lo, lo + S - 1]
        reads.append(texture_linear(atlas, (blk * dtype(T) + local + dtype(0.5)) * inv_size))
    return lookup_blend(reads)


def sample_error(volumes, compressed: CompressedMasks, counts, origin, spacing, S: int, n: int = 10000,
                 seed: int = 0, dtype=np.float32, layers=None) -> float:
    """Max |compressed − dense| over ``n`` seeded uniform points in the grid box, all volumes and channels."""
    if isinstance(volumes, np.ndarray):
        volumes = [volumes]
    rng = np.random.default_rng(seed)
    counts = np.asarray(counts, np.int64)
    ext = np.asarray(spacing, np.float64) * np.maximum(counts - 1, 0)
    pts = np.asarray(origin, np.float64) + rng.random((int(n), 3)) * ext
    err = 0.0
    for vol, atlas in zip(volumes, compressed.atlases):
        d = sample_dense(vol, pts, counts, origin, spacing, dtype, layers=layers)
        c = sample_compressed(atlas, compressed.indirection, compressed.meta, pts, counts, origin, spacing, S,
                              dtype, layers=layers)
        err = max(err, float(np.abs(d - c).max()))
    return err
