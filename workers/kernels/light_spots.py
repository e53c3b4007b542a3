"""Light-side sampling of the hot spots punctual lights make on nearby surfaces (variance reduction for probes).

Each bounce of :mod:`workers.kernels.bounce` estimates DDGI-I eq 1 from the trace stage's R cached rays per probe;
a ray hitting a surface carries ``albedo/π · E_direct``. A point light a centimetre from a surface (the procedural
Cornell box's, 1 cm under its panel) lights a spot of a few cm² to ~10⁴ lux: reflected radiance ~2,300, hundreds of
times anything else, over a solid angle of ~10⁻³ sr from the probes. A probe's 256 rays (0.05 sr each) hit it or miss
it by chance, each probe independently of its neighbours: DDGI's blotches. More rays from the probes do not cure it
(8x the rays still hit a 10⁻³ sr spot 0-3 times); RTXGI's per-ray clamp removes the spot's light (biased).
This module splits each point / spot light's direct irradiance at a surface into a bounded part and the excess:

    E_l = E_l·min(1, c/Y(E_l)) + E_l·max(0, 1 − c/Y(E_l)),   c = :data:`SPOT_FACTOR` x median of Y(E_l) > 0

over the probe rays' front-face hits (Y: luminance). The probe rays carry the bounded part (:func:`split_direct`,
bounded radiance: low variance), and the excess is sampled from the light's side, as instant radiosity's virtual
point lights (Keller 1997): photons leave the light in :data:`PHOTONS` Fibonacci directions, each landing at a
front face y with flux ``Φ_i = I·A·4π/N`` (intensity I, spot attenuation A) of which the share
``max(0, 1 − c/Y(E_l(y)))`` is excess; reflected (albedo ρ) it makes y a Lambertian emitter of intensity
``ρ·Φ_ex·cos θ_y / π``. Photons are merged into cells of :data:`CELL_FRACTION` of the probe spacing (flux-weighted
position, normal; coarser cells beyond :data:`MAX_VIRTUAL_LIGHTS`), each cell one virtual light, tested against
each probe with a shadow ray; its irradiance at probe x for the octahedral texel direction n is
``E(n) = ρΦ_ex/π · cos θ_y · max(0, n·ω) / d²`` (d clamped below at
:data:`MIN_DISTANCE_FRACTION` of the spacing), its radiance SH ``ρΦ_ex/π · cos θ_y / d² · Y_lm(ω)`` (a delta).
:func:`spot_correction` returns these as corrections added to every bounce's maps and to the SH projection
(:func:`workers.kernels.bounce.integrate` ``correction=``). A light with no spot (every surface it lights within
SPOT_FACTOR of its median) has no excess: nothing changes.

Many lights: every virtual light is tested against every live probe, so a level with 32 point lights (16,000 virtual
lights, 20,000 probes) would cast 158 M shadow rays, nearly all of them to probes the virtual light adds a trace of
light to (or that stand in another room). Russian roulette (Arvo & Kirk 1990) keeps the sum's expectation: with
``b_i = SPOT_ROULETTE · Σ_j Y(a_ij)`` the unshadowed total luminance of the pairs at probe i, a pair with
``Y(a_ij) < b_i`` is kept with probability ``q = Y(a_ij)/b_i`` and then weighs ``a_ij/q`` (luminance b_i), else
dropped. At most 1/SPOT_ROULETTE pairs a probe are above the bound and the kept ones below it are Σ q ≤
1/SPOT_ROULETTE on average; a dropped or kept pair changes the probe's correction by at most b_i. The draws are a hash
of (seed, virtual light, probe) (:mod:`workers.kernels.path_rng`): the same bake gives the same floats on any thread
count.

Consumer: stages/light. Inverse: none.

References
----------
.. [Keller97] A. Keller, "Instant Radiosity", SIGGRAPH 1997.
.. [Arvo90] J. Arvo, D. Kirk, "Particle Transport and Image Synthesis", SIGGRAPH 1990 (Russian roulette).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from workers.kernels.chunks import CHUNK_THREADS, map_chunks
from workers.kernels.octahedral import add_border, oct_texel_directions
from workers.kernels.path_rng import _uniform
from workers.kernels.sampling import fibonacci_sphere
from workers.kernels.sh import SH_C0, SH_C1, SH_C2, SH_C3, SH_C4

__all__ = ["SPOT_FACTOR", "PHOTONS", "CELL_FRACTION", "MAX_VIRTUAL_LIGHTS", "MIN_DISTANCE_FRACTION",
           "spot_thresholds", "split_direct", "spot_correction"]

SPOT_FACTOR = 32.0
"""c = this times the median luminance of a light's non-zero direct irradiance at the probe rays' hits."""
PHOTONS = 1 << 16
"""Photons per point / spot light."""
CELL_FRACTION = 0.125
"""Photons are merged into cubic cells of this fraction of the smallest probe spacing (one virtual light each)."""
MAX_VIRTUAL_LIGHTS = 1024
"""Virtual lights per light at most (each costs a shadow ray per probe): the cells double until they fit."""
MIN_DISTANCE_FRACTION = 0.25
"""A virtual light's distance to a probe is clamped below at this fraction of the smallest probe spacing."""
DELTA_THREADS = 2
"""Threads adding the virtual lights to the probes (:func:`_add_deltas`; numba without the GIL)."""
SPOT_BATCH_RAYS = 1 << 18
"""Shadow rays of several virtual lights cast in one caster call (several chunks, so its threads share them)."""
SPOT_ROULETTE = 1.0 / 1024
"""Russian roulette on the (virtual light, probe) pairs (module doc): a pair whose unshadowed luminance is below this
fraction of the probe's unshadowed total over all pairs casts its shadow ray with probability (its luminance / that
bound) and, when it does, counts as the bound: the same expectation for 2 · 1024 shadow rays a probe at most instead
of one per virtual light. 0: every pair, exactly. Measured on zdm2 with 32 point lights (docs/architecture.md, "Many
lights"): against every pair, the probes' L0 moves 0.65% at the 99th percentile, 9.6% at most (a probe at 2% of the
median), for 13 M shadow rays instead of 158 M (1/512: 1.1% and 34%, 7.4 M; 1/2048: 0.36% and 9.5%, 22 M)."""
SPOT_DIM = 15
""":mod:`workers.kernels.path_rng` dimension of the pairs' roulette draws (path: virtual light, vertex: probe)."""
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _luma(e):
    return np.asarray(e, np.float64) @ _LUMA


def spot_thresholds(per_light: list[np.ndarray], lights: list) -> list[float]:
    """c per light from its direct irradiance (H, 3) at the hits (module doc); inf for a light lighting no hit and
    for a directional light (no 1/d²: no spot)."""
    out = []
    for e, light in zip(per_light, lights):
        if light["type"] not in ("point", "spot"):
            out.append(math.inf)
            continue
        y = _luma(e)
        y = y[y > 0]
        out.append(SPOT_FACTOR * float(np.median(y)) if y.size else math.inf)
    return out


def split_direct(per_light: list[np.ndarray], thresholds: list[float]) -> np.ndarray:
    """(H, 3) float32: the bounded part ``Σ_l E_l·min(1, c_l/Y(E_l))`` of the direct irradiance (module doc)."""
    out = np.zeros(per_light[0].shape if per_light else (0, 3), np.float64)
    for e, c in zip(per_light, thresholds):
        _add_bounded(out, np.ascontiguousarray(e), _luma(e), float(c))
    return out.astype(np.float32)


@njit(cache=True, nogil=True)
def _add_bounded(out, e, y, c):  # pragma: no cover - compiled
    """``out += e · min(1, c / max(y, 1e-30))`` row by row in float64, NaN propagating as numpy's minimum and
    maximum do (the vectorized form this replaced, without its (H, 3) temporaries)."""
    for i in range(e.shape[0]):
        m = y[i] if (y[i] >= 1e-30 or y[i] != y[i]) else 1e-30
        q = c / m
        s = q if (q <= 1.0 or q != q) else 1.0
        for k in range(e.shape[1]):
            out[i, k] += np.float64(e[i, k]) * s


def _virtual_lights(scene, caster, light: dict, c: float, double_sided: np.ndarray, cell: float):
    """The excess of one point / spot light as merged virtual lights: (position (V, 3), normal (V, 3), ρΦ_ex/π
    (V, 3)) float64, the normal facing the light."""
    from workers.kernels.shading import direct_irradiance, surface_at_hits
    from workers.raycast.probes import trace_probes

    p = np.asarray(light["position"], np.float64)
    dirs = fibonacci_sphere(PHOTONS).astype(np.float64)
    t, tri, u, v, back, _ = trace_probes(caster, p[None].astype(np.float32), dirs, double_sided)
    front = np.flatnonzero((tri[0] >= 0) & ~back[0])
    if front.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    s = surface_at_hits(scene, tri[0][front], u[0][front], v[0][front])
    y = p + t[0][front, None].astype(np.float64) * dirs[front]
    n = np.asarray(s["normal"], np.float64)
    n = np.where((np.einsum("ij,ij->i", n, dirs[front]) > 0)[:, None], -n, n)      # facing the light
    e = direct_irradiance(y, n, [light], None, 0.0).astype(np.float64)            # unshadowed: the first hit
    ye = _luma(e)
    share = np.maximum(0.0, 1.0 - c / np.maximum(ye, 1e-30))
    keep = share > 0
    if not keep.any():
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    d2 = np.einsum("ij,ij->i", y - p, y - p)
    cos_l = np.abs(np.einsum("ij,ij->i", n, dirs[front]))
    # photon flux Φ_i = E·dA with dA = (4π/N)·d²/cos θ: the light's flux into the photon's solid angle
    flux = e * ((4.0 * math.pi / PHOTONS) * d2 / np.maximum(cos_l, 1e-6))[:, None]
    out = np.asarray(s["albedo"], np.float64) * flux * share[:, None] / math.pi          # ρΦ_ex/π
    y, n, out = y[keep], n[keep], out[keep]
    extent = float(np.ptp(y, axis=0).max())
    while True:                                         # at most MAX_VIRTUAL_LIGHTS cells: coarser ones if needed
        _, inv = np.unique(np.floor(y / cell).astype(np.int64), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        if inv.max() < MAX_VIRTUAL_LIGHTS:
            break
        if cell > extent:       # origin-anchored cells wider than the spot still split it in up to 8: merge all
            inv = np.zeros_like(inv)
            break
        cell *= 2.0
    V = int(inv.max()) + 1
    w = _luma(out)
    wsum = np.bincount(inv, w, V)
    pos = np.stack([np.bincount(inv, w * y[:, k], V) for k in range(3)], 1) / np.maximum(wsum, 1e-30)[:, None]
    nrm = np.stack([np.bincount(inv, w * n[:, k], V) for k in range(3)], 1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    power = np.stack([np.bincount(inv, out[:, k], V) for k in range(3)], 1)
    return pos, nrm, power


def spot_correction(scene, caster, positions: np.ndarray, live: np.ndarray, lights: list, thresholds: list[float],
                    double_sided: np.ndarray, spacing, n: int, eps: float, sh_order: int = 2, *,
                    roulette: float = SPOT_ROULETTE, seed: int = 0):
    """The excess of every point / spot light at every live probe (module doc): ``(Δmaps (P, n+2, n+2, 3) float32,
    ΔSH (P, 4|9, 3) float64, virtual lights, shadow rays)``.

    positions : (P, 3) relocated probes, metres; live : (P,) bool (not OFF); lights, thresholds : the scene's
    lights and :func:`spot_thresholds`; double_sided : (T,) bool; spacing : (3,) probe spacing, metres (0 on a
    one-probe axis); n : octahedral interior texels; eps : shadow-ray offset, metres; roulette : the pairs'
    Russian roulette bound (:data:`SPOT_ROULETTE`; 0 = every pair); seed : its draws' seed (the bake's).
    """
    P = positions.shape[0]
    K = (sh_order + 1) ** 2
    dmaps = np.zeros((P, n * n, 3), np.float64)
    dsh = np.zeros((P, K, 3), np.float64)
    sp = np.asarray(spacing, np.float64)
    h = float(sp[sp > 0].min()) if np.any(sp > 0) else 1.0
    texel = oct_texel_directions(n).reshape(-1, 3).astype(np.float64)              # (n², 3)
    idx = np.flatnonzero(live)
    x = np.ascontiguousarray(positions[idx], np.float64)
    found = []
    for light, c in zip(lights, thresholds):
        if light["type"] not in ("point", "spot") or not math.isfinite(c):
            continue
        found.append(_virtual_lights(scene, caster, light, c, double_sided, CELL_FRACTION * h))
    n_vl = sum(len(f[0]) for f in found)
    rays = 0
    if n_vl == 0 or x.shape[0] == 0:
        return add_border(dmaps.reshape(P, n, n, 3)).astype(np.float32), dsh, n_vl, rays
    pos, nrm, power = (np.ascontiguousarray(np.concatenate([f[i] for f in found]), np.float64) for i in range(3))
    y_power = np.ascontiguousarray(_luma(power))
    bound = np.zeros(x.shape[0])                    # b_i: the roulette's bound per probe (0: every pair, exactly)
    if roulette > 0:                                # each probe's total on its own: any chunking, the same floats
        map_chunks(lambda lo, hi: _pair_totals(pos, nrm, y_power, x, MIN_DISTANCE_FRACTION * h, bound, lo, hi),
                   x.shape[0], -(-x.shape[0] // CHUNK_THREADS))
        bound *= float(roulette)
    # virtual lights in batches of 2·SPOT_BATCH_RAYS pairs at most (cos θ_y > 0 leaves about half of them as shadow
    # rays), one caster call each so that its threads share them; the pair buffers are reused
    group = min(max(1, 2 * SPOT_BATCH_RAYS // x.shape[0]), n_vl)
    cap = group * x.shape[0]
    o, dirs, om = (np.empty((cap, 3)) for _ in range(3))
    a, tfar, probe = np.empty((cap, 3)), np.empty(cap), np.empty(cap, np.int64)
    for j in range(0, n_vl, group):
        k = _spot_pairs(pos[j:j + group], nrm[j:j + group], power[j:j + group], x, eps,
                        MIN_DISTANCE_FRACTION * h, o, dirs, tfar, probe, om, a, y_power[j:j + group], bound,
                        np.uint64(seed & 0xFFFFFFFFFFFFFFFF), j)
        rays += k
        if k == 0:
            continue
        free = ~np.asarray(caster.occluded(o[:k], dirs[:k], tfar=tfar[:k]), bool)
        # E(n) = a·max(0, n·ω) per texel, and the radiance SH of a delta a·Y_lm(ω), added in place
        _add_deltas(dmaps, dsh, idx[probe[:k]], free, om[:k], a[:k], texel)
    return add_border(dmaps.reshape(P, n, n, 3)).astype(np.float32), dsh, n_vl, rays


@njit(cache=True, nogil=True)
def _pair_totals(vy, vn, vl, x, dmin, tot, lo, hi):  # pragma: no cover - compiled
    """``tot[i] = Σ_j Y(a_ij)`` for the probes i in [lo, hi): the unshadowed luminance of every pair that can
    receive light (:func:`_spot_pairs`' ``cos θ_y > 0`` and ``g``; vl (V,) the virtual lights' Y(ρΦ_ex/π))."""
    for i in range(lo, hi):
        s = 0.0
        for j in range(vy.shape[0]):
            wx, wy, wz = vy[j, 0] - x[i, 0], vy[j, 1] - x[i, 1], vy[j, 2] - x[i, 2]
            d = math.sqrt(wx * wx + wy * wy + wz * wz)
            m = max(d, 1e-12)
            cos_y = -((wx / m) * vn[j, 0] + (wy / m) * vn[j, 1] + (wz / m) * vn[j, 2])
            if cos_y > 0.0:
                dd = max(d, dmin)
                s += cos_y / (dd * dd) * vl[j]
        tot[i] = s


@njit(cache=True, nogil=True)
def _spot_pairs(vy, vn, vp, x, eps, dmin, o, dirs, tfar, probe, om, a, vl, bound, seed, j0):  # pragma: no cover
    """The (virtual light, probe) pairs that can receive light, in the order of the virtual lights and then of the
    probes: written to ``o``, ``dirs``, ``tfar`` (the shadow ray from the virtual light, lifted by ``eps`` along its
    normal, to the probe), ``probe`` (index into x), ``om`` (unit probe → virtual light) and ``a`` (the irradiance
    at normal ω, ``ρΦ_ex/π · cos θ_y / max(d, dmin)²``); returns their count. vy, vn, vp : (V, 3) positions,
    normals (facing the light), ρΦ_ex/π; x : (N, 3) probes; the buffers hold V·N rows. The same float64 operations
    as the vectorized form it replaced (module doc). Russian roulette (module doc): vl (V,) Y(vp); bound (N,) b_i
    (0: none); a pair with ``Y(a) = g·vl < b_i`` is kept when ``u·b_i < g·vl`` (u = :func:`workers.kernels.path_rng.
    _uniform` of the seed, path j0 + j, vertex i, dimension SPOT_DIM; j0 the batch's first virtual light) and then
    carries ``a·b_i/Y(a)``."""
    k = 0
    for j in range(vy.shape[0]):
        yx, yy, yz = vy[j, 0], vy[j, 1], vy[j, 2]
        nx, ny, nz = vn[j, 0], vn[j, 1], vn[j, 2]
        ox, oy, oz = yx + eps * nx, yy + eps * ny, yz + eps * nz
        for i in range(x.shape[0]):
            wx, wy, wz = yx - x[i, 0], yy - x[i, 1], yz - x[i, 2]               # probe -> virtual light
            d = math.sqrt(wx * wx + wy * wy + wz * wz)
            m = max(d, 1e-12)
            mx, my, mz = wx / m, wy / m, wz / m
            cos_y = -(mx * nx + my * ny + mz * nz)                             # at y, toward the probe
            if not cos_y > 0.0:
                continue
            dd = max(d, dmin)
            g = cos_y / (dd * dd)                                               # cos θ_y / d²
            ya = g * vl[j]
            if ya < bound[i]:                                                   # the roulette (module doc)
                if _uniform(seed, np.uint64(j0 + j), i, SPOT_DIM) * bound[i] >= ya:
                    continue
                g = g * (bound[i] / ya)
            bx, by, bz = x[i, 0] - ox, x[i, 1] - oy, x[i, 2] - oz
            dist = math.sqrt(bx * bx + by * by + bz * bz)
            o[k, 0], o[k, 1], o[k, 2] = ox, oy, oz
            if dist > 0.0:
                dirs[k, 0], dirs[k, 1], dirs[k, 2] = bx / dist, by / dist, bz / dist
            else:           # the probe at the ray's origin: tfar 0, nothing can block it
                dirs[k, 0], dirs[k, 1], dirs[k, 2] = 0.0, 0.0, 1.0
            tfar[k] = max(dist - 2.0 * eps, 0.0)
            probe[k] = i
            om[k, 0], om[k, 1], om[k, 2] = mx, my, mz
            a[k, 0], a[k, 1], a[k, 2] = g * vp[j, 0], g * vp[j, 1], g * vp[j, 2]
            k += 1
    return k


def _add_deltas(dmaps, dsh, probes, free, om, a, texel) -> None:
    """``dmaps[p, t] += a_j·max(0, texel_t·ω_j)`` and ``dsh[p, k] += a_j·Y_k(ω_j)`` (:func:`workers.kernels.sh.
    _sh_basis`, K = dsh.shape[1]) for p = probes[j] where ``free[j]`` (the shadow ray reached the probe), in the
    order of j (a batch of virtual lights, each one's probes distinct): :data:`DELTA_THREADS` threads, each over a
    range of probes, so every probe's sum has the same terms in the same order as one pass."""
    if probes.size == 0:
        return
    cuts = np.linspace(0, dmaps.shape[0], DELTA_THREADS + 1).astype(np.int64)
    if DELTA_THREADS == 1 or probes.size < 4096:
        _add_delta(dmaps, dsh, probes, free, om, a, texel, 0, dmaps.shape[0])
        return
    with ThreadPoolExecutor(DELTA_THREADS) as pool:
        list(pool.map(lambda i: _add_delta(dmaps, dsh, probes, free, om, a, texel, cuts[i], cuts[i + 1]),
                      range(DELTA_THREADS)))


@njit(cache=True, nogil=True)
def _add_delta(dmaps, dsh, probes, free, om, a, texel, lo, hi):  # pragma: no cover - compiled
    """:func:`_add_deltas` for the probes in [lo, hi), without (k, n², 3) or (k, K) temporaries: the SH basis
    of each ω as :func:`workers.kernels.sh._sh_basis` computes it (the same products in the same order)."""
    K = dsh.shape[1]
    y = np.empty(9)
    for j in range(probes.size):
        p = probes[j]
        if p < lo or p >= hi or not free[j]:
            continue
        ox, oy, oz = om[j, 0], om[j, 1], om[j, 2]
        for t in range(texel.shape[0]):
            c = ox * texel[t, 0] + oy * texel[t, 1] + oz * texel[t, 2]
            if c > 0.0:
                for ch in range(3):
                    dmaps[p, t, ch] += c * a[j, ch]
        y[0], y[1], y[2], y[3] = SH_C0, SH_C1 * oy, SH_C1 * oz, SH_C1 * ox
        if K == 9:
            y[4], y[5] = SH_C2 * ox * oy, SH_C2 * oy * oz
            y[6], y[7], y[8] = SH_C3 * (3.0 * oz * oz - 1.0), SH_C2 * ox * oz, SH_C4 * (ox * ox - oy * oy)
        for k in range(K):
            for ch in range(3):
                dsh[p, k, ch] += y[k] * a[j, ch]
