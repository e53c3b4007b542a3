"""Path-traced reference: diffuse indirect irradiance at surface points with Embree (DESIGN stage 7).

What is estimated
-----------------
At a point x with unit normal n (the side being lit), the irradiance splits as

    E(x) = E_direct(x) + E_indirect(x)

- ``E_direct`` — the scene's punctual lights with shadow rays (:func:`workers.kernels.shading.direct_irradiance`),
- ``E_indirect(x) = ∫_Ω L_in(x, ω) max(0, n·ω) dω`` — everything else that arrives: the sky, emissive
  surfaces seen from x, and light reflected by other surfaces (any number of bounces). This is what
  the probe GI modes deliver (the light stage's probe irradiance also holds emission and sky), so
  the two are comparable term by term.

The exitant radiance of a Lambertian surface is ``L_out = Le + albedo/π · (E_direct + E_indirect)``
(the light stage's ray shading, DDGI-I §3.4); :func:`exitant_radiance` forms it per pixel.

Estimator
---------
Cosine-weighted hemisphere sampling (pdf ``cos θ / π``), so one sample of ``E_indirect`` is
``π · L(ray)``. Along a path, vertex k (k = 1 … ``bounces``) adds

    throughput_k · (Le(y_k) + albedo(y_k)/π · E_direct(y_k))

with ``throughput_1 = 1`` and ``throughput_{k+1} = throughput_k · albedo(y_k)`` (Lambertian BRDF
``albedo/π`` times ``cos/pdf = π``); a ray that misses adds ``throughput · sky`` and ends. A hit on
the back face of a single-sided surface carries 0 and ends the path (as probe rays do in the light
stage, DDGI-P §4.1); a double-sided back face is shaded with flipped normals. Paths are truncated
after ``bounces`` vertices, so the estimate converges to the ``bounces``-bounce solution;
Russian roulette (from vertex ``rr_depth`` on, survival ``q = min(0.95, max_c throughput)``,
throughput divided by q) is unbiased with respect to that truncation.

Emitter sampling (next-event estimation, on by default): small bright emitters are found by few
cosine-sampled rays, so at every vertex that continues (the shading point itself and vertices
k < ``bounces``) one emissive triangle is also picked (pmf ∝ area × max emissive factor), a uniform point
on it sampled, and its emission added through a shadow ray, weighted by the power heuristic against the
cosine pdf (Veach 1997); emission found by the cosine-sampled ray is weighted by the complementary
weight. Each vertex's emission is then counted exactly once in expectation: the estimate is unchanged,
the noise much lower. The back of a single-sided emitter emits nothing, in both strategies.

Closed forms (tests): in a closed box whose walls all have albedo a and emit Le, every vertex adds
``a^(k-1) Le``, so ``E_indirect = π Le (1 - a^B)/(1 - a)`` with B = ``bounces`` (→ ``π Le / (1 - a)``,
and ``L_out = Le + a/π E = Le/(1 - a)``, the geometric series); in open space under a sky L,
``E_indirect = π L``.

Execution: wavefront style. All paths of a chunk of points (``max_paths`` paths) advance one
bounce at a time: one ``intersect`` call for every live path, surface attributes for every hit
(:func:`shading.surface_at_hits`), one ``direct_irradiance`` call (shadow rays) for every hit, then
new directions. Rays go through :class:`workers.raycast.RayCaster` (2 threads).

Randomness is counter-based: the uniform numbers of path p = point·spp + sample at vertex k are
a hash (splitmix64) of (seed, p, k, dimension), so a point's estimate depends only on the seed, the
settings and its index in the input — never on chunking, thread count or the other points.

Secondary rays start at ``y + eps·n_geo`` (the geometric normal on the side the path arrived from);
directions are cosine-distributed about the shading normal, and a direction below the geometric
surface (possible where interpolated normals bend away) ends the path with 0 (counted in
``stats["below_surface"]``).

Consumers: the evaluate stage (reference images), tests. Inverse: none.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from workers.kernels.shading import direct_irradiance, surface_at_hits

__all__ = ["PathTraceResult", "indirect_irradiance", "reference_at_gbuffer", "exitant_radiance",
           "cosine_directions", "uniforms", "texel_surfaces", "scene_eps"]

DEFAULT_MAX_PATHS = 1 << 18  # paths per wavefront chunk: bounds memory (~0.5 KB per path in flight)


# ------------------------------------------------------------------------------------- RNG + sampling
@numba.njit(cache=True, inline="always")
def _mix64(z):
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def _uniform(seed, path, vertex, dim):
    h = _mix64(seed * np.uint64(0x9E3779B97F4A7C15) + _mix64(path))
    h = _mix64(h + np.uint64(vertex) * np.uint64(16) + np.uint64(dim))
    return np.float64(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)  # [0, 1), 53 bits


@numba.njit(cache=True, nogil=True)
def _uniforms_kernel(seed, paths, vertex, dim, out):
    for i in range(paths.shape[0]):
        out[i] = _uniform(seed, paths[i], vertex, dim)


@numba.njit(cache=True, nogil=True)
def _cosine_kernel(normals, seed, paths, vertex, out):
    for i in range(paths.shape[0]):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        # orthonormal basis (Duff et al. 2017, "Building an Orthonormal Basis, Revisited")
        s = 1.0 if nz >= 0.0 else -1.0
        a = -1.0 / (s + nz)
        b = nx * ny * a
        t1x, t1y, t1z = 1.0 + s * nx * nx * a, s * b, -s * nx
        t2x, t2y, t2z = b, s + ny * ny * a, -ny
        u1 = _uniform(seed, paths[i], vertex, 0)
        u2 = _uniform(seed, paths[i], vertex, 1)
        r = math.sqrt(u1)
        phi = 2.0 * math.pi * u2
        x = r * math.cos(phi)
        y = r * math.sin(phi)
        z = math.sqrt(max(0.0, 1.0 - u1))
        out[i, 0] = x * t1x + y * t2x + z * nx
        out[i, 1] = x * t1y + y * t2y + z * ny
        out[i, 2] = x * t1z + y * t2z + z * nz


def uniforms(seed: int, paths, vertex: int, dim: int) -> np.ndarray:
    """(N,) float64 uniforms in [0, 1) for path ids ``paths`` (uint64) at ``vertex`` and ``dim``."""
    p = np.ascontiguousarray(paths, np.uint64)
    out = np.empty(p.shape[0], np.float64)
    _uniforms_kernel(np.uint64(seed), p, int(vertex), int(dim), out)
    return out


def cosine_directions(normals, seed: int, paths, vertex: int) -> np.ndarray:
    """(N, 3) float64 unit directions, cosine-distributed about the unit ``normals`` (pdf cos θ / π).

    Deterministic per (seed, path id, vertex); uses dimensions 0 and 1 of :func:`uniforms`.
    """
    n = np.ascontiguousarray(normals, np.float64)
    p = np.ascontiguousarray(paths, np.uint64)
    if n.shape != (p.shape[0], 3):
        raise ValueError(f"cosine_directions: normals {n.shape} do not match {p.shape[0]} paths")
    out = np.empty((p.shape[0], 3), np.float64)
    _cosine_kernel(n, np.uint64(seed), p, int(vertex), out)
    return out


def scene_eps(scene) -> float:
    """Ray offset used with a scene: 1e-4 × its bounds diagonal (the light stage's choice), metres."""
    b = np.asarray(scene.bounds, np.float64)
    return 1e-4 * max(float(np.linalg.norm(b[1] - b[0])), 1e-3)


class _CountingCaster:
    """Wraps a caster and counts the rays it is asked to trace."""

    def __init__(self, caster):
        self.caster = caster
        self.intersect_rays = 0
        self.occluded_rays = 0

    def intersect(self, origins, dirs, *a, **k):
        self.intersect_rays += len(origins)
        return self.caster.intersect(origins, dirs, *a, **k)

    def occluded(self, origins, dirs, *a, **k):
        self.occluded_rays += len(origins)
        return self.caster.occluded(origins, dirs, *a, **k)


def _unit_rows(a: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


# ------------------------------------------------------------------------------------- the tracer
@dataclass
class PathTraceResult:
    """``irradiance`` (N, 3) float32: E_indirect per point; ``stderr`` (N, 3) float32: the standard error
    of each estimate (sample std / √spp); ``stats``: rays traced, timings, settings."""

    irradiance: np.ndarray
    stderr: np.ndarray
    stats: dict = field(default_factory=dict)


def indirect_irradiance(scene, points, normals, lights=(), *, sky=(0.0, 0.0, 0.0), spp: int = 64,
                        bounces: int = 4, seed: int = 0, rr_depth: int | None = None, caster=None,
                        eps: float | None = None, geo_normals=None, max_paths: int = DEFAULT_MAX_PATHS,
                        emitter_sampling: bool = True, report=None) -> PathTraceResult:
    """Path-traced indirect irradiance (see the module doc) at N points.

    Parameters
    ----------
    scene : workers.scene.NormalizedScene
    points : (N, 3) float
        World-space shading points, metres.
    normals : (N, 3) float
        Unit shading normals on the lit side (e.g. ``GBuffer.normal``). Zero rows give 0.
    lights : list of dict
        Punctual lights (the ingest stage's resolved ``lights``) lighting every path vertex.
    sky : (3,) float
        Radiance of rays that miss, linear RGB.
    spp : int
        Paths per point.
    bounces : int
        Maximum path vertices (1 = emission, sky and direct light reflected once).
    seed : int
        Seed of the counter-based RNG (0 … 2⁶⁴-1).
    rr_depth : int or None
        Russian roulette from this vertex on (>= 1); None = off.
    caster : RayCaster, optional
        Built from ``scene.triangles`` when omitted.
    eps : float, optional
        Ray offset, metres; default :func:`scene_eps`.
    geo_normals : (N, 3) float, optional
        Geometric normals on the lit side, for the offset of the first rays (default ``normals``).
    max_paths : int
        Paths per wavefront chunk (memory bound); the result does not depend on it.
    emitter_sampling : bool
        Next-event estimation of emissive triangles with multiple importance sampling (see the module
        doc). Same expectation either way; far less noise where small emitters light the scene.
    report : callable(fraction), optional
        Progress callback.

    Returns
    -------
    PathTraceResult
    """
    from workers.raycast import caster_for_scene

    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape:
        raise ValueError(f"indirect_irradiance: points and normals must both be (N, 3), got {pts.shape}, {nrm.shape}")
    geo = nrm if geo_normals is None else np.asarray(geo_normals, np.float64)
    if geo.shape != pts.shape:
        raise ValueError(f"indirect_irradiance: geo_normals must be (N, 3), got {geo.shape}")
    spp, bounces = int(spp), int(bounces)
    if spp < 1 or bounces < 1:
        raise ValueError(f"indirect_irradiance: spp and bounces must be >= 1, got {spp}, {bounces}")
    if rr_depth is not None and int(rr_depth) < 1:
        raise ValueError(f"indirect_irradiance: rr_depth must be >= 1 or None, got {rr_depth}")
    if not (np.isfinite(pts).all() and np.isfinite(nrm).all() and np.isfinite(geo).all()):
        raise ValueError("indirect_irradiance: points and normals must be finite")
    sky = np.asarray(sky, np.float64).reshape(3)
    eps = scene_eps(scene) if eps is None else float(eps)
    caster = caster_for_scene(scene) if caster is None else caster
    cc = _CountingCaster(caster)
    lights = list(lights)
    n = pts.shape[0]
    nrm = _unit_rows(nrm)
    geo = _unit_rows(geo)
    mean = np.zeros((n, 3), np.float64)
    m2 = np.zeros((n, 3), np.float64)
    ds = np.array([bool(m.get("double_sided", False)) for m in scene.materials] or [False], bool)
    tri_ds = ds[np.asarray(scene.material, np.int64)] if scene.n_triangles else np.zeros(1, bool)
    emitters = _Emitters(scene) if emitter_sampling else None
    stats = {"paths": n * spp, "below_surface": 0, "backface_ends": 0, "rr_kills": 0, "vertices": 0,
             "emitters": int(emitters.tri.size) if emitters is not None else 0}
    t0 = time.perf_counter()
    per_chunk = max(1, int(max_paths) // spp)
    for s in range(0, n, per_chunk):
        e = min(n, s + per_chunk)
        acc = _trace_chunk(scene, cc, pts[s:e], nrm[s:e], geo[s:e], np.arange(s, e, dtype=np.uint64), lights, sky,
                           spp, bounces, seed, rr_depth, eps, stats, tri_ds, emitters)  # (m, spp, 3)
        est = math.pi * acc
        mean[s:e] = est.mean(axis=1)
        if spp > 1:
            m2[s:e] = est.var(axis=1, ddof=1)
        if report is not None:
            report(e / n)
    seconds = time.perf_counter() - t0
    rays = cc.intersect_rays + cc.occluded_rays
    stats.update({"spp": spp, "bounces": bounces, "seed": int(seed), "rr_depth": rr_depth, "eps": eps,
                  "intersect_rays": cc.intersect_rays, "shadow_rays": cc.occluded_rays, "rays": rays,
                  "seconds": seconds, "rays_per_second": rays / seconds if seconds > 0 else 0.0})
    stderr = np.sqrt(m2 / spp)
    return PathTraceResult(irradiance=mean.astype(np.float32), stderr=stderr.astype(np.float32), stats=stats)


@numba.njit(cache=True, nogil=True)
def _hit_frames(d, o, t, ns, ng, pos_out, ns_out, ng_out):
    """Hit points ``o + t d`` and the shading / geometric normals flipped to face the arriving ray."""
    for i in range(d.shape[0]):
        sn = ns[i, 0] * d[i, 0] + ns[i, 1] * d[i, 1] + ns[i, 2] * d[i, 2]
        sg = ng[i, 0] * d[i, 0] + ng[i, 1] * d[i, 1] + ng[i, 2] * d[i, 2]
        fs = -1.0 if sn > 0.0 else 1.0
        fg = -1.0 if sg > 0.0 else 1.0
        for c in range(3):
            pos_out[i, c] = o[i, c] + t[i] * d[i, c]
            ns_out[i, c] = fs * ns[i, c]
            ng_out[i, c] = fg * ng[i, c]


@numba.njit(cache=True, nogil=True)
def _shade_scatter(vertex, last, rr_depth, seed, pid, owner, thr, albedo, emission, e_in, ns, ng, pos, eps,
                   acc, keep, new_o, new_d, new_cos, counts):
    """Add each live vertex's radiance ``thr · (emission + albedo/π · e_in)`` to its path, then continue the
    path (throughput × albedo, Russian roulette, a cosine direction about ns above the geometric surface).

    counts[0] += Russian-roulette kills, counts[1] += directions below the geometric surface.
    """
    inv_pi = 1.0 / math.pi
    for i in range(pid.shape[0]):
        j = owner[i]
        for c in range(3):
            acc[j, c] += thr[i, c] * (emission[i, c] + albedo[i, c] * inv_pi * e_in[i, c])
        keep[i] = False
        if last:
            continue
        t0 = thr[i, 0] * albedo[i, 0]
        t1 = thr[i, 1] * albedo[i, 1]
        t2 = thr[i, 2] * albedo[i, 2]
        tmax = max(t0, max(t1, t2))
        if not tmax > 0.0:
            continue
        if rr_depth > 0 and vertex >= rr_depth:
            q = min(0.95, tmax)
            if _uniform(seed, pid[i], vertex, 2) >= q:
                counts[0] += 1
                continue
            t0 /= q
            t1 /= q
            t2 /= q
        thr[i, 0] = t0
        thr[i, 1] = t1
        thr[i, 2] = t2
        # cosine direction about the shading normal (same construction as _cosine_kernel)
        nx, ny, nz = ns[i, 0], ns[i, 1], ns[i, 2]
        s = 1.0 if nz >= 0.0 else -1.0
        a = -1.0 / (s + nz)
        b = nx * ny * a
        u1 = _uniform(seed, pid[i], vertex, 0)
        u2 = _uniform(seed, pid[i], vertex, 1)
        r = math.sqrt(u1)
        phi = 2.0 * math.pi * u2
        x = r * math.cos(phi)
        y = r * math.sin(phi)
        z = math.sqrt(max(0.0, 1.0 - u1))
        dx = x * (1.0 + s * nx * nx * a) + y * b + z * nx
        dy = x * (s * b) + y * (s + ny * ny * a) + z * ny
        dz = x * (-s * nx) + y * (-ny) + z * nz
        if dx * ng[i, 0] + dy * ng[i, 1] + dz * ng[i, 2] <= 0.0:
            counts[1] += 1
            continue
        keep[i] = True
        new_d[i, 0] = dx
        new_d[i, 1] = dy
        new_d[i, 2] = dz
        new_cos[i] = z
        for c in range(3):
            new_o[i, c] = pos[i, c] + eps * ng[i, c]


# ------------------------------------------------------------------------------------- emitter sampling
@numba.njit(cache=True, nogil=True)
def _nee_kernel(pos, ns, pid, seed, vertex, cdf, em_tri, tris, ngeo, dsided, tri_pmf, area,
                out_tri, out_u, out_v, out_dir, out_dist, out_w):
    """Pick an emissive triangle (pmf ∝ area × max emissive factor) and a uniform point on it per shading
    point; out_w = cos θ · w_light / p_light (solid-angle pdf, power heuristic against the cosine pdf),
    0 when the point is behind the shading point or sees the back of a single-sided emitter."""
    n_em = em_tri.shape[0]
    for i in range(pos.shape[0]):
        out_w[i] = 0.0
        xi = _uniform(seed, pid[i], vertex, 3)
        lo, hi = 0, n_em - 1
        while lo < hi:  # first cdf entry > xi
            mid = (lo + hi) // 2
            if cdf[mid] > xi:
                hi = mid
            else:
                lo = mid + 1
        t = em_tri[lo]
        su = math.sqrt(_uniform(seed, pid[i], vertex, 4))
        u = _uniform(seed, pid[i], vertex, 5) * su
        b0 = 1.0 - su
        v = 1.0 - b0 - u
        out_tri[i] = t
        out_u[i] = u
        out_v[i] = v
        dx = b0 * tris[t, 0, 0] + u * tris[t, 1, 0] + v * tris[t, 2, 0] - pos[i, 0]
        dy = b0 * tris[t, 0, 1] + u * tris[t, 1, 1] + v * tris[t, 2, 1] - pos[i, 1]
        dz = b0 * tris[t, 0, 2] + u * tris[t, 1, 2] + v * tris[t, 2, 2] - pos[i, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if not d2 > 0.0:
            continue
        dist = math.sqrt(d2)
        dx /= dist
        dy /= dist
        dz /= dist
        cos_s = dx * ns[i, 0] + dy * ns[i, 1] + dz * ns[i, 2]
        if cos_s <= 0.0:
            continue
        cos_e = -(dx * ngeo[t, 0] + dy * ngeo[t, 1] + dz * ngeo[t, 2])
        if cos_e <= 0.0:
            if not dsided[t]:
                continue
            cos_e = -cos_e
        if cos_e < 1e-9:
            continue
        p_l = tri_pmf[t] * d2 / (area[t] * cos_e)
        p_b = cos_s / math.pi
        out_dir[i, 0] = dx
        out_dir[i, 1] = dy
        out_dir[i, 2] = dz
        out_dist[i] = dist
        out_w[i] = cos_s * p_l / (p_l * p_l + p_b * p_b)  # cos · w_l / p_l, w_l = p_l² / (p_l² + p_b²)


class _Emitters:
    """Emissive triangles of a scene, for next-event estimation (area sampling with MIS)."""

    def __init__(self, scene):
        mats = scene.materials
        T = scene.n_triangles
        mat = np.asarray(scene.material, np.int64)
        emis = np.array([m.get("emissive", [0, 0, 0])[:3] for m in mats] or [[0, 0, 0]], np.float64).reshape(-1, 3)
        tex = np.array([m.get("emissive_texture") is not None for m in mats] or [False], bool)
        ds = np.array([bool(m.get("double_sided", False)) for m in mats] or [False], bool)
        tris = np.asarray(scene.triangles, np.float64).reshape(T, 3, 3)
        cr = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]) if T else np.zeros((0, 3))
        ln = np.linalg.norm(cr, axis=1)
        self.area = 0.5 * ln
        self.ngeo = np.divide(cr, ln[:, None], out=np.zeros_like(cr), where=ln[:, None] > 0)
        self.tris = np.ascontiguousarray(tris)
        self.double_sided = ds[mat] if T else np.zeros(0, bool)
        self.factor = emis[mat] if T else np.zeros((0, 3))
        power = self.area * (self.factor.max(axis=1) if T else np.zeros(0))
        self.tri = np.flatnonzero(power > 0)
        self.textured = bool(T and np.any(tex[mat][self.tri]))
        total = float(power[self.tri].sum())
        self.tri_pmf = np.zeros(T)
        if self.tri.size:
            self.tri_pmf[self.tri] = power[self.tri] / total
            self.cdf = np.cumsum(self.tri_pmf[self.tri])
            self.cdf[-1] = 1.0
        else:
            self.cdf = np.ones(0)
        self.total_area = float(self.area[self.tri].sum())

    def __bool__(self) -> bool:
        return bool(self.tri.size)

    def bsdf_weights(self, tri, t, d, prev_cos) -> np.ndarray:
        """MIS weights (power heuristic) of emission found by cosine-sampled rays: (L,) float64."""
        w = np.ones(tri.shape[0])
        pmf = self.tri_pmf[tri]
        e = np.flatnonzero(pmf > 0)
        if e.size:
            cos_e = np.abs(np.einsum("ij,ij->i", self.ngeo[tri[e]], d[e]))
            p_l = pmf[e] * t[e].astype(np.float64) ** 2 / np.maximum(self.area[tri[e]] * cos_e, 1e-300)
            p_b = prev_cos[e] / math.pi
            w[e] = p_b * p_b / (p_b * p_b + p_l * p_l)
        return w

    def irradiance(self, scene, caster, pos, ns, ng, pid, seed, vertex, eps) -> np.ndarray:
        """(L, 3) MIS-weighted one-sample estimate of the emitted irradiance arriving at the points."""
        L = pos.shape[0]
        out = np.zeros((L, 3))
        if L == 0:
            return out
        tri = np.empty(L, np.int64)
        u = np.empty(L)
        v = np.empty(L)
        d = np.zeros((L, 3))
        dist = np.zeros(L)
        w = np.empty(L)
        _nee_kernel(np.ascontiguousarray(pos), np.ascontiguousarray(ns), pid, np.uint64(seed), int(vertex), self.cdf,
                    self.tri, self.tris, self.ngeo, self.double_sided, self.tri_pmf, self.area, tri, u, v, d, dist, w)
        ok = np.flatnonzero((w > 0) & (dist > 2 * eps))
        if ok.size == 0:
            return out
        # the shadow ray runs from the offset origin to the sampled point itself (a ray along d from the
        # offset origin would meet a large emitter's plane early at grazing angles)
        o = pos[ok] + eps * ng[ok]
        seg = pos[ok] + d[ok] * dist[ok, None] - o
        length = np.linalg.norm(seg, axis=1)
        far = length > 2 * eps
        blocked = np.zeros(ok.size, bool)
        if far.any():
            blocked[far] = np.asarray(caster.occluded(o[far], seg[far] / length[far, None],
                                                      tfar=length[far] - 2 * eps), bool)
        ok = ok[~blocked]
        if ok.size == 0:
            return out
        if self.textured:
            le = surface_at_hits(scene, tri[ok], u[ok], v[ok])["emission"].astype(np.float64)
        else:
            le = self.factor[tri[ok]]
        out[ok] = le * w[ok, None]
        return out


def _trace_chunk(scene, caster, pts, nrm, geo, point_ids, lights, sky, spp, bounces, seed, rr_depth, eps, stats,
                 tri_double_sided, emitters):
    m = pts.shape[0]
    total = m * spp
    acc = np.zeros((total, 3), np.float64)
    path_ids = (np.repeat(point_ids, spp) * np.uint64(spp) + np.tile(np.arange(spp, dtype=np.uint64), m))
    owner = np.repeat(np.arange(m), spp)
    n0 = nrm[owner]
    g0 = geo[owner]
    lit = np.any(n0 != 0, axis=1)
    nee = emitters is not None and bool(emitters)
    if nee:  # emitted light reaching the shading point itself: E = π · acc, so add E_nee / π
        first = np.flatnonzero(lit)
        acc[first] += emitters.irradiance(scene, caster, pts[owner[first]], n0[first], g0[first], path_ids[first],
                                          seed, 0, eps) / math.pi
    dirs = cosine_directions(n0, seed, path_ids, 0)
    cos0 = np.einsum("ij,ij->i", dirs, n0)
    ok = (np.einsum("ij,ij->i", dirs, g0) > 0) & lit
    stats["below_surface"] += int((~ok & lit).sum())
    alive = np.flatnonzero(ok)
    origins = pts[owner[alive]] + eps * g0[alive]
    dirs = dirs[alive]
    prev_cos = cos0[alive]
    thr = np.ones((alive.size, 3), np.float64)
    sky_on = bool(np.any(sky != 0))
    counts = np.zeros(2, np.int64)
    rr = 0 if rr_depth is None else int(rr_depth)
    for k in range(1, bounces + 1):
        if alive.size == 0:
            break
        h = caster.intersect(origins, dirs)
        hit = h.hit
        if sky_on and not hit.all():
            acc[alive[~hit]] += thr[~hit] * sky
        front = hit & (~h.backface | tri_double_sided[np.where(hit, h.tri, 0)])
        stats["backface_ends"] += int((hit & ~front).sum())
        idx = np.flatnonzero(front)
        if idx.size == 0:
            break
        stats["vertices"] += int(idx.size)
        tri = h.tri[idx].astype(np.int64)
        s = surface_at_hits(scene, tri, h.u[idx], h.v[idx])
        L = idx.size
        pos = np.empty((L, 3))
        ns = np.empty((L, 3))
        ng = np.empty((L, 3))
        d = np.ascontiguousarray(dirs[idx])
        t_hit = h.t[idx].astype(np.float64)
        _hit_frames(d, origins[idx], t_hit, s["normal"].astype(np.float64), s["geo_normal"].astype(np.float64),
                    pos, ns, ng)
        emission = s["emission"].astype(np.float64)
        pid = path_ids[alive[idx]]
        if nee:
            emission *= emitters.bsdf_weights(tri, t_hit, d, prev_cos[idx])[:, None]
        e_in = direct_irradiance(pos, ns, lights, caster, eps).astype(np.float64) if lights else np.zeros((L, 3))
        if nee and k < bounces:
            e_in += emitters.irradiance(scene, caster, pos, ns, ng, pid, seed, k, eps)
        t = np.ascontiguousarray(thr[idx])
        keep = np.empty(L, np.bool_)
        new_o = np.empty((L, 3))
        new_d = np.empty((L, 3))
        new_cos = np.empty(L)
        _shade_scatter(k, k == bounces, rr, np.uint64(seed), pid, alive[idx], t, s["albedo"].astype(np.float64),
                       emission, e_in, ns, ng, pos, float(eps), acc, keep, new_o, new_d, new_cos, counts)
        if k == bounces:
            break
        alive = alive[idx[keep]]
        origins = new_o[keep]
        dirs = new_d[keep]
        prev_cos = new_cos[keep]
        thr = t[keep]
    stats["rr_kills"] += int(counts[0])
    stats["below_surface"] += int(counts[1])
    return acc.reshape(m, spp, 3)


# ------------------------------------------------------------------------------------- G-buffer pixels
def reference_at_gbuffer(scene, gbuffer, lights=(), *, sky=(0.0, 0.0, 0.0), caster=None, eps=None, spp: int = 64,
                         bounces: int = 4, seed: int = 0, rr_depth: int | None = None,
                         max_paths: int = DEFAULT_MAX_PATHS, emitter_sampling: bool = True, report=None) -> dict:
    """Direct and path-traced indirect irradiance at every shaded pixel of a G-buffer.

    Returns ``{"e_direct", "e_indirect", "stderr", "radiance"}`` (H, W, 3) float32 images (0 outside
    ``gbuffer.shaded``) and ``"stats"``. ``radiance`` = :func:`exitant_radiance`.
    """
    from workers.raycast import caster_for_scene

    caster = caster_for_scene(scene) if caster is None else caster
    eps = scene_eps(scene) if eps is None else float(eps)
    H, W = gbuffer.shape
    sel = gbuffer.shaded.ravel()
    pts = gbuffer.position.reshape(-1, 3)[sel].astype(np.float64)
    nrm = gbuffer.normal.reshape(-1, 3)[sel].astype(np.float64)
    geo = gbuffer.geo_normal.reshape(-1, 3)[sel].astype(np.float64)
    t0 = time.perf_counter()
    e_dir = np.zeros((H * W, 3), np.float32)
    if lights:
        # shadow rays start at x + eps·n (shading normal, facing the camera), as in the light stage
        e_dir[sel] = direct_irradiance(pts, nrm, list(lights), caster, eps)
    t_direct = time.perf_counter() - t0
    res = indirect_irradiance(scene, pts, nrm, lights, sky=sky, spp=spp, bounces=bounces, seed=seed,
                              rr_depth=rr_depth, caster=caster, eps=eps, geo_normals=geo, max_paths=max_paths,
                              emitter_sampling=emitter_sampling, report=report)
    e_ind = np.zeros((H * W, 3), np.float32)
    err = np.zeros((H * W, 3), np.float32)
    e_ind[sel] = res.irradiance
    err[sel] = res.stderr
    e_dir, e_ind, err = (a.reshape(H, W, 3) for a in (e_dir, e_ind, err))
    stats = dict(res.stats, direct_seconds=t_direct, pixels=int(sel.sum()))
    return {"e_direct": e_dir, "e_indirect": e_ind, "stderr": err,
            "radiance": exitant_radiance(gbuffer, e_dir, e_ind), "stats": stats}


def exitant_radiance(gbuffer, e_direct, e_indirect) -> np.ndarray:
    """(H, W, 3) float32 ``emission + albedo/π · (E_direct + E_indirect)`` on shaded pixels, 0 elsewhere
    (back faces of single-sided surfaces, uncovered pixels)."""
    e = np.asarray(e_direct, np.float32) + np.asarray(e_indirect, np.float32)
    out = gbuffer.emission + gbuffer.albedo / np.float32(math.pi) * e
    return np.where(gbuffer.shaded[..., None], out, 0.0).astype(np.float32)


# ------------------------------------------------------------------------------------- lightmap texels
@numba.njit(cache=True)
def _raster_uv(uv, width, height, owner, bu, bv):
    T = uv.shape[0]
    for t in range(T):
        x0, y0 = uv[t, 0, 0] * width, uv[t, 0, 1] * height
        x1, y1 = uv[t, 1, 0] * width, uv[t, 1, 1] * height
        x2, y2 = uv[t, 2, 0] * width, uv[t, 2, 1] * height
        den = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if abs(den) < 1e-20:
            continue
        cmin = max(0, int(math.floor(min(x0, x1, x2) - 0.5)))
        cmax = min(width - 1, int(math.ceil(max(x0, x1, x2) - 0.5)))
        rmin = max(0, int(math.floor(min(y0, y1, y2) - 0.5)))
        rmax = min(height - 1, int(math.ceil(max(y0, y1, y2) - 0.5)))
        for r in range(rmin, rmax + 1):
            py = r + 0.5
            for c in range(cmin, cmax + 1):
                if owner[r, c] >= 0:
                    continue
                px = c + 0.5
                w0 = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / den
                w1 = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / den
                w2 = 1.0 - w0 - w1
                if w0 >= -1e-9 and w1 >= -1e-9 and w2 >= -1e-9:
                    owner[r, c] = t
                    bu[r, c] = w1
                    bv[r, c] = w2


def texel_surfaces(uv, width: int, height: int, triangle_ids=None) -> dict:
    """The surface point under each texel centre of a UV atlas (e.g. UV1 lightmap texels).

    Texel (row r, col c) of a ``height`` x ``width`` map is centred at ``u = (c + 0.5)/width``,
    ``v = (r + 0.5)/height`` (glTF: v = 0 on the first row). Each centre inside a triangle's UV
    footprint gets that triangle (the first one in order where footprints overlap) and its
    barycentrics in the convention of :class:`workers.raycast.Hits` (x = (1-u-v)·v0 + u·v1 + v·v2).

    Parameters
    ----------
    uv : (T, 3, 2) float
        Per-triangle texture coordinates (``scene.uv1`` or a subset).
    triangle_ids : (T,) int, optional
        The scene triangle index of each row of ``uv`` (default 0 … T-1).

    Returns
    -------
    dict with ``rows``, ``cols`` (K,) int64 texel indices, ``tri`` (K,) int64 scene triangles, ``u``,
    ``v`` (K,) float64 barycentrics — feed ``tri, u, v`` to :func:`shading.surface_at_hits`.
    """
    a = np.ascontiguousarray(uv, np.float64)
    if a.ndim != 3 or a.shape[1:] != (3, 2):
        raise ValueError(f"texel_surfaces: uv must be (T, 3, 2), got {a.shape}")
    owner = np.full((int(height), int(width)), -1, np.int64)
    bu = np.zeros(owner.shape)
    bv = np.zeros(owner.shape)
    _raster_uv(a, int(width), int(height), owner, bu, bv)
    rows, cols = np.nonzero(owner >= 0)
    t = owner[rows, cols]
    ids = np.arange(a.shape[0]) if triangle_ids is None else np.asarray(triangle_ids, np.int64)
    return {"rows": rows, "cols": cols, "tri": ids[t], "u": bu[rows, cols], "v": bv[rows, cols]}
