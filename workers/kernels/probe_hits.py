"""The probe rays' front-face hits as shading points, and which cage probes each hit sees (DDGI-I §3.4).

The light stage and PRT shade the trace stage's cached probe rays, never re-tracing them (DESIGN stage 2):

- :func:`hit_surfaces`: position, normal (facing the probe), view direction, albedo and emission at every
  front-face hit, once per geometry (the "surfel buffer" of DDGI-I §3.4: the rays' hit points used as a
  G-buffer);
- :func:`probe_visibility`: for every hit, which of its 8 cage probes an occlusion ray from the hit's
  biased point (DDGI-P eq 2) reaches, applied on top of DDGI's Chebyshev weights
  (:func:`workers.kernels.ddgi.sample_irradiance` ``visible=``).

Ray casting comes in as a ``caster`` object (``occluded(origins, dirs, tfar)``, :mod:`workers.raycast`);
nothing here imports it. Consumers: stages/light, kernels/prt_dataset. Inverse: none.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from workers.kernels.chunks import map_chunks
from workers.kernels.ddgi import cage_probes, cage_rays
from workers.kernels.path_rng import _cosine_dir, _uniform
from workers.kernels.sampling import probe_rays
from workers.kernels.shading import ensure_valid_reflection, surface_at_hits

__all__ = ["HitSurfaces", "hit_surfaces", "concat_hits", "probe_visibility", "near_occlusion", "NearField", "VISIBILITY_CHUNK", "HIT_CHUNK"]

HIT_CHUNK = 1 << 20
"""Hits shaded per :func:`workers.kernels.shading.surface_at_hits` call in :func:`hit_surfaces` (memory bound; two
calls in flight, :func:`workers.kernels.chunks.map_chunks`: as many hits as one call of 2²¹ before)."""

VISIBILITY_CHUNK = 1 << 19
"""Hits per batch of visibility rays (8 rays each), bounding memory: two batches are in flight
(:func:`workers.kernels.chunks.map_chunks`), as many rays as one batch of 2²⁰ before."""


@dataclass
class HitSurfaces:
    """The shading inputs of the front-face probe-ray hits, computed once per geometry.

    ``index`` (H,) int64 flat ray indices (into P·R) of the front-face hits; ``position`` (world space,
    metres), ``normal`` (unit, facing the probe: the closure normal N' Cycles would shade with for a viewer at the
    probe, :func:`hit_surfaces`), ``view`` (unit, toward the probe), ``albedo`` (linear RGB), ``emission`` (linear
    RGB radiance) : (H, 3) float32; ``miss`` (P, R) bool; P probes, R rays each. ``geo_normal`` (H, 3) float32:
    the unit geometric normal on the probe's side; ``smooth_normal`` (H, 3) float32: the interpolated vertex normal
    flipped with it; ``bent`` (H,) bool: N' != smooth normal (Cycles bent it). The light stage drops these three
    once E_direct and the horizon factors are made.
    """

    index: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    miss: np.ndarray
    P: int
    R: int
    geo_normal: np.ndarray | None = None
    smooth_normal: np.ndarray | None = None
    bent: np.ndarray | None = None


def hit_surfaces(scene, dirs: np.ndarray, hits: np.ndarray, tri: np.ndarray) -> HitSurfaces:
    """Shading data of the front-face hits of the cached probe rays (the trace stage's outputs).

    Parameters
    ----------
    scene : NormalizedScene
        Triangles, normals and materials (:func:`workers.kernels.shading.surface_at_hits`).
    dirs : (R, 3) float32 or :class:`workers.kernels.sampling.ProbeRays`
        Unit ray directions, world space: the same for every probe, or each probe's pattern.
    hits : (P, R, 4) float32
        t (metres), barycentric u, v, backface (1.0 when the ray hit a triangle's back).
    tri : (P, R) int32
        Hit triangle, -1 for a miss.

    Back-face hits (a single-sided surface seen from behind: radiance 0, DDGI-P §4.1) and misses are not
    in ``index``. The hits are returned in spatial order (a coarse 3D grid), which changes no result.

    Normals as Cycles 3.4 shades a hit seen by a viewer at the probe: the geometric and the interpolated normal are
    flipped together when the geometric one faces away from the ray (shader setup), and the closure normal is
    ``N' = ensure_valid_reflection(Ng, view, N)`` (:func:`workers.kernels.shading.ensure_valid_reflection`): N
    rotated toward Ng where the probe's mirror reflection about N would go below the surface (interpolated normals
    bent at a cube's corners). Where N' = N (every flat-shaded surface) ``normal`` is the interpolated normal
    exactly, as before.
    """
    P, R = tri.shape
    flat = hits.reshape(-1, hits.shape[-1])               # (P·R, 4): t, u, v, backface
    index = np.flatnonzero((tri >= 0) & ~(hits[..., 3] > 0.5))
    tri_flat = tri.ravel()
    tris = np.asarray(scene.triangles)
    # visit hits in spatial order (a coarse 3D grid): the probe sampler then reads neighbouring probes from cache
    # (about 1.6x faster than ray order); the order does not change any result. It is found from the positions
    # alone (the float32 positions surface_at_hits gives), and every field is then made in that order: no
    # reordered copies of the fields (about 1.3 s of single-threaded gathers for 3.4 M hits)
    H = index.size
    pos = np.empty((H, 3), np.float32)
    map_chunks(lambda a, b: _hit_positions(tris, tri_flat[index[a:b]], flat[index[a:b], 1], flat[index[a:b], 2],
                                           pos[a:b]), H, HIT_CHUNK)
    lo, hi = pos.min(axis=0) if len(pos) else 0, pos.max(axis=0) if len(pos) else 1
    cell = np.floor((pos - lo) / np.maximum(hi - lo, 1e-6) * 63.999).astype(np.int64)
    key = cell[:, 0] + 64 * (cell[:, 1] + 64 * cell[:, 2])
    in_range = len(key) == 0 or (key.min() >= 0 and key.max() < 64 ** 3)        # (not for non-finite positions)
    order = _counting_order(key, 64 ** 3) if in_range else np.argsort(key, kind="stable")
    del cell, key
    index = index[order]
    d = probe_rays(dirs, P).of_rays(index)                # probe p's ray r at p·R + r (no (P·R, 3) tile)
    n, alb, emi, geo, smooth = (np.empty((H, 3), np.float32) for _ in range(5))
    bent = np.zeros(H, bool)

    def chunk(a: int, b: int) -> None:     # bounded float64 temporaries (12M hits: ~2 GB at once), two at a time
        uv = flat[index[a:b], 1:3]
        s = surface_at_hits(scene, tri_flat[index[a:b]], uv[:, 0], uv[:, 1])
        nn = s["normal"].astype(np.float32)
        gg = s["geo_normal"].astype(np.float32)
        flip = (np.einsum("ij,ij->i", gg, d[a:b]) > 0)[:, None]                  # the side the ray arrived on
        smooth[a:b] = np.where(flip, -nn, nn)
        geo[a:b] = np.where(flip, -gg, gg)
        nb, bent[a:b] = ensure_valid_reflection(geo[a:b], -d[a:b], smooth[a:b])   # Cycles' closure normal N'
        n[a:b] = nb
        pos[a:b], alb[a:b], emi[a:b] = s["position"], s["albedo"], s["emission"]

    map_chunks(chunk, H, HIT_CHUNK)
    view = (-d).astype(np.float32)
    d = None
    return HitSurfaces(index=index, position=pos, normal=n, view=view, albedo=alb, emission=emi, miss=tri < 0, P=P,
                       R=R, geo_normal=geo, smooth_normal=smooth, bent=bent)


@njit(cache=True, nogil=True)
def _hit_positions(tris, t, u, v, out):  # pragma: no cover - compiled
    """``out[h] = (1 − u − v)·v0 + u·v1 + v·v2`` of triangle t[h], float64 arithmetic stored as float32: the
    positions :func:`workers.kernels.shading.surface_at_hits` gives (its ``_interpolate_hits``, the same
    expression), computed alone to order the hits before they are shaded."""
    for h in range(t.shape[0]):
        k = t[h]
        b1 = np.float64(u[h])
        b2 = np.float64(v[h])
        b0 = 1.0 - b1 - b2
        for a in range(3):
            out[h, a] = b0 * np.float64(tris[k, 0, a]) + b1 * np.float64(tris[k, 1, a]) + b2 * np.float64(tris[k, 2, a])


def concat_hits(a: HitSurfaces, b: HitSurfaces) -> HitSurfaces:
    """The hits of ``a``'s P_a probes then ``b``'s P_b rows (the same R) as one :class:`HitSurfaces` of P_a + P_b rows:
    ``b``'s flat ray indices shifted by P_a·R. Fields None in either are None. Consumes ``a`` and ``b`` (their fields
    are dropped one by one as they are joined, so the peak holds one field twice, not every one)."""
    if a.R != b.R:
        raise ValueError(f"concat_hits: {a.R} and {b.R} rays per row")
    out = {}
    for name in ("index", "position", "normal", "view", "albedo", "emission", "miss", "geo_normal", "smooth_normal",
                 "bent"):
        x, y = getattr(a, name), getattr(b, name)
        if name == "index":
            y = y + a.P * a.R
        out[name] = None if x is None or y is None else np.concatenate([x, y])
        setattr(a, name, None)
        setattr(b, name, None)
    return HitSurfaces(P=a.P + b.P, R=a.R, **out)


@njit(cache=True, nogil=True)
def _counting_order(key, n_keys):
    """``np.argsort(key, kind="stable")`` for keys in [0, n_keys), by counting (O(N); 12M keys: ~0.2 s, not ~10 s)."""
    start = np.zeros(n_keys + 1, np.int64)
    for i in range(key.shape[0]):
        start[key[i] + 1] += 1
    for k in range(n_keys):
        start[k + 1] += start[k]
    order = np.empty(key.shape[0], np.int64)
    for i in range(key.shape[0]):
        order[start[key[i]]] = i
        start[key[i]] += 1
    return order


def probe_visibility(surf, grid: dict, positions: np.ndarray, states: np.ndarray, caster,
                     bias: float) -> tuple[np.ndarray, int]:
    """(H, 8) uint8: whether each cage probe of each point is visible from the point's biased position.

    Parameters
    ----------
    surf : HitSurfaces or any object with ``position``, ``normal``, ``view`` : (H, 3) float32
        Shading points (world space, metres), unit normals, unit directions toward the viewer.
    grid : dict
        ``counts`` (nx, ny, nz), ``origin``, ``spacing`` (metres) of the probe grid.
    positions : (P, 3) float32
        Relocated probe positions, metres.
    states : (P,) int
        Probe states; OFF probes are never visible and cast no ray.
    caster
        ``occluded(origins, dirs, tfar) -> (k,) bool`` (:mod:`workers.raycast`).
    bias : float
        DDGI-P eq 2's self-shadow bias B (the ray starts at the biased point x_b).

    Ray-traced, once per geometry (points and probes do not move between bounces), and applied on top of
    the DDGI weights: DDGI's Chebyshev test keeps a 5% floor, which the weight normalization amplifies
    into visible leaks through thin walls when the visible side's probes have small trilinear weights
    (a sealed room next to a lit one). Offline we can afford the exact answer. Returns the mask and
    the number of rays traced.
    """
    H = surf.position.shape[0]
    vis = np.zeros((H, 8), np.uint8)

    def chunk(a: int, b: int) -> int:       # two chunks at a time (workers.kernels.chunks): rays made while cast
        biased, cage = cage_probes(surf.position[a:b], surf.normal[a:b], surf.view[a:b], grid["counts"],
                                   grid["origin"], grid["spacing"], bias,        # x_b of DDGI-P eq 2
                                   layers=grid.get("layers"))
        live, o, dirs, tfar, slot = cage_rays(biased, cage, positions, states)   # biased point -> live probe
        occluded = caster.occluded(o, dirs, tfar=tfar)
        live.reshape(-1)[slot[occluded]] = 0
        vis[a:b] = live
        return int(slot.shape[0])

    return vis, sum(map_chunks(chunk, H, VISIBILITY_CHUNK))


NEAR_CHUNK = 1 << 17
"""Hits per batch of :func:`near_occlusion` rays (``rays`` each), bounding memory: two batches are in flight
(:func:`workers.kernels.chunks.map_chunks`), as many hits as one batch of 2¹⁸ before."""


@njit(cache=True, nogil=True)
def _near_rays(pos, nrm, geo, eps, k, seed, a0, o, d, slot):
    """Cosine-distributed directions about ``nrm[h]`` for hits a0..a0+len: k per hit, a spiral on the unit disk
    (u1 = (j+½)/k, golden-angle steps) rotated by a per-hit uniform of (seed, h) and lifted onto the hemisphere
    (:func:`workers.kernels.path_rng._cosine_dir`: Malley in Duff et al.'s basis). Directions within 1e-4 of the
    geometric plane or below it are not cast (the horizon factor handles those). Writes the cast rays (origin
    x + eps·Ng) into o, d and the hit's local index into slot; returns the count."""
    m = 0
    golden = (3.0 - math.sqrt(5.0)) / 2.0           # the golden angle as a fraction of a turn
    for i in range(pos.shape[0]):
        turn0 = _uniform(np.uint64(seed), np.uint64(a0 + i), 0, 0)
        for j in range(k):
            dx, dy, dz, _ = _cosine_dir(nrm[i, 0], nrm[i, 1], nrm[i, 2], (j + 0.5) / k, (turn0 + j * golden) % 1.0)
            if dx * geo[i, 0] + dy * geo[i, 1] + dz * geo[i, 2] <= 1e-4:
                continue
            o[m, 0] = pos[i, 0] + eps * geo[i, 0]
            o[m, 1] = pos[i, 1] + eps * geo[i, 1]
            o[m, 2] = pos[i, 2] + eps * geo[i, 2]
            d[m, 0], d[m, 1], d[m, 2] = dx, dy, dz
            slot[m] = i
            m += 1
    return m


@dataclass
class NearField:
    """Near-field occlusion of the hits that have any (:func:`near_occlusion`): ``index`` (k,) int64 into the hits;
    ``a`` (k,) float32 the cosine-weighted occluded part of the hemisphere; ``albedo`` and ``emission`` (k, 3)
    float32 the mean GI albedo and emitted radiance of the occluders the rays hit (0 for the back of a single-sided
    surface: it carries no light, DDGI-P §4.1); ``rays`` the number cast."""

    index: np.ndarray
    a: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    rays: int = 0


def near_occlusion(scene, position: np.ndarray, normal: np.ndarray, geo_normal: np.ndarray, caster, radius: float,
                   rays: int, eps: float, seed: int = 0) -> NearField:
    """The part of each hit's hemisphere that geometry within ``radius`` covers, and what covers it.

    Parameters
    ----------
    scene : NormalizedScene
        Materials of the occluders (:func:`workers.kernels.shading.surface_at_hits`).
    position, normal, geo_normal : (H, 3) float32
        Hit points (world space, metres), the shading normal N' E_indirect is gathered about and the geometric
        normal on the same side (unit).
    caster
        ``intersect(origins, dirs, tnear, tfar) -> Hits`` (:mod:`workers.raycast`).
    radius : float
        Occluders farther than this (metres) are the probes' far field, not counted.
    rays : int
        Cosine-distributed rays per hit (stratified, rotated per hit).
    eps : float
        Ray origin offset along the geometric normal, metres.

    ``a = (1/π) ∫ max(0, N'·ω) [hit within radius along ω] dω``, estimated by ``rays`` cosine-distributed
    rays (each 1/rays of the lobe; rays at or below the geometric plane count as free: the horizon factor of bent
    normals owns them). An open plane gives a = 0 exactly; beside an infinite wall at distance d (d ≤ radius) a
    = (acos c − c·√(1 − c²))/π with c = d/radius, 1/2 at the edge. Fixed per geometry (the hits do not move
    between bounces). Only hits with a > 0 are returned.
    """
    H = position.shape[0]
    idx, aa, alb, emi, cast = [], [], [], [], 0

    def chunk(s: int, e: int):              # two chunks at a time (workers.kernels.chunks): rays made while cast
        n = e - s
        o = np.empty((n * rays, 3), np.float32)
        d = np.empty((n * rays, 3), np.float32)
        slot = np.empty(n * rays, np.int64)
        m = _near_rays(np.ascontiguousarray(position[s:e], np.float64),
                       np.ascontiguousarray(normal[s:e], np.float64),
                       np.ascontiguousarray(geo_normal[s:e], np.float64), float(eps), int(rays), int(seed), s,
                       o, d, slot)
        if m == 0:
            return m, None
        h = caster.intersect(o[:m], d[:m], 0.0, np.full(m, radius, np.float32))
        hit = np.flatnonzero(np.asarray(h.tri) >= 0)
        if hit.size == 0:
            return m, None
        sl = slot[:m][hit]
        surf = surface_at_hits(scene, np.asarray(h.tri)[hit], np.asarray(h.u)[hit], np.asarray(h.v)[hit])
        dark = (np.asarray(h.backface)[hit] & ~np.asarray(surf["double_sided"], bool))[:, None]
        count = np.bincount(sl, minlength=n)
        own = np.flatnonzero(count)
        w = 1.0 / count[own][:, None]
        sums = [np.stack([np.bincount(sl, np.where(dark[:, 0], 0.0, surf[k][:, c]), minlength=n)
                          for c in range(3)], axis=1)[own] for k in ("albedo", "emission")]
        return m, (own + s, count[own] / rays, sums[0] * w, sums[1] * w)

    if H and rays > 0 and radius > 0:
        for m, part in map_chunks(chunk, H, NEAR_CHUNK):
            cast += m
            if part is not None:
                for lst, v in zip((idx, aa, alb, emi), part):
                    lst.append(v)
    cat = (lambda xs, shape: np.concatenate(xs).astype(np.float32) if xs else np.zeros(shape, np.float32))
    return NearField(index=np.concatenate(idx) if idx else np.zeros(0, np.int64), a=cat(aa, (0,)),
                     albedo=cat(alb, (0, 3)), emission=cat(emi, (0, 3)), rays=cast)
