"""Emitter sampling (next-event estimation) for the path tracer, with multiple importance sampling.

Small bright emitters are found by few cosine-sampled rays, so at every vertex that continues one emissive
triangle is also picked (pmf ∝ area × max emissive factor), a uniform point on it sampled, and its emission
added through a shadow ray, weighted by the power heuristic against the cosine pdf (Veach 1997, eq 9.13 with
β = 2); emission found by the cosine-sampled ray gets the complementary weight (:meth:`Emitters.bsdf_weights`).
The back of a single-sided emitter emits nothing, in both strategies. Light pdf in solid angle:
``p_l = pmf(t) · d² / (area(t) · cos θ_e)``; cosine pdf ``p_b = cos θ_s / π``.

Consumer: :mod:`workers.kernels.pathtrace`. Inverse: none.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from workers.kernels.materials import double_sided_triangles
from workers.kernels.path_rng import _uniform
from workers.kernels.shading import _bump_shadowing, surface_at_hits

__all__ = ["Emitters"]


@numba.njit(cache=True, nogil=True)
def _nee_kernel(pos, ns, pid, seed, vertex, uni, cdf, em_tri, tris, ngeo, dsided, tri_pmf, area,
                out_tri, out_u, out_v, out_dir, out_dist, out_w, bent_mode, ng, sm, bent):
    """Pick an emissive triangle (pmf ∝ area × max emissive factor) and a uniform point on it per shading
    point; out_w = cos θ · w_light / p_light (solid-angle pdf, power heuristic against the cosine pdf),
    0 when the point is behind the shading point or sees the back of a single-sided emitter. The uniforms:
    ``uni`` (L, 3) when it has L rows (the pick, the point's two), else dimensions 3, 4, 5 of (seed, pid, vertex).
    ``bent_mode`` (path vertices, Cycles 3.4's bent normals): also 0 below the geometric plane ``ng``, and × the
    bump shadowing term (smooth normal ``sm``, ns = N', direction) on ``bent`` rows."""
    n_em = em_tri.shape[0]
    given = uni.shape[0] == pos.shape[0]
    for i in range(pos.shape[0]):
        out_w[i] = 0.0
        xi = uni[i, 0] if given else _uniform(seed, pid[i], vertex, 3)
        lo, hi = 0, n_em - 1
        while lo < hi:  # first cdf entry > xi
            mid = (lo + hi) // 2
            if cdf[mid] > xi:
                hi = mid
            else:
                lo = mid + 1
        t = em_tri[lo]
        su = math.sqrt(uni[i, 1] if given else _uniform(seed, pid[i], vertex, 4))
        u = (uni[i, 2] if given else _uniform(seed, pid[i], vertex, 5)) * su
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
        bump = 1.0
        if bent_mode:
            gdot = dx * ng[i, 0] + dy * ng[i, 1] + dz * ng[i, 2]
            if gdot <= 0.0 and (ng[i, 0] != 0.0 or ng[i, 1] != 0.0 or ng[i, 2] != 0.0):
                continue
            if bent[i]:
                bump = _bump_shadowing(sm[i, 0], sm[i, 1], sm[i, 2], ns[i, 0], ns[i, 1], ns[i, 2], dx, dy, dz)
                if not bump > 0.0:
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
        out_w[i] = bump * cos_s * p_l / (p_l * p_l + p_b * p_b)  # cos · w_l / p_l, w_l = p_l² / (p_l² + p_b²)


class Emitters:
    """Emissive triangles of a scene, for next-event estimation (area sampling with MIS)."""

    def __init__(self, scene):
        mats = scene.materials
        T = scene.n_triangles
        mat = np.asarray(scene.material, np.int64)
        emis = np.array([m.get("emissive", [0, 0, 0])[:3] for m in mats] or [[0, 0, 0]], np.float64).reshape(-1, 3)
        tex = np.array([m.get("emissive_texture") is not None for m in mats] or [False], bool)
        tris = np.asarray(scene.triangles, np.float64).reshape(T, 3, 3)
        cr = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]) if T else np.zeros((0, 3))
        ln = np.linalg.norm(cr, axis=1)
        self.area = 0.5 * ln
        self.ngeo = np.divide(cr, ln[:, None], out=np.zeros_like(cr), where=ln[:, None] > 0)
        self.tris = np.ascontiguousarray(tris)
        self.double_sided = double_sided_triangles(scene) if T else np.zeros(0, bool)
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

    def irradiance(self, scene, caster, pos, ns, ng, pid, seed, vertex, eps, uniforms=None, smooth=None,
                   bent=None) -> np.ndarray:
        """(L, 3) MIS-weighted one-sample estimate of the emitted irradiance arriving at the points. ``uniforms``
        (L, 3) in [0, 1): the emitter pick and the point on it (e.g. stratified); default: the counter-based
        dimensions 3, 4, 5 of (seed, pid, vertex) (:mod:`workers.kernels.path_rng`). ``smooth`` (L, 3), ``bent``
        (L,) bool: a path vertex with Cycles' bent normals (ns = N' of
        :func:`workers.kernels.shading.ensure_valid_reflection`, smooth the interpolated normal): samples below
        the geometric plane ``ng`` give 0, bent rows × :func:`workers.kernels.shading.bump_shadowing_term`
        (Cycles 3.4 ``bsdf_eval``); the cosine pdf of the MIS weight stays ``max(0, N'·ω)/π``, the pdf the
        vertex samples with. Without them (the shading point itself) neither applies."""
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
        uni = np.zeros((0, 3)) if uniforms is None else np.ascontiguousarray(uniforms, np.float64)
        if uni.shape not in ((0, 3), (L, 3)):
            raise ValueError(f"Emitters.irradiance: uniforms must be ({L}, 3), got {uni.shape}")
        _nee_kernel(np.ascontiguousarray(pos), np.ascontiguousarray(ns), pid, np.uint64(seed), int(vertex), uni,
                    self.cdf, self.tri, self.tris, self.ngeo, self.double_sided, self.tri_pmf, self.area, tri, u, v, d,
                    dist, w, bent is not None, np.ascontiguousarray(ng, np.float64),
                    np.ascontiguousarray(ns if smooth is None else smooth, np.float64),
                    np.zeros(L, np.bool_) if bent is None else np.ascontiguousarray(bent, np.bool_))
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

