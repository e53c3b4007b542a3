"""Per-probe depth moments: the octahedral mean distance and mean squared distance (DDGI-I §3.5 eq 2,
DDGI-P §4.1; numpy only).

Per probe an octahedral ``n``² map of the weighted mean of the ray distance l and l², weight
``max(0, cos)^sharpness`` between the ray and the texel direction (DDGI-I eq 2 and its power-cosine
weighting of distances); back-face hits shortened by 80% (DDGI-P §4.1), misses at ``max_distance``; plus the
1-texel border (:func:`workers.kernels.octahedral.add_border`). The runtime's Chebyshev visibility test
(:mod:`workers.kernels.ddgi`) reads them. Consumer: stage ``trace``. Inverse: none.
"""
from __future__ import annotations

import numpy as np

from workers.kernels.octahedral import accumulate_octahedral, add_border, oct_texel_directions

__all__ = ["BACKFACE_SHORTEN", "depth_moments", "max_ray_distance"]

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
    directions; n : texels per side (without border); sharpness : the cosine exponent; max_distance : metres.
    """
    d = np.where(np.isfinite(t), t, max_distance)                             # misses at max_distance
    d = np.minimum(np.where(back, d * BACKFACE_SHORTEN, d), max_distance)     # DDGI-P §4.1: back faces −80%
    values = np.stack([d, d * d], axis=-1).astype(np.float32)               # DDGI-I eq 2: l and l²
    maps = accumulate_octahedral(dirs, values, oct_texel_directions(n), sharpness)
    return add_border(maps).astype(np.float32)
