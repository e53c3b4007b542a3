"""More probe rays where a probe's few rays see a small bright thing (the light stage's adaptive rays).

A probe in a dark room sees the lit room through a door with a handful of its R rays; each of them carries radiance a
hundred times the dark room's, so the probe's irradiance is a few large samples: its Monte Carlo error is large
(sun-window: ±7% on the dark room's mean between two rotations of the rays at R = 256, under 2% at R = 1024), while
probes that see only broad, even light are right with R. The first-bounce radiance of the cached rays (emission
plus albedo/π · E_direct at the hits, the sky at misses; DDGI-I §3.4) shows which probes those are before any
bounce: per probe the relative standard error of its mean first-bounce luminance,

    q_p = std_r(L_pr) / (mean_r(L_pr) · √R)        (0 where the probe sees no direct light),

pooled over the probe's 3×3×3 neighbourhood (so that whether a probe gets more rays hardly depends on its own rays:
a choice made on the same samples would favour the probes whose rays happened to catch the bright thing, and bias
them). Extra sets of R rays go to the probes in proportion to the pooled q̄ (the allocation that minimises the
summed variance ``Σ q̄²/n`` for a given number of rays), at most ``max_sets`` per probe, ``budget`` × the live
probes' count of sets in all. Each extra set is the pattern under another rotation; the probe's irradiance is the
mean of its sets' estimates (:func:`merge_rows`).

Consumers: stages/light. Kernels only (no I/O).
"""
from __future__ import annotations

import numpy as np

from workers.kernels.grid import OFF

__all__ = ["first_bounce_noise", "pooled", "allocate_sets", "extra_rows", "extra_patterns", "merge_rows"]

_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def first_bounce_noise(index, miss, base, sky, rays: int) -> np.ndarray:
    """(P,) float64 q_p (module doc): the relative standard error of each probe's mean first-bounce luminance.

    ``index`` (H,) flat ray indices (p·R + r) of the front-face hits; ``miss`` (P, R) bool; ``base`` (H, 3) the hits'
    first-bounce radiance (emission + albedo/π · E_direct, linear RGB); ``sky`` (3,) or None, the misses' radiance;
    ``rays``: R. Back-face hits carry 0."""
    P = miss.shape[0]
    lum = np.zeros(P * rays, np.float64)
    lum[np.asarray(index, np.int64)] = np.asarray(base, np.float32) @ _LUMA
    if sky is not None:
        lum[np.asarray(miss).ravel()] = float(np.asarray(sky, np.float32) @ _LUMA)
    lum = lum.reshape(P, rays)
    mean = lum.mean(axis=1)
    std = lum.std(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(mean > 0, std / (mean * np.sqrt(rays)), 0.0)
    return q


def pooled(q, counts) -> np.ndarray:
    """(P,) the mean of ``q`` (P,) over each probe's 3×3×3 grid neighbourhood (clipped at the grid's faces); grid
    ``counts`` (nx, ny, nz), probes in flattened C order from (nz, ny, nx)."""
    nx, ny, nz = (int(c) for c in counts)
    v = np.asarray(q, np.float64).reshape(nz, ny, nx)
    total = np.zeros_like(v)
    n = np.zeros_like(v)
    pad = np.pad(v, 1)
    ones = np.pad(np.ones_like(v), 1)
    for dz in range(3):
        for dy in range(3):
            for dx in range(3):
                total += pad[dz:dz + nz, dy:dy + ny, dx:dx + nx]
                n += ones[dz:dz + nz, dy:dy + ny, dx:dx + nx]
    return (total / n).ravel()


def allocate_sets(q, states, budget: float, max_sets: int) -> np.ndarray:
    """(P,) int64 extra ray sets per probe: ``min(max_sets, floor(c · q_p))`` with the largest c that keeps the total
    within ``budget`` × the number of live (not OFF) probes; OFF probes and q = 0 get none."""
    q = np.where(np.asarray(states) == OFF, 0.0, np.asarray(q, np.float64))
    limit = int(np.floor(float(budget) * int((np.asarray(states) != OFF).sum())))
    if limit <= 0 or max_sets <= 0 or not (q > 0).any():
        return np.zeros(q.shape, np.int64)

    def sets(c: float) -> np.ndarray:
        return np.minimum(np.floor(c * q), max_sets).astype(np.int64)

    full = np.where(q > 0, int(max_sets), 0).astype(np.int64)
    if full.sum() <= limit:                                  # every probe with q > 0 at max_sets fits
        return full
    lo, hi = 0.0, 1.0
    while sets(hi).sum() <= limit:
        hi *= 2.0
    for _ in range(60):                                      # bisection on c
        mid = 0.5 * (lo + hi)
        if sets(mid).sum() <= limit:
            lo = mid
        else:
            hi = mid
    return sets(lo)


def extra_rows(sets) -> np.ndarray:
    """(E,) int64 the parent probe of each extra row: probe p repeated ``sets[p]`` times, probes ascending."""
    s = np.asarray(sets, np.int64)
    return np.repeat(np.arange(s.size, dtype=np.int64), s)


def extra_patterns(parents, k: int) -> np.ndarray:
    """(E,) int64 the rotated pattern (of ``k``) of each extra row of :func:`extra_rows` ``parents`` (E,): set j of
    probe p casts pattern ``(hash(p) + j) mod k``, so a probe's sets differ from each other and from its neighbours',
    and depend on the probe and the set alone. Numbered down the rows instead (row i: ``i mod k``), one probe more or
    less anywhere before it shifted the rays of every probe after it: apartments turned 30° in its file (the same grid
    to 1e-6 in the bake frame; 3,160 probes given extra sets instead of 3,174, through float rounding) baked as another
    seed would, its dark room 4-5% lower (bench_fidelity, 2026-12-06)."""
    parents = np.asarray(parents, np.int64)
    if parents.size == 0:
        return np.zeros(0, np.int64)
    starts = np.r_[0, np.flatnonzero(np.diff(parents) != 0) + 1]
    run = np.repeat(starts, np.diff(np.r_[starts, parents.size]))
    j = np.arange(parents.size, dtype=np.int64) - run            # the set's number within its probe
    h = (parents.astype(np.uint64) * np.uint64(2654435761)) >> np.uint64(7)
    return ((h % np.uint64(max(int(k), 1))).astype(np.int64) + j) % max(int(k), 1)


def merge_rows(values, parents) -> np.ndarray:
    """Per probe the mean of its rows: ``values`` (P + E, ...) (the probes' own rows, then the extra rows of
    ``parents`` (E,) int); returns (P, ...) of ``values``' dtype (``values[:P]`` where there are no extra rows)."""
    v = np.asarray(values)
    parents = np.asarray(parents, np.int64)
    P = v.shape[0] - parents.size
    if parents.size == 0:
        return v
    extra = v[P:]
    if np.any(parents[1:] < parents[:-1]):                  # extra_rows gives them sorted
        order = np.argsort(parents, kind="stable")
        parents, extra = parents[order], extra[order]
    heads, starts, n = np.unique(parents, return_index=True, return_counts=True)
    out = v[:P].copy()
    out[heads] = (out[heads] + np.add.reduceat(extra, starts, axis=0)) / (1 + n).reshape((-1,) + (1,) * (v.ndim - 1))
    return out
