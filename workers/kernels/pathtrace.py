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
(the light stage's ray shading, DDGI-I §3.4); :func:`workers.kernels.reference.exitant_radiance` forms it
per pixel.

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

Russian roulette with a control variate (``tail``): a killed path loses everything it would have gathered
after the vertex, and survivors carry it 1/q times, which in a closed, bright room (albedo ~0.7, half the light
after the third bounce) made roulette the largest noise of the reference: two-rooms, 384 surface points, 12
bounces, variance of the luminance estimates summed over the points 104 with roulette from vertex 3, 44 without
(at 2.6x the vertices). With a guess G of the radiance a continuing path gathers per unit throughput (fixed before
the path is traced, e.g. E_indirect/π of the point from an independent pilot pass), the roulette at throughput t
(after the vertex's albedo) is played on the difference from the guess: a killed path adds ``t·G``, a survivor
adds ``t·G·(1 − 1/q)`` and continues with ``t/q``. In expectation ``(1 − q)·t·G + q·(t·G(1 − 1/q) + t·μ/q) =
t·μ`` (μ the true gathered radiance), whatever G: unbiased; where G ≈ μ both branches add about ``t·μ``, so the
roulette's noise goes (closed furnace with the exact G: the estimate exact, test_pathtrace.py). Two-rooms, 384
points, 64 bounces, 192 paths: summed variance 122 → 77 with G from a 48-path pilot (a global G: 86; the mean
future measured on the pilot's own paths per point: 80, no better; a guess per vertex, the pilot points' mean in
the vertex's 0.5-2 m cell and normal octant: 72-73, not kept).

Stratified first directions: the first direction of a point's paths (dimensions 0, 1 at vertex 0) and its
emitter sample (dimensions 3-5) come from ``replicates`` (G, :data:`REPLICATES`) independent randomized
quasi-Monte Carlo sets per point (:func:`workers.kernels.path_rng.stratified_uniforms`: Owen-scrambled Sobol
(0, 2)-nets; path j in set ``j mod G``). Every path's numbers are still uniform, so the estimate is unbiased, but
within a set they are stratified, so the first bounce's noise drops (a square emitter seen by cosine sampling,
32 paths: variance 2.5x lower; with emitter sampling 1.5x; test_pathtrace.py). The paths' sample variance then no
longer measures the error (it overstates it: 8x in that test, 2.9x with emitter sampling), so the standard error
is taken from the G independent sets: ``s² = var(set means, ddof=1) / G``, the estimate the mean of the set
means — unbiased (test_pathtrace.py: mean s² / variance across 4000 independent estimates 1.00-1.03), with
G − 1 = 7 degrees of freedom per point. Deeper vertices stay plain counter-based random numbers. On two-rooms the first direction is
a small part of the noise (the sum of the variances 145 → 122 at 192 paths: 1.19x; its one-bounce part 26 → 13).
With both, the reference stage's points on two-rooms (pilot, first pass, refinement; 10 seeds each,
tests/bench/bench_reference_noise.py): summed variance 396 → 247, mean s² 393 → 249 (the standard errors
unbiased), the per-point values unchanged (+0.08% ± 0.07%).

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
a hash (splitmix64) of (seed, p, k, dimension) — the stratified first ones a hash-keyed scramble of (seed, point,
set) — so a point's estimate depends only on the seed, the settings and its index in the input — never on
chunking, thread count or the other points.

Secondary rays start at ``y + eps·n_geo`` (the geometric normal on the side the path arrived from).
Shading normals at path vertices k >= 1 follow Blender Cycles 3.4 (the fidelity oracle), which matters where
interpolated normals bend away from the geometric one (a cube's corner-averaged normals: up to 54.7°):

- the geometric normal Ng and the interpolated N are flipped together when Ng faces away from the arriving ray
  (Cycles' shader setup; each flipped by its own sign, N could end up below the surface);
- the closure normal is ``N' = ensure_valid_reflection(Ng, I, N)`` with I = −(arriving direction)
  (:func:`workers.kernels.shading.ensure_valid_reflection`; Cycles' svm_node_closure_bsdf does it for every BSDF):
  N rotated toward Ng just enough that the mirror reflection of I stays above the surface;
- the next direction is cosine-distributed about N'; one below the geometric surface ends the path with 0
  (``stats["below_surface"]``; Cycles' bsdf_diffuse_sample gives it pdf and eval 0);
- where N' differs from N (``stats["bent_vertices"]``), the throughput of the sampled direction and the vertex's
  direct light (punctual lights and emitter NEE) are multiplied by Cycles' bump shadowing term of (N, N', ω)
  (:func:`workers.kernels.shading.bump_shadowing_term`, Chiang et al. 2019; 0 below the smooth N:
  ``stats["bump_zero"]`` ends those paths); direct light is ``max(0, N'·l)`` and 0 for lights below Ng.

Vertex 0 (the query point: a free-space receiver, a G-buffer pixel, a texel) has no arriving ray: its normals are
used as given (cosine about ``normals``, rejection below ``geo_normals``, no bump term). On the real Cornell box
with such normals (cornell-vinc3r) this took Kiln's path tracer from 0.80-0.997 of Cycles to 0.999-1.018 (module
tests: a bent floor under a sky and under a sun against the Cycles model).

Modules: this one (the estimator and its wavefront loop), :mod:`workers.kernels.path_rng` (random numbers,
cosine directions), :mod:`workers.kernels.emitters` (next-event estimation), :mod:`workers.kernels.reference`
(at G-buffer pixels and surface points, with the direct light), :mod:`workers.kernels.texels` (lightmap texels).

Consumers: the reference stage (through :mod:`workers.kernels.reference`), tests. Inverse: none.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from workers.kernels.emitters import Emitters
from workers.kernels.materials import double_sided_triangles
from workers.kernels.path_rng import _cosine_sample, _uniform, first_cosine_directions, stratified_uniforms
from workers.kernels.shading import _bump_shadowing, _valid_reflection, direct_irradiance, surface_at_hits

__all__ = ["PathTraceResult", "indirect_irradiance", "scene_eps", "DEFAULT_MAX_PATHS", "REPLICATES"]

DEFAULT_MAX_PATHS = 1 << 18  # paths per wavefront chunk: bounds memory (~0.5 KB per path in flight)
REPLICATES = 8
"""Independent randomized nets of first directions per point (module doc, "Stratified first directions"): the
standard error comes from the spread of their means."""


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
    of each estimate (the spread of its G replicates' means: ``sqrt(var(means, ddof=1) / G)``, module doc);
    ``stats``: rays traced, timings, settings."""

    irradiance: np.ndarray
    stderr: np.ndarray
    stats: dict = field(default_factory=dict)


def indirect_irradiance(scene, points, normals, lights=(), *, sky=(0.0, 0.0, 0.0), spp: int = 64,
                        bounces: int = 4, seed: int = 0, rr_depth: int | None = None, caster=None,
                        eps: float | None = None, geo_normals=None, max_paths: int = DEFAULT_MAX_PATHS,
                        emitter_sampling: bool = True, replicates: int = REPLICATES, tail=None,
                        report=None) -> PathTraceResult:
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
    replicates : int
        G, independent stratified sets of first directions per point (module doc); at most ``spp``. The
        estimate is the mean of their means, its standard error their spread. 1: plain stratified paths with the
        paths' sample standard error (an overestimate of the error under stratification).
    tail : (N, 3) float, optional
        Per point, the control variate of Russian roulette (module doc, "Russian roulette with a control
        variate"): a guess of the radiance a continuing path gathers per unit throughput, linear RGB, e.g.
        E_indirect/π of an independent pilot pass (:func:`workers.kernels.reference.tail_guess`). Any values keep
        the estimate unbiased; good ones cut the noise Russian roulette adds. Default 0 (plain roulette).
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
    if int(replicates) < 1:
        raise ValueError(f"indirect_irradiance: replicates must be >= 1, got {replicates}")
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
    tri_ds = double_sided_triangles(scene) if scene.n_triangles else np.zeros(1, bool)
    emitters = Emitters(scene) if emitter_sampling else None
    G = min(int(replicates), spp)
    tail_r = np.zeros((n, 3)) if tail is None else np.ascontiguousarray(tail, np.float64)
    if tail_r.shape != (n, 3) or not np.isfinite(tail_r).all():
        raise ValueError(f"indirect_irradiance: tail must be finite (N, 3) = ({n}, 3), got {tail_r.shape}")
    stats = {"paths": n * spp, "replicates": G, "below_surface": 0, "backface_ends": 0, "rr_kills": 0, "vertices": 0,
             "bent_vertices": 0, "bump_zero": 0,
             "emitters": int(emitters.tri.size) if emitters is not None else 0}
    t0 = time.perf_counter()
    per_chunk = max(1, int(max_paths) // spp)
    for s in range(0, n, per_chunk):
        e = min(n, s + per_chunk)
        acc = _trace_chunk(scene, cc, pts[s:e], nrm[s:e], geo[s:e], np.arange(s, e, dtype=np.uint64), lights, sky,
                           spp, G, bounces, seed, rr_depth, eps, stats, tri_ds, emitters, tail_r[s:e])  # (m, spp, 3)
        est = math.pi * acc
        if G > 1:      # sample j in replicate j mod G; the replicates are independent, their means unbiased
            reps = np.stack([est[:, g::G].mean(axis=1) for g in range(G)], axis=1)      # (m, G, 3)
            mean[s:e] = reps.mean(axis=1)
            m2[s:e] = reps.var(axis=1, ddof=1) / G        # var of the mean of G means
        else:
            mean[s:e] = est.mean(axis=1)
            if spp > 1:
                m2[s:e] = est.var(axis=1, ddof=1) / spp
        if report is not None:
            report(e / n)
    seconds = time.perf_counter() - t0
    rays = cc.intersect_rays + cc.occluded_rays
    stats.update({"spp": spp, "bounces": bounces, "seed": int(seed), "rr_depth": rr_depth, "eps": eps,
                  "intersect_rays": cc.intersect_rays, "shadow_rays": cc.occluded_rays, "rays": rays,
                  "seconds": seconds, "rays_per_second": rays / seconds if seconds > 0 else 0.0})
    stderr = np.sqrt(m2)
    return PathTraceResult(irradiance=mean.astype(np.float32), stderr=stderr.astype(np.float32), stats=stats)


@numba.njit(cache=True, nogil=True)
def _hit_frames(d, o, t, ns, ng, pos_out, ns_out, ng_out, sm_out, bent_out):
    """Hit points ``o + t d``; the geometric and the interpolated normal both flipped when the geometric one faces
    away from the arriving ray (Cycles' shader setup: ``sm_out``, ``ng_out``); the closure normal
    ``ns_out = N'`` of Cycles' ``ensure_valid_reflection(Ng, I = −d, N)`` (:func:`shading._valid_reflection`) and
    ``bent_out`` where it differs from the interpolated one."""
    for i in range(d.shape[0]):
        sg = ng[i, 0] * d[i, 0] + ng[i, 1] * d[i, 1] + ng[i, 2] * d[i, 2]
        fg = -1.0 if sg > 0.0 else 1.0
        for c in range(3):
            pos_out[i, c] = o[i, c] + t[i] * d[i, c]
            sm_out[i, c] = fg * ns[i, c]
            ng_out[i, c] = fg * ng[i, c]
        x, y, z, b = _valid_reflection(ng_out[i, 0], ng_out[i, 1], ng_out[i, 2], -d[i, 0], -d[i, 1], -d[i, 2],
                                       sm_out[i, 0], sm_out[i, 1], sm_out[i, 2])
        ns_out[i, 0], ns_out[i, 1], ns_out[i, 2] = x, y, z
        bent_out[i] = b


@numba.njit(cache=True, nogil=True)
def _shade_scatter(vertex, last, rr_depth, seed, pid, owner, thr, albedo, emission, e_in, ns, ng, sm, bent, pos, eps,
                   tail, acc, keep, new_o, new_d, new_cos, counts):
    """Add each live vertex's radiance ``thr · (emission + albedo/π · e_in)`` to its path, then continue the
    path (throughput × albedo, Russian roulette, a cosine direction about ns = N' above the geometric surface,
    throughput × the bump shadowing term of (sm, N', direction) where ``bent``: Cycles 3.4's diffuse bsdf_sample).

    counts[0] += Russian-roulette kills, counts[1] += directions below the geometric surface, counts[2] += bent
    vertices' directions below the smooth normal (bump term 0).
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
            g0, g1, g2 = tail[j, 0], tail[j, 1], tail[j, 2]
            if _uniform(seed, pid[i], vertex, 2) >= q:
                counts[0] += 1
                acc[j, 0] += t0 * g0         # the control variate in place of the killed tail
                acc[j, 1] += t1 * g1
                acc[j, 2] += t2 * g2
                continue
            f = 1.0 - 1.0 / q
            acc[j, 0] += t0 * g0 * f
            acc[j, 1] += t1 * g1 * f
            acc[j, 2] += t2 * g2 * f
            t0 /= q
            t1 /= q
            t2 /= q
        thr[i, 0] = t0
        thr[i, 1] = t1
        thr[i, 2] = t2
        # cosine direction about the shading normal (pdf cos θ / π)
        dx, dy, dz, z = _cosine_sample(ns[i, 0], ns[i, 1], ns[i, 2], seed, pid[i], vertex)
        if dx * ng[i, 0] + dy * ng[i, 1] + dz * ng[i, 2] <= 0.0:
            counts[1] += 1
            continue
        if bent[i]:
            f = _bump_shadowing(sm[i, 0], sm[i, 1], sm[i, 2], ns[i, 0], ns[i, 1], ns[i, 2], dx, dy, dz)
            if not f > 0.0:
                counts[2] += 1
                continue
            thr[i, 0] *= f
            thr[i, 1] *= f
            thr[i, 2] *= f
        keep[i] = True
        new_d[i, 0] = dx
        new_d[i, 1] = dy
        new_d[i, 2] = dz
        new_cos[i] = z
        for c in range(3):
            new_o[i, c] = pos[i, c] + eps * ng[i, c]



def _trace_chunk(scene, caster, pts, nrm, geo, point_ids, lights, sky, spp, replicates, bounces, seed, rr_depth, eps,
                 stats, tri_double_sided, emitters, tail):
    m = pts.shape[0]
    total = m * spp
    acc = np.zeros((total, 3), np.float64)
    path_ids = (np.repeat(point_ids, spp) * np.uint64(spp) + np.tile(np.arange(spp, dtype=np.uint64), m))
    owner = np.repeat(np.arange(m), spp)
    n0 = nrm[owner]
    g0 = geo[owner]
    lit = np.any(n0 != 0, axis=1)
    nee = emitters is not None and bool(emitters)
    point_of, sample_of = np.repeat(point_ids, spp), np.tile(np.arange(spp), m)
    if nee:  # emitted light reaching the shading point itself: E = π · acc, so add E_nee / π
        first = np.flatnonzero(lit)
        # its emitter sample stratified too (padded pairs 1 and 2 of the point's nets: the point on the triangle,
        # the pick)
        uni = np.concatenate([stratified_uniforms(seed, point_of[first], sample_of[first], spp, replicates, 2)[:, :1],
                              stratified_uniforms(seed, point_of[first], sample_of[first], spp, replicates, 1)], axis=1)
        acc[first] += emitters.irradiance(scene, caster, pts[owner[first]], n0[first], g0[first], path_ids[first],
                                          seed, 0, eps, uniforms=uni) / math.pi
    dirs, cos0 = first_cosine_directions(n0, seed, point_of, sample_of, spp, replicates)   # stratified (module doc)
    ok = (np.einsum("ij,ij->i", dirs, g0) > 0) & lit
    stats["below_surface"] += int((~ok & lit).sum())
    alive = np.flatnonzero(ok)
    origins = pts[owner[alive]] + eps * g0[alive]
    dirs = dirs[alive]
    prev_cos = cos0[alive]
    thr = np.ones((alive.size, 3), np.float64)
    tail = np.repeat(np.ascontiguousarray(tail, np.float64), spp, axis=0)      # per path
    sky_on = bool(np.any(sky != 0))
    counts = np.zeros(3, np.int64)
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
        sm = np.empty((L, 3))
        bent = np.empty(L, np.bool_)
        d = np.ascontiguousarray(dirs[idx])
        t_hit = h.t[idx].astype(np.float64)
        _hit_frames(d, origins[idx], t_hit, s["normal"].astype(np.float64), s["geo_normal"].astype(np.float64),
                    pos, ns, ng, sm, bent)
        stats["bent_vertices"] += int(bent.sum())
        emission = s["emission"].astype(np.float64)
        pid = path_ids[alive[idx]]
        if nee:
            emission *= emitters.bsdf_weights(tri, t_hit, d, prev_cos[idx])[:, None]
        e_in = (direct_irradiance(pos, ns, lights, caster, eps, geo_normals=ng, smooth_normals=sm, bent=bent)
                .astype(np.float64) if lights else np.zeros((L, 3)))
        if nee and k < bounces:
            e_in += emitters.irradiance(scene, caster, pos, ns, ng, pid, seed, k, eps, smooth=sm, bent=bent)
        t = np.ascontiguousarray(thr[idx])
        keep = np.empty(L, np.bool_)
        new_o = np.empty((L, 3))
        new_d = np.empty((L, 3))
        new_cos = np.empty(L)
        _shade_scatter(k, k == bounces, rr, np.uint64(seed), pid, alive[idx], t, s["albedo"].astype(np.float64),
                       emission, e_in, ns, ng, sm, bent, pos, float(eps), tail, acc, keep, new_o, new_d, new_cos,
                       counts)
        if k == bounces:
            break
        alive = alive[idx[keep]]
        origins = new_o[keep]
        dirs = new_d[keep]
        prev_cos = new_cos[keep]
        thr = t[keep]
    stats["rr_kills"] += int(counts[0])
    stats["below_surface"] += int(counts[1])
    stats["bump_zero"] += int(counts[2])
    return acc.reshape(m, spp, 3)


