"""PRT's lighting scenario and measurement points (PRT §4.1 "Database Creation", §5.1 supersampling).

- :func:`random_light_configurations`: N random lighting configurations drawn from a scenario, a share of
  the point/spot lights close to a surface (:func:`near_surface_sampler`);
- :func:`measurement_points`: M blue-noise points on the front faces of the surfaces, by sample elimination
  [Yuksel15] (:func:`sample_elimination`) from uniform area-weighted candidates (:func:`area_samples`),
  grouped into supersamples (§5.1);
- :func:`measurement_direct`: a configuration's direct vector x at those points (PRT §4.3's "fake G-buffer"
  deferred shading, outgoing radiance ``albedo/π · E_direct``).

Everything here is numpy/scipy; shadow rays come in as a ``caster`` object. Consumers: kernels/prt_dataset,
kernels/lightmap (triangle areas), stages/prt. Inverse: none.

References
----------
.. [PRT] L. Belcour, T. Deliot, W. Barbier, C. Soler, "A Data-Driven Paradigm for Precomputed Radiance
   Transfer", SIGGRAPH 2022 (``../shared/papers/data-driven-prt.txt``).
.. [Yuksel15] C. Yuksel, "Sample Elimination for Generating Poisson Disk Sample Sets", CGF 34(2), 2015.
"""
from __future__ import annotations

import heapq
import math

import numpy as np
from scipy.spatial import cKDTree

from workers.kernels.prt import group_mean
from workers.kernels.shading import direct_irradiance, surface_at_hits

__all__ = ["random_light_configurations", "triangle_areas", "area_samples", "sample_elimination", "min_spacing",
           "measurement_points", "measurement_direct",
           "near_surface_sampler"]

SPOT_OUTER_RANGE = (math.pi / 8, math.pi / 3)
"""radians: a random spot's outer cone angle is uniform in this range; the inner one is half of it."""
PLACEMENT_TRIES = 64
"""redraws of a point/spot light position that falls inside geometry."""
CANDIDATES_PER_POINT = 5
"""Uniform candidates per kept sample for sample elimination (Yuksel uses 5x)."""
MAX_CANDIDATES = 2_000_000
"""At most this many candidates (or M·S, if more)."""


# --------------------------------------------------------------------------------------------- lights
def random_light_configurations(rng: np.random.Generator, scenario: dict, n: int, box_min, box_max,
                                inside=None, target_box=None, near=None) -> list[list[dict]]:
    """N random lighting configurations from a scenario (PRT §4.1 "Database Creation").

    Parameters
    ----------
    rng : numpy Generator (seeded by the caller)
    scenario : dict
        ``proto.models.LightRange`` as a dict: ``types``, ``count`` (lights per configuration),
        ``color_min``/``color_max`` (per channel, linear RGB), ``intensity_min``/``intensity_max``
        (candela for point/spot, lux for directional), optionally ``near_surface`` (share, default 0).
    n : int
        Number of configurations.
    box_min, box_max : (3,) float
        Where point and spot lights are placed (uniformly), world space, metres.
    inside : callable or None
        ``inside(points (k, 3) float32) -> (k,) bool``; a position inside geometry is drawn again (up to
        :data:`PLACEMENT_TRIES` times), since a light inside a solid lights nothing.
    target_box : ((3,), (3,)) or None
        Where spots aim (a uniform point of it); default: the placement box. Pass the scene bounds when
        the lights stand outside the scene.
    near : callable or None
        ``near(rng) -> (3,)`` a position close to a surface (:func:`near_surface_sampler`); with the scenario's
        ``near_surface`` share s > 0, a point/spot light is placed by it with probability s (redrawn while
        inside geometry or outside the placement box; uniform after PLACEMENT_TRIES), else uniformly in the box.

    Returns
    -------
    list of N lists of light dicts in the scene format (:mod:`workers.scene`): each light's type is
    uniform over ``types``, colour uniform per channel, intensity uniform. Directional lights travel in a
    uniformly random direction; a spot aims at a uniform point of ``target_box``, outer cone uniform in
    :data:`SPOT_OUTER_RANGE`, inner cone half of it.
    """
    lo = np.asarray(box_min, np.float64)
    hi = np.asarray(box_max, np.float64)
    types = list(scenario["types"])
    cmin = np.asarray(scenario["color_min"], np.float64)
    cmax = np.asarray(scenario["color_max"], np.float64)
    tlo, thi = (lo, hi) if target_box is None else (np.asarray(target_box[0], np.float64),
                                                    np.asarray(target_box[1], np.float64))
    share = float(scenario.get("near_surface", 0.0))
    out = []
    for _ in range(n):
        lights = []
        for _ in range(int(scenario["count"])):
            kind = types[int(rng.integers(len(types)))]
            color = rng.uniform(cmin, cmax) if np.any(cmax > cmin) else cmin.copy()
            intensity = float(rng.uniform(scenario["intensity_min"], scenario["intensity_max"]))
            light = {"type": kind, "color": color.tolist(), "intensity": intensity, "range": None,
                     "position": None, "direction": None, "inner_cone_angle": 0.0,
                     "outer_cone_angle": math.pi / 4, "name": "prt"}
            if kind in ("point", "spot"):
                p = None
                if near is not None and share > 0 and rng.random() < share:
                    for _ in range(PLACEMENT_TRIES):
                        q = near(rng)
                        if np.all(q >= lo) and np.all(q <= hi) and not _inside(inside, q):
                            p = q
                            break
                if p is None:                        # uniform (or no near-surface point in the box)
                    p = rng.uniform(lo, hi)
                    for _ in range(PLACEMENT_TRIES):
                        if not _inside(inside, p):
                            break
                        p = rng.uniform(lo, hi)
                light["position"] = p.tolist()
            if kind == "directional":
                d = rng.normal(size=3)
                light["direction"] = (d / max(np.linalg.norm(d), 1e-12)).tolist()
            elif kind == "spot":
                target = rng.uniform(tlo, thi)
                d = target - np.asarray(light["position"])
                if np.linalg.norm(d) < 1e-6:
                    d = np.array([0.0, -1.0, 0.0])
                light["direction"] = (d / np.linalg.norm(d)).tolist()
                outer = float(rng.uniform(*SPOT_OUTER_RANGE))
                light["outer_cone_angle"], light["inner_cone_angle"] = outer, 0.5 * outer
            lights.append(light)
        out.append(lights)
    return out


def _inside(inside, p) -> bool:
    return inside is not None and bool(np.asarray(inside(np.asarray(p, np.float32)[None]))[0])


def near_surface_sampler(scene, rng: np.random.Generator, distance, count: int = 4096):
    """``near(rng) -> (3,)`` for :func:`random_light_configurations`: a uniform area-weighted point of the
    scene's surfaces (``count`` candidates drawn once from ``rng``) moved along its front normal by a distance
    uniform in ``distance = (lo, hi)`` metres: lights close to a wall, the floor or an object, whose direct
    light is a bright local spot that lights far from every surface never make (PRT §4.1: the scenario
    defines the distribution the transfer learns)."""
    tri, u, v = area_samples(scene.triangles, count, rng)
    surf = surface_at_hits(scene, tri, u, v)
    pos, nrm = np.asarray(surf["position"], np.float64), np.asarray(surf["normal"], np.float64)
    lo, hi = float(distance[0]), float(distance[1])

    def near(r: np.random.Generator) -> np.ndarray:
        i = int(r.integers(pos.shape[0]))
        return pos[i] + nrm[i] * r.uniform(lo, hi)
    return near


# ---------------------------------------------------------------------------------- measurement points
def triangle_areas(triangles) -> np.ndarray:
    """(T,) float64 areas (m²) of (T, 3, 3) triangles."""
    t = np.asarray(triangles, np.float64)
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def area_samples(triangles, count: int, rng: np.random.Generator, weights=None):
    """Uniform area-weighted random points on triangles.

    Returns ``(tri (count,) int64, u (count,), v (count,))`` barycentrics in the ray-hit convention
    ``x = (1 - u - v)·v0 + u·v1 + v·v2`` (:class:`workers.raycast.Hits`). ``weights`` (T,) optionally
    scales each triangle's area (0 excludes it).
    """
    area = triangle_areas(triangles)
    if weights is not None:
        area = area * np.asarray(weights, np.float64)
    total = area.sum()
    if not total > 0:
        raise ValueError("area_samples: the triangles have no area")
    cdf = np.cumsum(area) / total
    tri = np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right").clip(0, len(area) - 1)
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    return tri.astype(np.int64), s * (1.0 - r2), s * r2  # uniform on the triangle (Osada et al. 2002)


def sample_elimination(points, m: int, area: float, *, alpha: float = 8.0, beta: float = 0.65,
                       gamma: float = 1.5, dims: int = 2) -> np.ndarray:
    """Indices of ``m`` points kept from a denser set by weighted sample elimination [Yuksel15].

    Each point i gets the weight ``w_i = Σ_j (1 - d̂_ij / (2 r_max))^α`` over neighbours within
    2·r_max (Yuksel eq 1-2, α = 8), with ``d̂ = max(d, r_min)``, ``r_min = r_max·(1 - (m/N)^γ)·β``
    (§3.3, γ = 1.5, β = 0.65) and r_max the maximal Poisson-disk radius of m points on a domain of
    the given measure (§3.2: 2D ``√(A / (2√3·m))``, 3D ``∛(V / (4√2·m))``). The point with the largest
    weight is removed and its neighbours' weights drop by its contribution, with a max-heap, until m
    remain. Euclidean distances (Yuksel §5 uses them for surfaces too).

    Parameters
    ----------
    points : (N, 3) float, N >= m
    m : int
    area : float
        The domain's measure: total surface area (m²) for dims = 2, volume for dims = 3.

    Returns
    -------
    (m,) int64 indices into ``points``, in increasing order.
    """
    p = np.asarray(points, np.float64)
    n = p.shape[0]
    if p.ndim != 2 or m < 1 or m > n:
        raise ValueError(f"sample_elimination: need (N, d) points with 1 <= m <= N, got {p.shape} and m = {m}")
    if m == n:
        return np.arange(n)
    if dims == 2:
        r_max = math.sqrt(area / (2.0 * math.sqrt(3.0) * m))
    elif dims == 3:
        r_max = (area / (4.0 * math.sqrt(2.0) * m)) ** (1.0 / 3.0)
    else:
        raise ValueError("sample_elimination: dims must be 2 or 3")
    r_min = r_max * (1.0 - (m / n) ** gamma) * beta
    r2 = 2.0 * r_max
    pairs = cKDTree(p).query_pairs(r2, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    d = np.maximum(np.linalg.norm(p[i] - p[j], axis=1), r_min)
    w = (1.0 - np.minimum(d, r2) / r2) ** alpha
    weight = np.zeros(n)
    np.add.at(weight, i, w)
    np.add.at(weight, j, w)
    # neighbour lists (CSR, both directions)
    src = np.concatenate([i, j])
    dst = np.concatenate([j, i])
    ww = np.concatenate([w, w])
    order = np.argsort(src, kind="stable")
    src, dst, ww = src[order], dst[order], ww[order]
    start = np.searchsorted(src, np.arange(n + 1))
    alive = np.ones(n, bool)
    heap = [(-weight[k], k) for k in range(n)]
    heapq.heapify(heap)
    remaining = n
    while remaining > m:
        neg, k = heapq.heappop(heap)
        if not alive[k] or -neg != weight[k]:
            continue  # stale entry (lazy deletion)
        alive[k] = False
        remaining -= 1
        for e in range(start[k], start[k + 1]):
            q = dst[e]
            if alive[q]:
                weight[q] -= ww[e]
                heapq.heappush(heap, (-weight[q], q))
    return np.flatnonzero(alive)


def min_spacing(points) -> float:
    """Smallest distance between two of the points (metres)."""
    p = np.asarray(points, np.float64)
    d, _ = cKDTree(p).query(p, k=2)
    return float(d[:, 1].min())


# ---------------------------------------------------------------------------------- measurement points
def measurement_points(scene, m: int, s: int, rng: np.random.Generator, usable=None) -> dict:
    """M blue-noise measurement points (M·S samples grouped by point) on the scene's front faces (PRT §4.1, §5.1).

    Candidates are uniform area-weighted points (CANDIDATES_PER_POINT per sample); ``usable(position,
    normal, albedo) -> (k,) bool`` may drop some first (the stage drops those that no configuration of
    the scenario lights: they carry no information and would waste points, e.g. the outside of a room).
    Sample elimination [Yuksel15] keeps M·S of them; with S > 1 the M points are a second elimination of
    those and every sample joins its nearest point. Returns ``{"position", "normal", "albedo": (M·S, 3)
    float32, "offsets": (M+1,) int32, "usable_fraction": float}``; point i averages rows offsets[i]:offsets[i+1].
    """
    tris = scene.triangles
    area = float(triangle_areas(tris).sum())
    fine = m * s
    cand = min(max(CANDIDATES_PER_POINT * fine, fine), max(MAX_CANDIDATES, fine))
    tri, u, v = area_samples(tris, cand, rng)
    surf = surface_at_hits(scene, tri, u, v)
    pos, nrm, alb = surf["position"], surf["normal"], surf["albedo"]
    frac = 1.0
    if usable is not None:
        ok = np.asarray(usable(pos, nrm, alb), bool)
        if ok.sum() >= fine:  # else too few usable candidates: keep them all
            frac = float(ok.mean())
            pos, nrm, alb = pos[ok], nrm[ok], alb[ok]
    keep = sample_elimination(pos, fine, area * frac)                 # [Yuksel15]
    pos, nrm, alb = pos[keep], nrm[keep], alb[keep]
    if s == 1:
        offsets = np.arange(m + 1, dtype=np.int32)
    else:  # §5.1: the M points are a coarser elimination of the samples; each sample joins its nearest
        heads = sample_elimination(pos, m, area * frac)
        _, group = cKDTree(pos[heads].astype(np.float64)).query(pos.astype(np.float64))
        group[heads] = np.arange(m)
        order = np.argsort(group, kind="stable")
        pos, nrm, alb, group = pos[order], nrm[order], alb[order], group[order]
        offsets = np.searchsorted(group, np.arange(m + 1)).astype(np.int32)
    return {"position": pos.astype(np.float32), "normal": nrm.astype(np.float32),
            "albedo": alb.astype(np.float32), "offsets": offsets, "usable_fraction": frac}


def measurement_direct(points: dict, lights: list[dict], caster, eps: float) -> np.ndarray:
    """The direct vector x (M, 3): outgoing radiance ``albedo/π · E_direct`` averaged per point (PRT §4.3, §5.1)."""
    e = direct_irradiance(points["position"], points["normal"], lights, caster, eps)
    rad = points["albedo"].astype(np.float64) / math.pi * e                  # PRT §4.3: albedo/π · E_direct
    return group_mean(rad, points["offsets"])                                # §5.1: mean over the supersamples
