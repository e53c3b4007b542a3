"""One iteration of the probe position optimizer (DDGI-P §5, Fig 7), for all probes at once (numpy only).

Per probe, from one spherical ray cast (:func:`workers.raycast.probes.trace_probes`):

- more than ``backface_fraction`` of the rays hit back faces → the probe is inside something: move along the
  direction of the closest back face as far as the offset limit allows (Fig 7's per-axis scale solve, minus
  1 mm), or not at all if that cannot get through it;
- else, if the closest front face is nearer than ``0.1 × min spacing`` (RTXGI's
  ``probeMinFrontfaceDistance`` test), step ``min(0.2 × min spacing, farthest front-face distance)`` toward
  the farthest front face, unless that direction is within 60° of the closest front face. (Fig 7 uses 0.2
  scene units; we scale it with the grid so it means the same at any scene scale.)

A new offset is kept only when it stays within the limit on every axis (RTXGI). Consumer: stage
``relocate`` (5 iterations, DDGI-P §5: "runs for 5 iterations"). Inverse: none.
"""
from __future__ import annotations

import numpy as np

__all__ = ["relocation_step"]


def relocation_step(offsets: np.ndarray, t: np.ndarray, back: np.ndarray, dirs: np.ndarray,
                    limit: np.ndarray, min_spacing: float, backface_fraction: float) -> np.ndarray:
    """One iteration of DDGI-P Fig 7 for all probes (vectorized). Returns the new offsets (P, 3) float64.

    Parameters
    ----------
    offsets : (P, 3) float
        Current offsets from the grid positions, world space, metres.
    t : (P, R) float
        Hit distances of this iteration's rays, metres (inf = miss).
    back : (P, R) bool
        The ray hit the back of a single-sided triangle.
    dirs : (R, 3) float
        This iteration's unit ray directions (the same for every probe).
    limit : (3,) float
        Per-axis offset limit, metres (``trace.max_offset × spacing``).
    min_spacing : float
        Smallest positive grid spacing, metres.
    backface_fraction : float
        Fraction of back-face hits above which a probe is inside geometry (Fig 7: 0.25).
    """
    P, R = t.shape
    full = offsets.copy()
    n_back = back.sum(axis=1)
    inside = n_back / R > backface_fraction                                  # Fig 7: backfaceCount / RAYS > 0.25
    # --- inside: move through the closest back face (Fig 7, first branch)
    if inside.any():
        tb = np.where(back, t, np.inf)[inside]
        ib = np.argmin(tb, axis=1)
        # closestBackfaceDirection: the ray direction scaled by the back face's distance, so that a
        # scale factor <= 1 means the offset limit does not reach past the back face (Fig 7)
        d = dirs[ib].astype(np.float64) * tb[np.arange(ib.size), ib][:, None]
        cur = offsets[inside]
        with np.errstate(divide="ignore", invalid="ignore"):
            pos = (-cur + limit) / d                                           # Fig 7: positiveOffset
            neg = (-cur - limit) / d                                           # Fig 7: negativeOffset
        combined = np.where(np.isnan(pos), np.inf, np.maximum(pos, neg))       # Fig 7: combinedOffset (per-axis max)
        scale = combined.min(axis=1) - 1e-3                                    # Fig 7: scaleFactor, epsilon 1 mm
        scale = np.where((scale <= 1.0) | ~np.isfinite(scale), 0.0, scale)     # Fig 7: cannot get through: stay
        full[inside] = cur + d * scale[:, None]
    # --- outside, too close to a front face: step toward the farthest front face (Fig 7, second branch)
    out = ~inside
    if out.any():
        tf = np.where(back, np.nan, t)[out]                                    # front faces and misses
        tf_close = np.where(np.isnan(tf), np.inf, tf)
        tf_far = np.where(np.isnan(tf), -np.inf, tf)
        closest = tf_close.min(axis=1)
        i_close = np.argmin(tf_close, axis=1)
        i_far = np.argmax(tf_far, axis=1)
        far_dist = tf_far.max(axis=1)
        move = closest < 0.1 * min_spacing                                     # RTXGI probeMinFrontfaceDistance
        d_close, d_far = dirs[i_close].astype(np.float64), dirs[i_far].astype(np.float64)
        move &= np.einsum("ij,ij->i", d_far, d_close) <= 0.5                  # Fig 7: !(dot(farthest, closest) > 0.5)
        step = np.minimum(0.2 * min_spacing, np.where(np.isfinite(far_dist), far_dist, np.inf))  # Fig 7: min(0.2, d)
        idx = np.flatnonzero(out)[move]
        full[idx] = offsets[idx] + d_far[move] * step[move][:, None]
    # keep a new offset only within the limit on every axis (RTXGI)
    ok = np.all(np.abs(full) <= limit + 1e-9, axis=1)
    return np.where(ok[:, None], full, offsets)
