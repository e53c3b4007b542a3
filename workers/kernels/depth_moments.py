"""Per-probe depth moments: the octahedral mean distance and mean squared distance (DDGI-I §3.5 eq 2,
DDGI-P §4.1; numpy only).

Per probe an octahedral ``n``² map of the weighted mean of the ray distance l and l², weight
``max(0, cos)^sharpness`` between the ray and the texel direction (DDGI-I eq 2 and its power-cosine
weighting of distances); back-face hits shortened by 80% (DDGI-P §4.1), misses at ``max_distance``; plus the
1-texel border (:func:`workers.kernels.octahedral.add_border`). The runtime's Chebyshev visibility test
(:mod:`workers.kernels.ddgi`) reads them. Consumer: stage ``trace``. Inverse: none.

**Far clamp** (:func:`clamp_far`, issue 17: what the stored ``depth_moments`` artifact holds). The runtime reads a
probe's moments only for shading points whose biased position x_b = x + (0.2·n + 0.8·ω_o)·bias (DDGI-P eq 2) has
that probe in its cage, i.e. lies in one of the probe's adjacent cells (the cells of the un-relocated grid with it
as a corner; points outside the grid box clamp to the border cells, so there the cells reach out to the scene
bounds), and compares the bilinearly read mean μ with r = |x_b − p|. :func:`reach` bounds r per probe: the largest
distance from the relocated probe to a corner of that region, grown by ``bias`` on every side. Every texel whose
mean is at least that reach R_p is stored as (R_p, R_p²). A texel read alone (all four bilinear taps clamped)
gives μ' = R_p ≥ r, the unoccluded branch (weight 1), as the original μ ≥ R_p ≥ r did: identical. Where a clamped
texel and an unclamped one share a bilinear footprint (the silhouette of a near surface against far ones) the
read mean is lower than before and the Chebyshev weight can change; ``tests/bench/bench_formats.py`` measures
what that does to the GI (proto/bundle.md 5.1). Long rays make most texels far, so the maps turn mostly constant
and Zstandard stores them in about half the bytes. The light and PRT stages integrate with the unclamped float32
moments (``depth_moments_full``).
"""
from __future__ import annotations

import numpy as np

from workers.kernels.octahedral import accumulate_octahedral, add_border, oct_texel_directions
from workers.kernels.sampling import probe_rays

__all__ = ["BACKFACE_SHORTEN", "depth_moments", "max_ray_distance", "reach", "clamp_far"]

BACKFACE_SHORTEN = 0.2
"""Back-face hit distances are multiplied by this (shortened by 80%, DDGI-P §4.1)."""


def max_ray_distance(bounds, counts, origin, spacing) -> float:
    """Diagonal of the scene bounds joined with the grid box, metres (at least 1 mm): the distance recorded
    for misses.

    bounds : (2, 3) world-space box (min, max), metres; counts : (3,) probes per axis; origin, spacing : (3,)
    metres (the grid box is ``origin … origin + spacing·(counts − 1)``).
    """
    lo = np.minimum(np.asarray(bounds[0]), np.asarray(origin))
    hi = np.maximum(np.asarray(bounds[1]), np.asarray(origin) + np.asarray(spacing) * (np.asarray(counts) - 1))
    return float(max(np.linalg.norm(hi - lo), 1e-3))


def depth_moments(t: np.ndarray, back: np.ndarray, dirs: np.ndarray, n: int, sharpness: float,
                  max_distance: float) -> np.ndarray:
    """(P, n+2, n+2, 2) float32 mean distance and mean squared distance per octahedral texel, with border.

    t : (P, R) hit distances, metres (inf = miss); back : (P, R) bool back-face hits; dirs : (R, 3) unit ray
    directions or each probe's (:class:`workers.kernels.sampling.ProbeRays`); n : texels per side (without border); sharpness : the cosine exponent; max_distance : metres.
    """
    d = np.where(np.isfinite(t), t, max_distance)                             # misses at max_distance
    d = np.minimum(np.where(back, d * BACKFACE_SHORTEN, d), max_distance)     # DDGI-P §4.1: back faces −80%
    values = np.stack([d, d * d], axis=-1).astype(np.float32)               # DDGI-I eq 2: l and l²
    texels = oct_texel_directions(n)
    maps = probe_rays(dirs, t.shape[0]).per_pattern(              # each probe's own pattern
        lambda d, v: accumulate_octahedral(d, v, texels, sharpness), values)
    return add_border(maps).astype(np.float32)


def reach(positions, counts, origin, spacing, bias: float, bounds, layers=None) -> np.ndarray:
    """(P,) float64 metres: per probe the largest distance from it to any biased shading point whose cage holds it
    (module doc "Far clamp").

    positions : (P, 3) relocated probe positions (flattened grid order, :mod:`workers.kernels.grid`); counts,
    origin, spacing : the grid; bias : the runtime's self-shadow bias, metres (``ddgi.bias_scale``), the most a
    shading point moves; bounds : (2, 3) scene bounds, metres (points outside the grid box clamp to its border
    cells: the region of a border probe reaches the bounds); layers : a rectilinear grid's (:mod:`workers.kernels.grid`).

    Probe index i on an axis is a corner of the cells with base i − 1 and i within [0, n − 2]; the cell with base 0
    also takes every point below the grid, the one with base n − 2 every point above it.
    """
    from workers.kernels.grid import layers_of, probe_grid_indices

    counts = np.asarray(counts, np.int64)
    origin = np.asarray(origin, np.float64)
    spacing = np.asarray(spacing, np.float64)
    bounds = np.asarray(bounds, np.float64)
    ijk = probe_grid_indices(counts)
    ls = layers_of(counts, origin, spacing, layers)

    def at(idx):                                     # (P, 3) layer coordinates at clipped indices
        return np.stack([ls[a][np.clip(idx[:, a], 0, counts[a] - 1)] for a in range(3)], axis=1)

    first, top = at(np.zeros_like(ijk)), at(np.broadcast_to(counts - 1, ijk.shape))
    lo = np.where(ijk <= 1, np.minimum(first, bounds[0]), at(ijk - 1)) - bias
    hi = np.where(ijk >= counts - 2, np.maximum(top, bounds[1]), at(ijk + 1)) + bias
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    far = np.maximum(np.abs(p - lo), np.abs(p - hi))
    return np.sqrt((far * far).sum(axis=1))


def clamp_far(maps: np.ndarray, limit) -> tuple[np.ndarray, float]:
    """Depth moments with every texel whose 3×3 neighbourhood (in its bordered tile, at each place the texel
    appears) has means ≥ its probe's ``limit`` stored as (limit, limit²) (module doc "Far clamp").

    maps : (P, m+2, m+2, 2) float32 (mean, mean square) with the 1-texel octahedral border (:func:`add_border`'s
    copies); limit : (P,) metres (:func:`reach`), rounded up to a half float (so that storing the result in half
    floats keeps every stored mean ≥ the reach). Returns the clamped copy (float32, its border again the copies of
    its interior, so it can be stored without it: :mod:`proto.atlas`) and the share of texels clamped.

    Why the neighbourhood: a bilinear read mixes a 2×2 footprint of the bordered tile. A footprint holding a clamped
    texel lies in that texel's 3×3 window, so all four of its texels had means ≥ limit ≥ r and still read
    ≥ limit: the read mean is ≥ r before and after, the Chebyshev weight 1 in both. A footprint without one reads
    what it read. An interior texel also appears as border texels (mirrored copies), each with a window of its own:
    it is clamped only when every one of those windows qualifies, so the border stays a copy of the interior.
    """
    a = np.array(maps, np.float32)
    lim = np.asarray(limit, np.float64).reshape(-1, 1, 1)
    h = lim.astype(np.float16)
    h = np.where(h.astype(np.float64) < lim, np.nextafter(h, np.float16(np.inf)), h)
    lim = h.astype(np.float32)
    mean = a[..., 0]
    t = mean.shape[1]
    pad = np.pad(mean, ((0, 0), (1, 1), (1, 1)), constant_values=np.inf)
    low = pad[:, 0:t, 0:t]
    for dy in range(3):
        for dx in range(3):
            low = np.minimum(low, pad[:, dy:dy + t, dx:dx + t])
    ok = low >= lim                                                  # (P, m+2, m+2): this place's window qualifies
    far = ok[:, 1:-1, 1:-1].copy()                                   # interior texels, AND over their border copies
    far[:, 0, :] &= ok[:, 0, 1:-1][:, ::-1]                          # top border row: first row, columns flipped
    far[:, -1, :] &= ok[:, -1, 1:-1][:, ::-1]
    far[:, :, 0] &= ok[:, 1:-1, 0][:, ::-1]                          # left border column: first column, rows flipped
    far[:, :, -1] &= ok[:, 1:-1, -1][:, ::-1]
    far[:, -1, -1] &= ok[:, 0, 0]                                    # corners: the opposite interior corner
    far[:, -1, 0] &= ok[:, 0, -1]
    far[:, 0, -1] &= ok[:, -1, 0]
    far[:, 0, 0] &= ok[:, -1, -1]
    inner = a[:, 1:-1, 1:-1]
    lim_b = np.broadcast_to(lim, far.shape)
    inner[..., 0] = np.where(far, lim_b, inner[..., 0])
    inner[..., 1] = np.where(far, lim_b * lim_b, inner[..., 1])
    return add_border(inner), float(far.mean()) if far.size else 0.0
