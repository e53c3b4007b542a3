"""One iteration of the probe position optimizer (DDGI-P §5, Fig 7), for all probes at once (numpy; the rescue's
candidate selection in numba).

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

**Settled probes** (:func:`settled`): the iterations after the first trace only the probes that can still move. A
probe that did not move is left alone from then on when its rays leave no doubt that no rotation of the pattern
will move it: outside (no back face at all) with its nearest front face more than ``SETTLE_FRONT`` × the move
threshold away, or inside with its nearest back face more than ``SETTLE_BACK`` × the farthest the limit lets it
go (its exit lies beyond the limit). 256 rays are 12.6° apart, so a wall that near is hit; a surface small enough
to slip between them could still be found by a later rotation, which the stage gives up. On zdm2-sauerbraten
(20,387 probes) the iterations cast 10.6 M rays instead of 26.1 M and every offset is the same; so on the default grids
of godot-living-room, truck-town, both real Cornell boxes and five procedural scenes (21-47% of the probe traces).

**Rescue** (:func:`rescue`, after the iterations; not in the paper): DDGI-P §6.1 turns off the probes the grid
constrains too much to leave a wall ("some probes are too constrained by the grid structure"). With the RTXGI
limit of 0.45 spacing that is every probe deeper than 0.45 spacing in a solid — on a budget-bound grid in a
cube-brush level (zdm2-sauerbraten: 2.19 m spacing, walls a metre or more thick) 7,319 of 20,387 probes, 4,652 of
them next to live ones, each leaving a hole in the cages of the rooms beside it. A probe still inside after the
iterations may move anywhere within ``rescue_limit`` (just under one spacing per axis: the 8 cells around its
grid point, those of them inside the grid's box) to the nearest free-space point found by its rays: each time a
ray leaves a solid through a back face (its first ``RESCUE_CROSSINGS`` hits: a probe on a wall's outer face first
hits that face) gives a candidate, the exit point moved ``margin`` along the exit face's outward normal; the
candidates within the limit and the grid's box, nearest the grid position first (no two within ``margin``), are each tested with a spherical ray set
(:func:`free_space`: at most half the inside threshold of back faces, no front face nearer than half the margin)
and the probe takes the first that passes. A probe whose rays leave the solid nowhere within the limit (deep
inside a solid: nothing to shade within its cells) stays, and the trace stage turns it OFF. The interpolation
needs nothing new: DDGI's weights and the θ field's occlusion rays already use the relocated position, and the
light stage re-shades from it; the volumes interpolated by grid position (leaking SH) take the probe's value one
cell or less from its grid point, as they take a relocated one's at 0.45.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from workers.kernels.sampling import fibonacci_sphere, random_rotation

__all__ = ["relocation_step", "settled", "exit_candidates", "free_space", "rescue", "RESCUE_CANDIDATES", "RESCUE_RAYS",
           "RESCUE_CROSSINGS", "RESCUE_MARGIN"]

RESCUE_CANDIDATES = 6
"""Candidate positions tested per stuck probe (the nearest distinct exits)."""

RESCUE_RAYS = 64
"""Rays of the free-space test of each candidate."""

RESCUE_CROSSINGS = 3
"""Hits followed along each ray of a stuck probe (the exits past the first hit: a wall's outer face, another solid)."""

SETTLE_FRONT = 2.0
"""An outside probe whose nearest front face is this many times the move threshold (0.1 min spacing) away is settled."""

SETTLE_BACK = 1.5
"""An inside probe whose nearest back face is this many times its reach (limit + offset, metres) away is settled."""

RESCUE_MARGIN = 0.1
"""Distance kept from the exit face, × the smallest spacing (RTXGI's probeMinFrontfaceDistance is 0.1 spacing)."""


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


def settled(offsets: np.ndarray, t: np.ndarray, back: np.ndarray, moved: np.ndarray, limit: np.ndarray,
            min_spacing: float, backface_fraction: float) -> np.ndarray:
    """(P,) bool: the probes that later iterations need not trace again (module doc, "Settled probes").

    ``offsets`` (P, 3) the offsets after this iteration, metres; ``t`` (P, R) this iteration's hit distances
    (inf = miss), ``back`` (P, R) its back-face flags, ``moved`` (P,) whether the iteration moved the probe;
    ``limit`` (3,) the per-axis offset limit, metres; ``min_spacing`` and ``backface_fraction`` as in
    :func:`relocation_step`.
    """
    R = t.shape[1]
    n_back = back.sum(axis=1)
    front = np.where(back, np.inf, t).min(axis=1)
    far_front = (n_back == 0) & (front > SETTLE_FRONT * 0.1 * min_spacing)
    inside = n_back > backface_fraction * R
    nearest_back = np.where(back, t, np.inf).min(axis=1)
    reach = float(np.linalg.norm(limit)) + np.linalg.norm(offsets, axis=1)
    deep = inside & (nearest_back > SETTLE_BACK * reach)
    return (far_front | deep) & ~np.asarray(moved, bool)


@njit(cache=True, nogil=True)
def _exit_candidates(base, positions, t, back, tri, d, normals, limit, margin, k, box_lo, box_hi, has_box, cand, ok):
    """The loop of :func:`exit_candidates` (same arguments, float64 arrays), probe by probe: each back-face hit's
    exit point moved ``margin`` along the outward normal, kept within the limit and the box, taken nearest
    ``base`` first (stable) unless within ``margin`` of one already taken, up to ``k``."""
    P, R = t.shape
    c = np.empty((R, 3))
    dist = np.empty(R)
    for p in range(P):
        for r in range(R):
            dist[r] = np.inf
            tt = t[p, r]
            if not (back[p, r] and np.isfinite(tt)):
                continue
            tr = tri[p, r]
            n0, n1, n2 = normals[tr, 0], normals[tr, 1], normals[tr, 2]
            if n0 * d[r, 0] + n1 * d[r, 1] + n2 * d[r, 2] < 0:               # outward: along the exiting ray
                n0, n1, n2 = -n0, -n1, -n2
            inside_limit = True
            for j in range(3):
                cj = positions[p, j] + d[r, j] * tt + margin * (n0 if j == 0 else (n1 if j == 1 else n2))
                c[r, j] = cj
                if not abs(cj - base[p, j]) <= limit[j]:
                    inside_limit = False
                if has_box and not (cj >= box_lo[j] and cj <= box_hi[j]):
                    inside_limit = False
            if inside_limit:
                e0, e1, e2 = c[r, 0] - base[p, 0], c[r, 1] - base[p, 1], c[r, 2] - base[p, 2]
                dist[r] = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        order = np.argsort(dist, kind="mergesort")
        got = 0
        for j in range(R):
            r = order[j]
            if got >= k or not np.isfinite(dist[r]):
                break                                                          # sorted: the rest are unused
            dup = False
            for g in range(got):
                dx = cand[p, g, 0] - c[r, 0]
                dy = cand[p, g, 1] - c[r, 1]
                dz = cand[p, g, 2] - c[r, 2]
                if np.sqrt(dx * dx + dy * dy + dz * dz) < margin:
                    dup = True
                    break
            if not dup:
                for i in range(3):
                    cand[p, got, i] = c[r, i]
                ok[p, got] = True
                got += 1


def exit_candidates(base: np.ndarray, positions: np.ndarray, t: np.ndarray, back: np.ndarray, tri: np.ndarray,
                    dirs: np.ndarray, normals: np.ndarray, limit: np.ndarray, margin: float,
                    k: int = RESCUE_CANDIDATES, box: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays of probes inside a solid leave it: up to ``k`` candidate positions per probe.

    Parameters
    ----------
    base, positions : (P, 3) float
        Grid positions and the current (relocated) positions the rays start from, world space, metres.
    t, back, tri : (P, R)
        The rays' hit distances (inf = miss), back-face flags and triangles (-1 = miss).
    dirs : (R, 3) float
        Unit ray directions (the same for every probe).
    normals : (T, 3) float
        Unit geometric normals of the triangles (any orientation: the outward one is the one along the ray).
    limit : (3,) float
        Per-axis limit of ``candidate − base``, metres.
    margin : float
        How far the candidate lies from the exit face, along its normal, metres.
    box : ((3,), (3,)) float, optional
        The grid's box (first and last probe layers): candidates outside it are dropped (a probe of the outer
        layer has no cells beyond it; moved there it would shade nothing).

    Returns ``(cand (P, k, 3) float64, ok (P, k) bool)``: per probe the back-face exits moved ``margin`` out, within
    the limit, nearest ``base`` first, no two closer than ``margin``; ``ok`` False for unused slots.
    """
    P, R = t.shape
    cand = np.zeros((P, k, 3))
    ok = np.zeros((P, k), bool)
    lo, hi = (np.zeros(3), np.zeros(3)) if box is None else (np.asarray(box[0], np.float64), np.asarray(box[1], np.float64))
    f64 = lambda x: np.ascontiguousarray(x, np.float64)  # noqa: E731
    _exit_candidates(f64(base), f64(positions), f64(t), np.ascontiguousarray(back, bool),
                     np.ascontiguousarray(tri, np.int64), f64(dirs), f64(normals), f64(limit), float(margin), int(k),
                     lo, hi, box is not None, cand, ok)
    return cand, ok


def free_space(t: np.ndarray, back: np.ndarray, margin: float, backface_fraction: float) -> np.ndarray:
    """(N,) bool: the point of each row of rays is in free space — at most half of ``backface_fraction`` of its
    rays hit back faces (stricter than the inside test, so that the trace stage's own rays agree) and no front
    face is nearer than ``margin / 2``. ``t`` (N, R) hit distances (inf = miss), ``back`` (N, R) bool."""
    R = t.shape[1]
    front = np.where(back, np.inf, t).min(axis=1)
    return (back.sum(axis=1) <= 0.5 * backface_fraction * R) & (front >= 0.5 * margin)


def _later_hits(caster, origins, dirs, t, back, tri, double_sided, reach):
    """The first ``RESCUE_CROSSINGS`` hits along each ray: (P, R·C) t, back, tri (column c·R + r = hit c of ray r),
    the rays cast and their seconds. A ray goes on past a hit nearer than ``reach`` (beyond it no exit can be
    within the limit): a probe on a wall's outer face (its first hit a front face at t = 0) or behind another
    solid still finds the exit into the room beyond."""
    import time

    P, R = t.shape
    ts, bs, trs = [t], [back], [tri]
    n, sec = 0, 0.0
    ds = np.asarray(double_sided, bool)
    eps = 1e-5 * float(getattr(caster, "scale", 1.0))
    cur = np.asarray(t, np.float64)
    for _ in range(RESCUE_CROSSINGS - 1):
        go = np.isfinite(cur) & (cur < reach)
        nt = np.full((P, R), np.inf, np.float32)
        nb = np.zeros((P, R), bool)
        ntr = np.full((P, R), -1, np.int64)
        pi, ri = np.nonzero(go)
        if pi.size:
            t0 = time.perf_counter()
            h = caster.intersect(origins[pi].astype(np.float32), dirs[ri], tnear=cur[pi, ri] + eps)
            sec += time.perf_counter() - t0
            n += pi.size
            hit = h.tri >= 0
            b = h.backface & hit
            if ds.any():
                b &= ~ds[np.where(hit, h.tri, 0)]
            nt[pi, ri], nb[pi, ri], ntr[pi, ri] = h.t, b, h.tri
        ts.append(nt)
        bs.append(nb)
        trs.append(ntr)
        cur = nt.astype(np.float64)
    return np.concatenate(ts, axis=1), np.concatenate(bs, axis=1), np.concatenate(trs, axis=1), n, sec


def rescue(caster, base: np.ndarray, offsets: np.ndarray, double_sided: np.ndarray, limit: np.ndarray,
           margin: float, backface_fraction: float, rays_per_probe: int, rng: np.random.Generator,
           check: np.ndarray | None = None, box: tuple | None = None, k: int = RESCUE_CANDIDATES,
           test_rays: int = RESCUE_RAYS) -> tuple[np.ndarray, dict]:
    """Move the probes still inside geometry to the nearest free-space point within ``limit`` (module doc).

    ``base`` (P, 3) grid positions and ``offsets`` (P, 3) the offsets after the DDGI-P §5 iterations, world space,
    metres; ``limit`` (3,) per-axis offset limit, metres; ``margin`` metres; ``double_sided`` (T,) bool as in
    :func:`workers.raycast.probes.trace_probes`; ``rng`` draws the two ray-set rotations; ``check`` the indices of
    the probes that may be inside (default all: the others are not traced); ``box`` the grid's box (lo, hi), which
    the probes stay in (:func:`exit_candidates`). Returns the new offsets (P, 3) float64
    and stats: ``inside`` (probes found inside), ``rescued``, ``rays``, ``ray_seconds``.
    """
    from workers.raycast.probes import trace_probes

    offsets = np.array(offsets, np.float64, copy=True)
    stats = {"inside": 0, "rescued": 0, "rays": 0, "ray_seconds": 0.0}
    dirs = (fibonacci_sphere(rays_per_probe).astype(np.float64) @ random_rotation(rng).T).astype(np.float32)
    test_dirs = (fibonacci_sphere(test_rays).astype(np.float64) @ random_rotation(rng).T).astype(np.float32)
    check = np.arange(base.shape[0]) if check is None else np.asarray(check, np.int64)
    pos = base[check] + offsets[check]
    t, tri, _, _, back, sec = trace_probes(caster, pos, dirs, double_sided)
    stats["rays"] += t.size
    stats["ray_seconds"] += sec
    inside = np.flatnonzero(back.sum(axis=1) > backface_fraction * dirs.shape[0])   # Fig 7 / Fig 10's test
    stuck = check[inside]
    stats["inside"] = int(stuck.size)
    if stuck.size == 0:
        return offsets, stats
    tris = np.asarray(caster.triangles, np.float64)
    nrm = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-30)[:, None]
    t, back, tri, n_more, sec = _later_hits(caster, pos[inside], dirs, t[inside], back[inside], tri[inside],
                                            double_sided, float(np.linalg.norm(limit)) * 2.0)
    stats["rays"] += n_more
    stats["ray_seconds"] += sec
    cand, ok = exit_candidates(base[stuck], pos[inside], t, back, tri, np.tile(dirs, (RESCUE_CROSSINGS, 1)), nrm,
                               np.asarray(limit, np.float64), margin, k, box)
    flat = cand[ok]
    if flat.shape[0] == 0:
        return offsets, stats
    tt, _, _, _, bb, sec = trace_probes(caster, flat, test_dirs, double_sided)
    stats["rays"] += tt.size
    stats["ray_seconds"] += sec
    good = np.zeros(ok.shape, bool)
    good[ok] = free_space(tt, bb, margin, backface_fraction)
    first = np.argmax(good, axis=1)
    hit = good.any(axis=1)
    idx = stuck[hit]
    offsets[idx] = cand[hit, first[hit]] - base[idx]
    stats["rescued"] = int(hit.sum())
    return offsets, stats
