"""The bounce integrator: probe irradiance as the sum of the bounce series, for one lighting or a batch.

The light stage (one configuration) and PRT's dataset (B configurations at once) run this same loop on the
trace stage's cached probe rays (DDGI-I §3.4-3.5; DESIGN stage 2). Radiance along probe ray r of probe p:

- a miss sees the sky (linear RGB radiance; PRT: 0);
- a back-face hit of a single-sided surface carries 0 (DDGI-P §4.1): such hits are not in ``index``;
- a front-face hit carries ``L = emission + albedo/π · (E_direct + E_indirect)`` (DDGI-I §3.4: indirect pass
  §3.4.1, direct pass §3.4.2), ``E_direct`` fixed (geometry and lights do not move between bounces),
  ``E_indirect`` the previous bounce's probe irradiance gathered at the hit (``gather``, :mod:`workers.kernels.gather`;
  0 at the first bounce).

Offline, each bounce is the full Monte Carlo estimate of DDGI-I eq 1 (DDGI-P eq 1) with no hysteresis
(α = 0): per octahedral texel direction n, ``E(n) = π · Σ_r max(0, n·ω_r) L_r / Σ_r max(0, n·ω_r)``, the
cosine-weighted mean radiance times π (exact for constant radiance: a furnace gives π·L). Bounce b holds the
first b terms of the Neumann series ``E = Σ_k T^k E_0``. Each configuration stops by one rule
(:mod:`workers.kernels.convergence`): after a fixed ``bounces``, or once the light unaccounted for after its
estimated geometric tail is below ``tolerance`` of its value at every probe that matters, and then that tail is added
(capped at ``max_bounces``).

Batches: configuration j owns columns 3j..3j+2 of every (…, 3·B) array; a converged configuration leaves the
batch (its columns are handed to ``retire`` and dropped), so later bounces cost only the live ones. The loop holds
the radiance ray-major (row r·P + p), which the octahedral sums read without a transposed copy.

Consumers: stages/light, kernels/prt_dataset, tests' light-stage reference. Inverse: none.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from workers.kernels.adaptive_rays import merge_rows
from workers.kernels.chunks import map_chunks
from workers.kernels.convergence import extrapolated_tail, relative_tail
from workers.kernels.grid import OFF
from workers.kernels.octahedral import _cosine_power, accumulate_octahedral, add_border, oct_texel_directions
from workers.kernels.sampling import probe_rays

__all__ = ["irradiance_maps", "integrate", "integrate_one", "BounceLog"]


def irradiance_maps(dirs: np.ndarray, radiance: np.ndarray, n: int, states: np.ndarray) -> np.ndarray:
    """Octahedral irradiance with border from per-ray radiance: one bounce's probe update.

    Parameters
    ----------
    dirs : (R, 3) float32 or :class:`workers.kernels.sampling.ProbeRays`
        Unit ray directions, world space: the same for every probe, or each probe's pattern.
    radiance : (P, R, C) float32
        Radiance arriving along each ray, C channels (3 per configuration).
    n : int
        Interior texels per side of a probe's octahedral map.
    states : (P,) int
        Probe states; OFF probes get 0.

    Returns (P, n+2, n+2, C) float32: DDGI-I eq 1 with α = 0 (each texel the cosine-weighted mean radiance
    times π), 1-texel octahedral border (:func:`workers.kernels.octahedral.add_border`).
    """
    texels = oct_texel_directions(n)
    maps = probe_rays(dirs, radiance.shape[0]).per_pattern(       # DDGI-I eq 1, α = 0, each probe's own pattern
        lambda d, v: math.pi * accumulate_octahedral(d, v, texels, 1.0), radiance)
    maps[states == OFF] = 0.0
    return add_border(maps).astype(np.float32)


class _RayMajorMaps:
    """:func:`irradiance_maps` of ray-major radiance (R, P, C): the same arithmetic (the cosine weights (T, R) and
    their sums, then one product with the radiance as it lies, no transposed copy of it), float32 rounding apart
    (the product's summation order).

    With several ray patterns (:class:`workers.kernels.sampling.ProbeRays`) the radiance's probe columns are held
    grouped by pattern, column j being probe ``perm[j]`` (``inv`` the inverse): each pattern's product then reads a
    contiguous block of columns in place. One pattern: ``perm`` and ``inv`` None (the probes' own order)."""

    def __init__(self, dirs, n: int, states: np.ndarray):
        self.n, self.off = n, states == OFF
        rays = probe_rays(dirs, states.shape[0])
        groups = rays.groups()
        texels = oct_texel_directions(n).reshape(-1, 3).astype(np.float32)
        self.w = [_cosine_power(texels @ rays.patterns[k].T, 1.0) for k, _ in groups]   # (T, R) max(0, n·ω)
        self._patterns = [rays.patterns[k] for k, _ in groups]
        self._sh_basis = None
        self.den = np.stack([w.sum(axis=-1) for w in self.w])                          # (G, T)
        self.ok = self.den > 0
        sizes = np.array([idx.size for _, idx in groups], np.int64)
        self.bounds = np.concatenate([[0], np.cumsum(sizes)])                           # group g: columns [b_g, b_g+1)
        self.slot = np.repeat(np.arange(len(groups), dtype=np.int64), sizes)           # column -> group
        if len(groups) == 1:
            self.perm = self.inv = None
            self.cols = np.arange(states.shape[0], dtype=np.int64)
        else:
            self.perm = np.concatenate([idx for _, idx in groups])
            self.inv = np.empty_like(self.perm)
            self.inv[self.perm] = np.arange(self.perm.size)
            self.cols = self.perm

    def __call__(self, radiance_rm: np.ndarray) -> np.ndarray:
        """``radiance_rm`` (R, P, C), its columns in this object's order; returns (P, n+2, n+2, C) in probe order."""
        R, P, C = radiance_rm.shape
        num = np.empty((self.w[0].shape[0], P, C), np.float32)

        def product(g: int) -> None:                        # Σ_r w · L: (T, P, C), each pattern's block in place
            a, b = self.bounds[g], self.bounds[g + 1]
            num[:, a:b] = (self.w[g] @ radiance_rm[:, a:b].reshape(R, (b - a) * C)).reshape(-1, b - a, C)

        self._per_group(product)
        out = np.empty((P, self.n + 2, self.n + 2, C), np.float32)
        bounds = np.linspace(0, P, _MAP_THREADS + 1).astype(np.int64)
        with ThreadPoolExecutor(_MAP_THREADS) as pool:      # π · num / den, OFF = 0, the border: one pass
            list(pool.map(lambda i: _finish_maps(num, self.den, self.ok, self.slot, self.cols, self.off, bounds[i],
                                                 bounds[i + 1], out), range(_MAP_THREADS)))
        return out

    def sh(self, radiance_rm: np.ndarray, K: int = 9) -> np.ndarray:
        """Radiance SH of each probe's rays (:func:`workers.kernels.sh.sh_project_probes`' sums, uniform weights
        4π/R, float32): ``radiance_rm`` (R, P, C) in this object's column order; returns (P, K, C) in probe order,
        OFF probes 0."""
        from workers.kernels.sh import _sh_basis

        R, P, C = radiance_rm.shape
        if self._sh_basis is None or self._sh_basis[0].shape[1] != K:
            self._sh_basis = [(_sh_basis(np.asarray(d, np.float64), K) * (4.0 * math.pi / R)).astype(np.float32)
                              for d in self._patterns]                        # (R, K) each
        out = np.empty((P, K, C), np.float32)

        def product(g: int) -> None:
            a, b = self.bounds[g], self.bounds[g + 1]
            out[self.cols[a:b]] = (self._sh_basis[g].T @ radiance_rm[:, a:b].reshape(R, (b - a) * C)) \
                .reshape(K, b - a, C).transpose(1, 0, 2)

        self._per_group(product)
        out[self.off] = 0.0
        return out

    def _per_group(self, product) -> None:
        """``product(g)`` for every pattern group, on :data:`_MAP_THREADS` threads: each writes only its own
        columns, and each product is one single-threaded BLAS call (the light stage's processes run OpenBLAS on one
        thread, workers.pipeline.BLAS_THREADS), so the floats are those of one loop."""
        map_chunks(lambda g, _: product(g), len(self.w), 1, _MAP_THREADS)


_MAP_THREADS = 2


@njit(cache=True, nogil=True)
def _finish_maps(num, den, ok, slot, cols, off, p0, p1, out):
    """Columns p0..p1 of :class:`_RayMajorMaps`: ``out[q]`` (n+2, n+2, C), q = cols[col], = π·num[:, col]/den[slot[col]]
    in the interior (0 where den = 0 or the probe is OFF; ``den``, ``ok`` (G, T) per pattern group, ``slot`` each
    column's group), float32 as numpy computes it, with :func:`workers.kernels.octahedral.add_border`'s border."""
    n = out.shape[1] - 2
    C = out.shape[3]
    pi = np.float32(math.pi)
    for col in range(p0, p1):
        p = cols[col]
        g = slot[col]
        for i in range(n):
            for j in range(n):
                t = i * n + j
                for c in range(C):
                    out[p, i + 1, j + 1, c] = pi * (num[t, col, c] / den[g, t]) if ok[g, t] and not off[p] else 0.0
        for k in range(1, n + 1):
            for c in range(C):
                out[p, 0, k, c] = out[p, 1, n + 1 - k, c]              # top: first row, columns flipped
                out[p, n + 1, k, c] = out[p, n, n + 1 - k, c]          # bottom: last row, columns flipped
                out[p, k, 0, c] = out[p, n + 1 - k, 1, c]              # left: first column, rows flipped
                out[p, k, n + 1, c] = out[p, n + 1 - k, n, c]          # right: last column, rows flipped
        for c in range(C):                                             # corners from the opposite interior corner
            out[p, 0, 0, c] = out[p, n, n, c]
            out[p, 0, n + 1, c] = out[p, n, 1, c]
            out[p, n + 1, 0, c] = out[p, 1, n, c]
            out[p, n + 1, n + 1, c] = out[p, 1, 1, c]


def _probe_major(held: np.ndarray, inv: np.ndarray | None) -> np.ndarray:
    """(rows, R, C) C-contiguous: ``held`` (R, rows, C) ray-major radiance with its columns in probe order (``inv``:
    column of each probe, None: already), transposed and gathered in one pass on two threads (a copy: the same
    floats as ``held[:, inv].transpose(1, 0, 2)`` made contiguous, without the intermediate copy)."""
    R, rows, C = held.shape
    out = np.empty((rows, R, C), held.dtype)
    src = np.arange(rows, dtype=np.int64) if inv is None else np.asarray(inv, np.int64)
    held = np.ascontiguousarray(held)
    _halves(lambda a, e: _gather_probe_rows(held, src, out, a, e), rows)
    return out


@njit(cache=True, nogil=True)
def _gather_probe_rows(held, src, out, p0, p1):
    """out[p, r, c] = held[r, src[p], c] for probes p in [p0, p1)."""
    for p in range(p0, p1):
        q = src[p]
        for r in range(held.shape[0]):
            for c in range(held.shape[2]):
                out[p, r, c] = held[r, q, c]


def _halves(kernel, n: int) -> None:
    """``kernel(a, e)`` over two halves of [0, n) on two threads: for the per-hit kernels below, whose rows (and the
    radiance rows and hits they write) are distinct, so the result is one pass's."""
    map_chunks(kernel, n, max(1, -(-n // 2)), 2)


@njit(cache=True, nogil=True)
def _near_update(e_ind, sel, a, base, rho, prev):
    """The near-field hits' E_indirect (:func:`integrate` ``near``), in place and float32 as numpy would compute
    ``prev = (1 − a)·e_ind[sel] + base + rho·prev; e_ind[sel] = prev`` (``a`` (k, 1), the rest (k, C))."""
    one = np.float32(1.0)
    for k in range(sel.shape[0]):
        h = sel[k]
        free = one - a[k, 0]
        for c in range(base.shape[1]):
            v = (free * e_ind[h, c] + base[k, c]) + rho[k, c] * prev[k, c]
            prev[k, c] = v
            e_ind[h, c] = v


@njit(cache=True, nogil=True)
def _shade_hits(radiance, index, base, rho, e_indirect):
    """radiance[index[h]] = base[h] + rho[h]·e_indirect[h] (float32; rows of ray-major radiance)."""
    for h in range(index.shape[0]):
        r = index[h]
        for c in range(base.shape[1]):
            radiance[r, c] = base[h, c] + rho[h, c] * e_indirect[h, c]


@njit(cache=True, nogil=True)
def _channel_sums(x):
    """(P, C) float64: ``x.sum(axis=1, dtype=np.float64)`` of a (P, T, C) float32 array, summed over T in order as numpy
    sums a non-contiguous axis (the same floats; one pass, no strided temporaries)."""
    P, T, C = x.shape
    out = np.zeros((P, C))
    for p in range(P):
        for t in range(T):
            for c in range(C):
                out[p, c] += np.float64(x[p, t, c])
    return out


@njit(cache=True, nogil=True)
def _add_tail(picked, rows, rho, e_ind, e_prev, cols, f, hit_probe):
    """The series' tail on the rays of the stopping configurations (:func:`integrate`), in place and float32 as numpy
    computes ``picked[rows] += rho[:, cols] · (e_ind[:, cols] − e_prev[:, cols]) · f[hit_probe]`` (``e_prev`` of shape
    (0, 0): no previous bounce, ΔE = e_ind). ``picked`` (rows, J) holds the columns ``cols`` (J,) of the hits' (H, ·)
    arrays; ``f`` (P, J) the per-probe factors, ``hit_probe`` (H,) each hit's probe."""
    first = e_prev.shape[0] == 0
    for h in range(rows.shape[0]):
        r = rows[h]
        p = hit_probe[h]
        for j in range(cols.shape[0]):
            c = cols[j]
            d = e_ind[h, c] if first else e_ind[h, c] - e_prev[h, c]
            picked[r, j] += rho[h, c] * d * f[p, j]


@dataclass
class BounceLog:
    """What each configuration's series did. ``bounces`` (B,) int64; per configuration, per bounce:
    ``change`` the whole grid's relative change ``Σ|E_b − E_{b−1}| / Σ|E_b|`` and ``residual``: iterating to
    convergence (``bounces`` None) the light unaccounted for at the worst probe that matters once the series' tail
    is added (:func:`workers.kernels.convergence.extrapolated_tail`, ∞ before the fourth bounce); with a fixed
    count the light still to come there (:func:`workers.kernels.convergence.relative_tail`, ∞ before the third)."""

    bounces: np.ndarray
    change: list = field(default_factory=list)
    residual: list = field(default_factory=list)


def integrate(index: np.ndarray, miss: np.ndarray, albedo: np.ndarray, e_direct: np.ndarray, dirs: np.ndarray,
              states: np.ndarray, n: int, gather, retire, *, emission: np.ndarray | None = None, sky=None,
              bounces: int | None, max_bounces: int, tolerance: float, report=None,
              correction: np.ndarray | None = None, indirect_scale: np.ndarray | None = None,
              near=None, parents: np.ndarray | None = None, correction_sh: np.ndarray | None = None) -> BounceLog:
    """Sum the bounce series of B lighting configurations (module doc) over the same cached probe-ray hits.

    Parameters
    ----------
    index : (H,) int
        Flat ray indices (into P·R) of the front-face hits (:class:`workers.kernels.probe_hits.HitSurfaces`).
    miss : (P, R) bool
        Rays that leave the scene (they see ``sky``).
    albedo : (H, 3) float32
        Diffuse albedo at the hits (linear RGB).
    e_direct : (B, H, 3) float32
        Direct irradiance at the hits per configuration (lux × colour).
    dirs : (R, 3) float32 or :class:`workers.kernels.sampling.ProbeRays`; states : (P,) int; n : int
        As :func:`irradiance_maps`.
    gather : callable
        ``gather(maps (P, n+2, n+2, 3k) float32) -> (H, 3k)``: E_indirect at the hits from the live
        configurations' maps (:mod:`workers.kernels.gather`). A gather with ``reads_sh`` True is called
        ``gather(maps, sh)`` with each probe's L2 radiance SH (P, 9, 3k) float32 of the same bounce, projected from
        its rays here (rows merged with ``parents``, ``correction_sh`` added): the light stage's default
        (``light.gather = "sh"``, :class:`workers.kernels.gather.SamplerGather`).
    retire : callable
        ``retire(ids (k,) int, radiance (P, R, 3k) float32, maps (P, n+2, n+2, 3k) float32, bounces int)``,
        called when configurations ``ids`` stop, with their final per-ray radiance and irradiance maps
        (column picks: not C-contiguous).
    emission : (H, 3) float32 or None
        Emitted radiance at the hits, the same for every configuration (PRT: None, the transfer is linear).
    sky : (3,) float or None
        Radiance of the misses (None: 0).
    bounces : int or None
        A fixed count; None: until the residual is below ``tolerance``, at most ``max_bounces``, and then the
        series' tail is added to the maps and rays handed to ``retire`` (per probe and channel, the geometric
        tail of :func:`workers.kernels.convergence.extrapolated_tail`; not for probes whose tail is still large).
    report : callable or None
        ``report(fraction)`` after each bounce.
    correction : (P, n+2, n+2, 3·B) float32 or None
        Added to every bounce's maps: light the cached rays do not carry (the point lights' hot spots sampled
        from the light, :func:`workers.kernels.light_spots.spot_correction`); the radiance handed to ``retire``
        does not hold it.
    correction_sh : (P, 9, 3·B) float32 or None
        The same light as radiance SH, added to every bounce's SH when the gather reads SH.
    indirect_scale : (H,) float32 or None
        Multiplies E_indirect at each hit (the light stage's horizon factor of bent shading normals,
        :func:`workers.kernels.shading.horizon_factor`): ``L = emission + albedo/π · (E_direct + h·E_indirect)``.
        None: 1.
    near : :class:`workers.kernels.probe_hits.NearField` or None
        Near-field occlusion of the hits (:func:`workers.kernels.probe_hits.near_occlusion`: the cosine-weighted
        part a of a hit's hemisphere that geometry within a radius of about a probe spacing covers, the light stage's
        weight ``light.near_strength`` folded in, and the occluders' mean albedo ρ' and emission L'_e). The probes
        stand up to a cell away and report the far field in those directions; the hit sees the nearby surface, whose irradiance the hit's own stands in for (multi-bounce
        ambient occlusion): ``E_indirect = (1 − a)·G + a·(π·L'_e + ρ'·(E_direct + E_indirect'))``, G the gathered
        irradiance and E_indirect' the hit's previous bounce. None, or hits not in it: ``E_indirect = G`` exactly.
    parents : (E,) int or None
        Extra ray rows (:mod:`workers.kernels.adaptive_rays`): the last E of the ``miss.shape[0]`` rows of ``miss``,
        ``index``, ``dirs`` and ``states`` are more rays of probes ``parents``; each bounce's map of a probe is the mean
        of its rows' maps (:func:`workers.kernels.adaptive_rays.merge_rows`), so the maps, ``gather``, ``correction``
        and ``retire``'s maps have P = rows − E probes, and ``retire``'s radiance all the rows.
    """
    rows_all, R = miss.shape
    parents = np.zeros(0, np.int64) if parents is None else np.asarray(parents, np.int64)
    P = rows_all - parents.size
    B, H = e_direct.shape[0], index.size
    t = n + 2
    alb = albedo / np.float32(math.pi)                                        # albedo/π, (H, 3)
    base = (alb[:, None, :] * e_direct.transpose(1, 0, 2)).reshape(H, 3 * B)  # albedo/π · E_direct
    if emission is not None:
        base = np.tile(emission, (1, B)) + base                               # + emission
    rho = np.tile(alb if indirect_scale is None else alb * np.asarray(indirect_scale, np.float32)[:, None], (1, B))
    # radiance ray-major, (R·P, 3B): row r·P + j is ray r of the probe in column j (the octahedral sums read it
    # without a copy; columns grouped by ray pattern, _RayMajorMaps)
    accumulate = _RayMajorMaps(dirs, n, states)          # its column order: probes grouped by ray pattern
    radiance = np.zeros((R * rows_all, 3 * B), np.float32)
    col = index // R if accumulate.inv is None else accumulate.inv[index // R]
    rows = (index % R) * rows_all + col
    if sky is not None:
        held = miss if accumulate.perm is None else miss[accumulate.perm]
        radiance[held.T.ravel()] = np.tile(np.asarray(sky, np.float32), B)
    if near is not None and near.index.size:   # the near-field hits (parameter ``near``), (k, ·) each
        sel = near.index
        near_a = near.a[:, None].astype(np.float32)
        near_rho = np.tile(near_a * near.albedo, (1, B))                               # a·ρ_near
        near_base = np.tile(near_a * np.float32(math.pi) * near.emission, (1, B)) + \
            near_rho * e_direct[:, sel].transpose(1, 0, 2).reshape(sel.size, 3 * B)
        near_prev = np.zeros_like(near_base)
    else:
        near = None
    maps = np.zeros((P, t, t, 3 * B), np.float32)
    reads_sh = bool(getattr(gather, "reads_sh", False))     # the gather reads the probes' L2 SH (parameter gather)
    sh = None
    live = np.arange(B)
    log = BounceLog(bounces=np.zeros(B, np.int64), change=[[] for _ in range(B)], residual=[[] for _ in range(B)])
    deltas: list[np.ndarray] = []
    cap = bounces if bounces is not None else max_bounces
    extrapolate = bounces is None       # iterating to convergence: the tail is added at the stop (convergence doc)
    e_ind = e_prev = None               # E_indirect at the hits of this bounce and the one before (None: 0)
    if extrapolate:                     # the probe of each hit's row (extra rows: their parent's)
        hit_probe = np.concatenate([np.arange(P), parents])[index // R]
    for b in range(1, cap + 1):
        if b == 1:
            radiance[rows] = base                                              # E_indirect = 0: the first bounce
        else:   # DDGI-I §3.4: L = emission + albedo/π·(E_direct + E_indirect), E_indirect gathered (§3.4.1)
            e_prev = e_ind
            e_ind = np.ascontiguousarray(gather(maps, sh) if reads_sh else gather(maps), np.float32)
            if near is not None:    # multi-bounce near-field occlusion (parameter ``near``), in place
                _halves(lambda a, e: _near_update(e_ind, sel[a:e], near_a[a:e], near_base[a:e], near_rho[a:e],
                                                  near_prev[a:e]), sel.size)
            _halves(lambda a, e: _shade_hits(radiance, rows[a:e], base[a:e], rho[a:e], e_ind[a:e]), rows.size)
        new = accumulate(radiance.reshape(R, rows_all, -1))                   # DDGI-I eq 1, α = 0
        if parents.size:
            new = merge_rows(new, parents)                                     # a probe's rows: their mean
        if correction is not None:
            new += correction                                                  # the fixed term over more rays
        if reads_sh:    # the same bounce's radiance as L2 SH, as the maps: rows merged, the fixed term added
            sh = accumulate.sh(radiance.reshape(R, rows_all, -1))
            if parents.size:
                sh = merge_rows(sh, parents)
            if correction_sh is not None:
                sh += correction_sh
        nb = live.size
        diff = new - maps
        step = np.abs(diff)
        # per probe, configuration and channel: the increments the tail is estimated from (workers.kernels.convergence)
        value = np.abs(new).reshape(P, -1, nb, 3).sum(axis=(1, 3), dtype=np.float64)
        deltas = (deltas + [_channel_sums(step.reshape(P, -1, 3 * nb)).reshape(P, nb, 3)])[-4:]
        if extrapolate:     # the residual after the tail is added, and the factor that adds it
            residual, factor = extrapolated_tail(deltas, value)
        else:               # ρ_p(b), max over probes that matter
            residual, _ = relative_tail([d.sum(axis=-1) for d in deltas], value)
        for j, c in enumerate(live):
            s = slice(3 * j, 3 * j + 3)
            total = float(np.abs(new[..., s]).sum())
            log.change[c].append(float(step[..., s].sum()) / total if total > 0 else 0.0)
            log.residual[c].append(float(residual[j]))
        maps = new
        if report is not None:
            report(b / cap)
        if b == cap:
            done = np.ones(nb, bool)
        elif bounces is None:
            done = np.asarray(residual) < tolerance
        else:
            done = np.zeros(nb, bool)
        if not done.any():
            continue
        cols = (3 * np.flatnonzero(done)[:, None] + np.arange(3)).ravel()
        log.bounces[live[done]] = b
        picked = radiance if done.all() else radiance[:, cols]               # no copy when all stop together
        out = new[..., cols]
        if extrapolate and b >= 4:  # the tail, E_∞ ≈ E_b + f·(E_b − E_{b−1}) per probe and channel (convergence doc)
            f = factor[:, done].reshape(P, -1).astype(np.float32)             # (P, 3·done)
            out = out + diff[..., cols] * f[:, None, None, :]
            _add_tail(picked, rows, rho, e_ind, np.zeros((0, 0), np.float32) if e_prev is None else e_prev, cols,
                      np.ascontiguousarray(f), hit_probe)                  # the rays: L_b − L_{b−1} = ρ·ΔE
        retire(live[done], _probe_major(picked.reshape(R, rows_all, -1), accumulate.inv), out, b)
        keep = ~done
        if not keep.any():
            break
        kc = (3 * np.flatnonzero(keep)[:, None] + np.arange(3)).ravel()
        live = live[keep]
        deltas = [d[:, keep] for d in deltas]
        base, rho = base[:, kc], rho[:, kc]
        if e_ind is not None:
            e_ind = e_ind[:, kc]
        if near is not None:
            near_rho, near_base, near_prev = near_rho[:, kc], near_base[:, kc], near_prev[:, kc]
        radiance = np.ascontiguousarray(radiance[:, kc])
        maps = np.ascontiguousarray(maps[..., kc])
        if correction is not None:
            correction = np.ascontiguousarray(correction[..., kc])
        if reads_sh:
            sh = np.ascontiguousarray(sh[..., kc])
            if correction_sh is not None:
                correction_sh = np.ascontiguousarray(correction_sh[..., kc])
    return log


def integrate_one(index, miss, albedo, e_direct, dirs, states, n, gather, *, emission=None, sky=None,
                  bounces: int | None, max_bounces: int, tolerance: float, report=None, correction=None,
                  indirect_scale=None, near=None, parents=None, correction_sh=None):
    """:func:`integrate` for one configuration: ``e_direct`` (H, 3). Returns ``(irradiance (P, n+2, n+2, 3),
    radiance (rows, R, 3), change per bounce, residual per bounce)`` (float32 arrays, lists of float; rows = P + E
    with ``parents``)."""
    out = {}

    def retire(ids, radiance, maps, b):     # C order, as the arrays the loop holds (column picks are not)
        out["radiance"], out["maps"] = np.ascontiguousarray(radiance), np.ascontiguousarray(maps)

    log = integrate(index, miss, albedo, e_direct[None], dirs, states, n, gather, retire, emission=emission,
                    sky=sky, bounces=bounces, max_bounces=max_bounces, tolerance=tolerance, report=report,
                    correction=correction, indirect_scale=indirect_scale, near=near, parents=parents,
                    correction_sh=correction_sh)
    return out["maps"], out["radiance"], log.change[0], log.residual[0]
