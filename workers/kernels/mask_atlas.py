"""Mask compression by channel blocks (MD §3.4.2, "mask atlas + indirection"; the compress stage's layout).

MD §3.4.2 cuts the dense mask volume into "cubes formed by 8 probes" (one per grid cell), merges cubes with the
same data and addresses them through one indirection volume. :mod:`workers.kernels.compress` does that with RGBA
cubes (all 4 masks of a cell in one block); this module cuts one step further, per mask **channel**: a cell's
block of channel k is its S³ samples of m_k alone. Measured at 16x32x16, S = 8, K = 4 (``tests/bench/bench_md.py``):
of godot-living-room's 27,900 channel blocks 16,123 are all 0 and 4,479 all 255, and the rest repeat far more
often one channel at a time (a wall between clusters 0 and 1 and the same wall between 2 and 3 is one block).

Dense input (proto/bundle.md §5, "refined grid"): ``counts`` probes, ``cells = max(n − 1, 1)`` per axis, ``S``
samples per cell axis; the mask volumes ``masks_0123`` (+ ``masks_4567``), (Z, Y, X, 4) = (cz·S, cy·S, cx·S, 4)
uint8, channel k of volume q = m_{4q + k}·255.

Codes
-----
Each (cell, channel k < K) gets a 16-bit **code**: 0 = the channel is 0 in the whole cell (no atlas storage, no
fetch: the cluster has no probe there or is hidden), 1 = 255 in the whole cell (m = 1, no fetch), c ≥ 2 = atlas slot
c − 2. With a tolerance ``tol`` (bytes ``thr = floor(255·tol)``) a block within ``thr`` of all-0 / all-255 takes
code 0 / 1, and the remaining distinct blocks are clustered greedily (most used first; a block joins the first
representative whose every byte differs by at most ``thr`` and that is 0 exactly where the block is 0 — a hidden
cluster stays hidden, so merging never adds light through a wall —, else it becomes one): the atlas stores
representatives only — actual blocks, never averages — so the error of any stored texel is at most ``thr / 255``
(``max_block_error``), and of any trilinear read too (a convex combination). ``tol = 0`` is lossless.

Atlas (``mask_atlas``): R8_UNORM 3D, (bz·S, by·S, bx·S, 1); slot u (0 ≤ u < U, by decreasing use, ties by
first cell) at block coordinates ``(u % bx, (u // bx) % by, u // (bx·by))`` (:func:`workers.kernels.compress.
atlas_layout`, ≤ 256 texels per axis when the count allows, else ≤ 2048); its texel (a, b, c) is atlas texel
``(bxu·S + a, byu·S + b, bzu·S + c)``. A bake with no non-constant block still gets one (zero) slot.

Indirection (``mask_indirection``): RGBA8_UNORM, (2·G·cz, cy, cx, 4), G = ceil(K / 4) groups of 4 channels:
texel (i, j, 2g·cz + k) holds the low bytes of the codes of channels 4g … 4g + 3 of cell (i, j, k), texel
(i, j, (2g + 1)·cz + k) the high bytes; code = lo + 256·hi; channels ≥ K are 0. 8·G bytes per cell.

Sampling (GLSL ``gi_mask.glsl`` ``giMasks``; :func:`sample_channel_atlas` in numpy)::

    cell, t (texel coordinates of the reads, clamped to the cell's own S³ samples): compress.mask_lookups
    code_k = floor(255·lo_k + 0.5) + 256·floor(255·hi_k + 0.5)          2·G texelFetch of the indirection
    m_k = 0 (code 0), 1 (code 1), else texture(mask_atlas, (blk·S + t − cell·S + 0.5) / atlas_size).r
          blk = the block coordinates of slot code − 2                     LINEAR, 1 fetch per read
    the reads (offset, at the point) blended by compress.lookup_blend over all K channels

so a pixel costs 2·G indirection fetches plus 1 atlas fetch per read and per channel whose code is ≥ 2 (2 reads:
the offset one and the one at the point). The own-cell rule makes the trilinear footprint stay in the cell's S³
samples, i.e. in its block: the atlas read equals the dense volume's read (:func:`decompress_channels`) up to
float32 rounding of the coordinate.

Consumers: stages/compress (writer); point_modes (decompress), samplers via the dense volumes; proto/glsl/gi_mask.glsl
and web/src/state/modes.js (readers).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from workers.kernels.compress import (MAX_TEXELS, PREFERRED_TEXELS, atlas_layout, cells_of, lookup_blend,
                                      mask_lookups, texture_linear)

__all__ = ["ChannelAtlas", "compress_channels", "decompress_channels", "codes_of", "sample_channel_atlas",
           "CODE_ZERO", "CODE_ONE", "FIRST_SLOT"]

CODE_ZERO = 0   # the channel is 0 in the whole cell
CODE_ONE = 1    # 255 in the whole cell
FIRST_SLOT = 2  # codes >= 2 are atlas slot code - 2
MAX_CODE = 65535


@dataclass
class ChannelAtlas:
    atlas: np.ndarray          # (bz·S, by·S, bx·S, 1) uint8: R8 channel blocks
    indirection: np.ndarray    # (2·G·cz, cy, cx, 4) uint8: low / high bytes of the codes
    codes: np.ndarray          # (cz, cy, cx, K) int64
    meta: dict
    stats: dict = field(default_factory=dict)


def _channel_blocks(volumes, S: int, cells, K: int) -> np.ndarray:
    """(cz, cy, cx, K, S³) uint8 — each cell's S³ samples of each channel k < K (x fastest in a block)."""
    v = np.concatenate([np.asarray(x) for x in volumes], axis=3)[..., :K]
    cx, cy, cz = (int(c) for c in cells)
    b = v.reshape(cz, S, cy, S, cx, S, K).transpose(0, 2, 4, 6, 1, 3, 5)
    return np.ascontiguousarray(b).reshape(cz, cy, cx, K, S ** 3)


@numba.njit(cache=True, nogil=True)
def _merge(blocks, S, order, thr):  # pragma: no cover - compiled
    """Greedy clustering of the module doc (``(rep_of, err, reps)``: each block's representative, its max byte
    difference, the representatives in the order they were made). Exact and in the greedy order; candidates are
    found through buckets of the block's three half sums (samples with x < S/2, y < S/2, z < S/2), which differ by
    at most thr·S³/2 between blocks within thr, so only the 27 neighbouring buckets can hold a match."""
    U, B = blocks.shape
    h = S // 2
    half = max(B // 2, 1)
    width = max(thr * half + 1, (255 * half) // 24 + 1)
    nb = (255 * half) // width + 1
    key = np.zeros((U, 3), np.int64)
    for u in range(U):
        for c in range(S):
            for b in range(S):
                for a in range(S):
                    v = np.int64(blocks[u, (c * S + b) * S + a])
                    if a < h:
                        key[u, 0] += v
                    if b < h:
                        key[u, 1] += v
                    if c < h:
                        key[u, 2] += v
    head = np.full(nb * nb * nb, -1, np.int64)
    tail = np.full(nb * nb * nb, -1, np.int64)
    nxt = np.full(U, -1, np.int64)
    rank = np.full(U, -1, np.int64)
    rep_of = np.empty(U, np.int64)
    err = np.zeros(U, np.int64)
    reps = np.empty(U, np.int64)
    nrep = 0
    for oi in range(U):
        u = order[oi]
        bx, by, bz = key[u, 0] // width, key[u, 1] // width, key[u, 2] // width
        best, best_rank, best_err = -1, U, 0
        for dz in range(-1, 2):
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    x, y, z = bx + dx, by + dy, bz + dz
                    if x < 0 or y < 0 or z < 0 or x >= nb or y >= nb or z >= nb:
                        continue
                    r = head[(z * nb + y) * nb + x]
                    while r >= 0 and rank[r] < best_rank:      # each bucket lists its reps in the order made
                        if abs(key[u, 0] - key[r, 0]) <= thr * half and abs(key[u, 1] - key[r, 1]) <= thr * half \
                                and abs(key[u, 2] - key[r, 2]) <= thr * half:
                            m = 0
                            for b in range(B):
                                d = abs(np.int64(blocks[u, b]) - np.int64(blocks[r, b]))
                                if d > 0 and (blocks[u, b] == 0 or blocks[r, b] == 0):
                                    m = thr + 1          # a 0 (a hidden cluster) stays 0, a seen one stays seen
                                    break
                                if d > m:
                                    m = d
                                    if m > thr:
                                        break
                            if m <= thr:
                                best, best_rank, best_err = r, rank[r], m
                                break
                        r = nxt[r]
        if best < 0:
            cell = (bz * nb + by) * nb + bx
            if head[cell] < 0:
                head[cell] = u
            else:
                nxt[tail[cell]] = u
            tail[cell] = u
            rank[u] = nrep
            reps[nrep] = u
            nrep += 1
            rep_of[u] = u
        else:
            rep_of[u] = best
            err[u] = best_err
    return rep_of, err, reps[:nrep]


def compress_channels(volumes, counts, S: int, clusters: int, tolerance: float = 0.0,
                      preferred: int = PREFERRED_TEXELS, limit: int = MAX_TEXELS) -> ChannelAtlas:
    """Compress the RGBA8 mask volumes (``masks_0123`` [, ``masks_4567``]) of ``clusters`` = K masks into one R8
    channel-block atlas + the code indirection (module doc). ``tolerance`` in mask units (0 = lossless).

    ``stats``: ``channel_blocks`` (cells·K), ``constant_zero`` / ``constant_one`` (code 0 / 1), ``unique_blocks``
    (distinct others), ``atlas_blocks`` (after merging), ``max_block_error`` (mask units), ``dense_bytes`` (the
    RGBA8 volumes), ``atlas_bytes``, ``indirection_bytes``, ``compressed_bytes``, ``ratio``.
    """
    if isinstance(volumes, np.ndarray):
        volumes = [volumes]
    volumes = [np.asarray(v) for v in volumes]
    S, K = int(S), int(clusters)
    if not 1 <= K <= 4 * len(volumes) or K > 8:
        raise ValueError(f"{K} clusters need {max(1, -(-K // 4))} mask volumes, got {len(volumes)}")
    cells = cells_of(counts)
    want = (int(cells[2]) * S, int(cells[1]) * S, int(cells[0]) * S, 4)
    for v in volumes:
        if v.dtype != np.uint8 or v.shape != want:
            raise ValueError(f"mask volume must be uint8 {want} for counts {list(counts)} and S = {S}, got "
                             f"{v.dtype} {v.shape}")
    if not 0.0 <= float(tolerance) <= 1.0:
        raise ValueError(f"tolerance must be in [0, 1], got {tolerance}")
    thr = int(math.floor(float(tolerance) * 255.0 + 1e-9))
    blocks = _channel_blocks(volumes, S, cells, K)
    shape = blocks.shape[:4]
    flat = blocks.reshape(-1, S ** 3)
    zero = flat.max(axis=1) <= thr                         # MD §3.4.2, ours: constant blocks need no storage
    one = ~zero & (flat.min(axis=1) >= 255 - thr)
    rest = np.flatnonzero(~zero & ~one)
    codes = np.where(one, CODE_ONE, CODE_ZERO).astype(np.int64)
    err_all = np.where(zero, flat.max(axis=1), np.where(one, 255 - flat.min(axis=1), 0)).astype(np.int64)
    if rest.size:
        uniq, first, inv, cnt = np.unique(flat[rest], axis=0, return_index=True, return_inverse=True,
                                          return_counts=True)
        inv = inv.reshape(-1)
        order = np.lexsort((first, -cnt))                 # most used first, then first appearance
        if thr > 0 and len(uniq) > 1:
            rep_of, err, reps = _merge(uniq, S, order, thr)
        else:
            rep_of, err, reps = np.arange(len(uniq)), np.zeros(len(uniq), np.int64), order
        slot_of_rep = np.full(len(uniq), -1, np.int64)
        slot_of_rep[reps] = np.arange(len(reps))
        codes[rest] = FIRST_SLOT + slot_of_rep[rep_of[inv]]
        err_all[rest] = err[inv]
        stored = uniq[reps]
        n_unique = len(uniq)
    else:
        stored = np.zeros((1, S ** 3), np.uint8)
        n_unique = 0
    n_slots = max(len(stored), 1)
    if FIRST_SLOT + n_slots - 1 > MAX_CODE:
        raise ValueError(f"{n_slots} mask blocks do not fit 16-bit codes")
    bx, by, bz = atlas_layout(n_slots, S, preferred, limit)
    grid = np.zeros((bx * by * bz, S, S, S), np.uint8)
    grid[:len(stored)] = stored.reshape(-1, S, S, S)
    atlas = np.ascontiguousarray(grid.reshape(bz, by, bx, S, S, S).transpose(0, 3, 1, 4, 2, 5)
                                 .reshape(bz * S, by * S, bx * S, 1))
    codes = codes.reshape(shape)
    G = -(-K // 4)
    cz, cy, cx = shape[:3]
    padded = np.zeros((cz, cy, cx, 4 * G), np.int64)
    padded[..., :K] = codes
    ind = np.zeros((2 * G * cz, cy, cx, 4), np.uint8)     # MD §3.4.2: one indirection volume indexes the cubes
    for g in range(G):
        part = padded[..., 4 * g:4 * g + 4]
        ind[2 * g * cz:(2 * g + 1) * cz] = part & 255
        ind[(2 * g + 1) * cz:(2 * g + 2) * cz] = part >> 8
    dense_bytes = int(sum(v.nbytes for v in volumes))
    comp = int(atlas.nbytes + ind.nbytes)
    meta = {
        "layout": "channel", "samples_per_cell": S, "block_size": S, "border_lo": 0, "border_hi": 0,
        "clusters": K, "groups": G, "cells": [int(c) for c in cells], "block_grid": [bx, by, bz],
        "atlas_size": [bx * S, by * S, bz * S], "atlas_blocks": int(n_slots),
        "codes": "code of (cell, channel k) = lo + 256·hi, lo = indirection texel (i, j, 2g·cz + k) channel k % 4, "
                 "hi = texel (i, j, (2g + 1)·cz + k), g = k // 4: 0 → m_k = 0, 1 → m_k = 1, c ≥ 2 → atlas slot c − 2 "
                 "at block (s % bx, (s // bx) % by, s // (bx·by))",
        "sample": "t = the texel coordinate of a read, clamped to the cell's S³ samples; uvw = (block·S + t − cell·S "
                  "+ 0.5) / atlas_size; texture(mask_atlas, uvw).r, LINEAR",
    }
    stats = {
        "layout": "channel", "cells": int(cz * cy * cx), "clusters": K, "channel_blocks": int(flat.shape[0]),
        "constant_zero": int((codes == CODE_ZERO).sum()), "constant_one": int((codes == CODE_ONE).sum()),
        "unique_blocks": int(n_unique), "atlas_blocks": int(len(stored) if rest.size else 0),
        "block_size": S, "border_lo": 0, "border_hi": 0, "block_grid": [bx, by, bz],
        "atlas_size": [bx * S, by * S, bz * S],
        "fits_256": bool(max(bx, by, bz) * S <= 256), "tolerance": float(tolerance),
        "max_block_error": float(err_all.max() / 255.0) if err_all.size else 0.0,
        "dense_bytes": dense_bytes, "atlas_bytes": int(atlas.nbytes), "indirection_bytes": int(ind.nbytes),
        "compressed_bytes": comp, "ratio": dense_bytes / comp,
    }
    return ChannelAtlas(atlas, ind, codes, meta, stats)


def codes_of(indirection: np.ndarray, clusters: int) -> np.ndarray:
    """(cz, cy, cx, K) int64 codes from an indirection (2·G·cz, cy, cx, 4) (module doc)."""
    ind = np.asarray(indirection).astype(np.int64)
    K = int(clusters)
    G = -(-K // 4)
    cz = ind.shape[0] // (2 * G)
    parts = [ind[2 * g * cz:(2 * g + 1) * cz] + 256 * ind[(2 * g + 1) * cz:(2 * g + 2) * cz] for g in range(G)]
    return np.concatenate(parts, axis=3)[..., :K]


def _slot_coords(slot: np.ndarray, atlas_shape, S: int) -> np.ndarray:
    """(..., 3) block coordinates (x, y, z) of atlas slots."""
    bx, by = atlas_shape[2] // S, atlas_shape[1] // S
    return np.stack([slot % bx, (slot // bx) % by, slot // (bx * by)], axis=-1)


def decompress_channels(atlas: np.ndarray, indirection: np.ndarray, meta: dict) -> list[np.ndarray]:
    """The dense RGBA8 volumes (``masks_0123`` [, ``masks_4567``]) an atlas + indirection stand for (module doc)."""
    S, K = int(meta["samples_per_cell"]), int(meta["clusters"])
    codes = codes_of(indirection, K)
    cz, cy, cx = codes.shape[:3]
    G = -(-K // 4)
    blocks = np.zeros((cz, cy, cx, 4 * G, S, S, S), np.uint8)
    blocks[..., :K, :, :, :][codes == CODE_ONE] = 255
    sel = codes >= FIRST_SLOT
    if sel.any():
        xyz = _slot_coords(codes[sel] - FIRST_SLOT, atlas.shape, S) * S
        a = np.asarray(atlas).reshape(np.shape(atlas)[:3])
        ar = np.arange(S)
        # MD §3.4.2 undone: each (cell, channel)'s cube through the indirection
        blocks[..., :K, :, :, :][sel] = a[xyz[:, 2, None, None, None] + ar[None, :, None, None],
                                          xyz[:, 1, None, None, None] + ar[None, None, :, None],
                                          xyz[:, 0, None, None, None] + ar[None, None, None, :]]
    dense = blocks.transpose(0, 4, 1, 5, 2, 6, 3).reshape(cz * S, cy * S, cx * S, 4 * G)
    return [np.ascontiguousarray(dense[..., 4 * g:4 * g + 4]) for g in range(G)]


def sample_channel_atlas(atlas: np.ndarray, indirection: np.ndarray, meta: dict, points, counts, origin, spacing,
                         dtype=np.float32, *, dirs=None, samples: float = 0.0, blend: bool = True, layers=None):
    """(N, K) masks at world points read as the GLSL reads the channel atlas (module doc, "Sampling"): per read and
    channel the constant of codes 0 / 1 or one LINEAR atlas fetch, the reads blended by ``lookup_blend`` over the K
    channels (``blend=False``: the list of reads, offset read first). Coordinate math in ``dtype`` (float32 = GLSL
    highp). Values in [0, 1], float64."""
    S, K = int(meta["samples_per_cell"]), int(meta["clusters"])
    ts, cell = mask_lookups(points, counts, origin, spacing, S, dirs, samples, dtype, layers)
    ci = cell.astype(np.int64)
    codes = codes_of(indirection, K)[ci[:, 2], ci[:, 1], ci[:, 0]]               # (N, K): 2·G texelFetch
    tex = np.asarray(atlas).reshape(np.shape(atlas)[:3] + (1,))
    size = np.array(tex.shape[2::-1], np.float64).astype(dtype)
    f_s = dtype(S)
    reads = []
    for t in ts:
        local = t - cell * f_s + dtype(0.5)
        out = (codes == CODE_ONE).astype(np.float64)
        for k in range(K):
            sel = np.flatnonzero(codes[:, k] >= FIRST_SLOT)
            if sel.size:
                blk = _slot_coords(codes[sel, k] - FIRST_SLOT, tex.shape, S).astype(dtype)
                out[sel, k] = texture_linear(tex, (blk * f_s + local[sel]) / size)[:, 0]
        reads.append(out)
    return lookup_blend(reads) if blend else reads
