"""Data-driven precomputed radiance transfer: the math of the ``prt`` stage and of relighting (PRT §3-5).

Everything here is numpy/scipy, no I/O. The stage (:mod:`workers.stages.prt`) builds a dataset of N random
lighting configurations (:func:`random_light_configurations`): for each, the *direct* illumination at M
measurement points (blue noise on the surfaces, :func:`sample_elimination`) and the *indirect*
illumination at a target (probe SH coefficients, lightmap texels). From that dataset :func:`fit` extracts

- a basis (PRT §3.2 eq 7-8, §4.2): the mean of the normalized indirect vectors plus the first n - 1
  left singular vectors of the mean-subtracted ones, found from the N x N Gram matrix (Turk & Pentland,
  as PRT §4.2 does);
- a transfer matrix per colour channel (PRT eq 14, ridge regression; eq 13's pseudo-inverse for λ = 0)
  mapping a direct vector to the basis coefficients.

Conventions
-----------
- A direct vector x is the *outgoing radiance* of the measurement points, ``albedo/π · E_direct``
  (linear RGB; the "fake G-buffer" deferred shading of PRT §4.3), averaged over each point's
  supersamples (§5.1). Shape (M, 3).
- A target vector y has shape (L, 3): L scalar slots per colour channel (L = probes x SH coefficients,
  or covered lightmap texels).
- **Slots**: ``slots[0]`` is the mean μ, ``slots[1:]`` the basis vectors U (orthonormal); "n basis"
  counts the mean, as PRT §4.2 does ("16 basis elements = the mean and 15 basis elements").
  mono (§5.2, default): slots (n, L), one basis shared by the three colour channels, one transfer per
  channel; multi: slots (n, L, 3), colour interleaved in the vectors, one transfer for all.
- **Normalization** (§4.2): each training pair is divided by the direct vector's norm and the mean
  is scaled back by ‖x‖ at runtime. The transfer therefore acts on the direct vector *augmented with
  its norm*, ``x⁺ = [x, ‖x‖]``: ``u = T x⁺``, ``y ≈ Σ_j u_j · slot_j``. Row 0 of T is ``[0, …, 0, 1]``
  (u_0 = ‖x‖, the mean's coefficient, as in PRT); rows j >= 1 are the ridge regression of eq 14 fitted
  *with an intercept* (centred data), the intercept landing in the ‖x‖ column. The paper's plain eq 14
  has no intercept, but its coefficients ``C = Uᵀ(y/‖x‖ - μ)`` are affine, not linear, in x/‖x‖
  (the constant -Uᵀμ), so without it even exactly linear data is not reproduced. This stays
  homogeneous: doubling the lights doubles y.
- **Gamma** (§5.3): with γ set, x and y are mapped by ``g(v) = sign(v)·|v|^(1/γ)`` before everything
  (signed, because SH coefficients and basis vectors can be negative) and the result by ``g⁻¹``.

References
----------
.. [PRT] L. Belcour, T. Deliot, W. Barbier, C. Soler, "A Data-Driven Paradigm for Precomputed Radiance
   Transfer", SIGGRAPH 2022 (``../shared/papers/data-driven-prt.txt``).
.. [Yuksel15] C. Yuksel, "Sample Elimination for Generating Poisson Disk Sample Sets", CGF 34(2), 2015.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "random_light_configurations", "area_samples", "sample_elimination", "min_spacing", "group_mean",
    "gamma_encode", "gamma_decode", "PrtFit", "fit", "reconstruct", "project", "pack_rgba", "unpack_rgba",
    "chart_layout", "rasterize", "dilate",
]

SPOT_OUTER_RANGE = (math.pi / 8, math.pi / 3)
"""radians: a random spot's outer cone angle is uniform in this range; the inner one is half of it."""
PLACEMENT_TRIES = 64
"""redraws of a point/spot light position that falls inside geometry."""
OUTLIER_RATIO = 10.0
"""A training column whose normalized indirect ‖y‖/‖x‖ exceeds this many times the median is left out
of the fit: its light is almost unseen by the measurement points (PRT §7, "sparse illumination
measurement"), and one such column can own the mean and the first basis vector."""


# --------------------------------------------------------------------------------------------- lights
def random_light_configurations(rng: np.random.Generator, scenario: dict, n: int, box_min, box_max,
                                inside=None, target_box=None) -> list[list[dict]]:
    """N random lighting configurations from a scenario (PRT §4.1 "Database Creation").

    Parameters
    ----------
    rng : numpy Generator (seeded by the caller)
    scenario : dict
        ``proto.models.LightRange`` as a dict: ``types``, ``count`` (lights per configuration),
        ``color_min``/``color_max`` (per channel, linear RGB), ``intensity_min``/``intensity_max``
        (candela for point/spot, lux for directional).
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
                p = rng.uniform(lo, hi)
                for _ in range(PLACEMENT_TRIES):
                    if inside is None or not bool(np.asarray(inside(p[None].astype(np.float32)))[0]):
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


def group_mean(values, offsets) -> np.ndarray:
    """Mean of consecutive row groups: rows ``offsets[g]:offsets[g+1]`` of ``values`` (K, ...) -> (G, ...).

    The §5.1 downscaling of supersampled direct illumination (every group non-empty)."""
    v = np.asarray(values)
    off = np.asarray(offsets, np.int64)
    sums = np.add.reduceat(v, off[:-1], axis=0)
    cnt = np.diff(off).reshape((-1,) + (1,) * (v.ndim - 1))
    return sums / cnt


# --------------------------------------------------------------------------------------------- gamma
def gamma_encode(v, gamma: float | None) -> np.ndarray:
    """``sign(v)·|v|^(1/γ)`` (PRT §5.3, signed); identity when gamma is None."""
    v = np.asarray(v)
    if gamma is None:
        return v
    return np.sign(v) * np.abs(v) ** (1.0 / gamma)


def gamma_decode(v, gamma: float | None) -> np.ndarray:
    """Inverse of :func:`gamma_encode`: ``sign(v)·|v|^γ``."""
    v = np.asarray(v)
    if gamma is None:
        return v
    return np.sign(v) * np.abs(v) ** gamma


# --------------------------------------------------------------------------------------- basis + fit
@dataclass
class PrtFit:
    """A fitted transfer (see the module doc).

    slots : (n, L) mono or (n, L, 3) multi, float32 — slot 0 the mean, then orthonormal basis vectors.
    transfer : (3, n, M + 1) mono (one per colour channel) or (1, n, 3M + 1) multi, float32, acting on
        ``[x, ‖x‖]``; row 0 is ``[0, …, 0, 1]``. Multi-channel direct vectors are interleaved
        ``[x0r, x0g, x0b, x1r, ...]``.
    singular : (r,) float64 — all singular values of the mean-subtracted normalized dataset.
    gamma, channels : as fitted. columns : training columns used (zero direct norms and outliers, see
    :data:`OUTLIER_RATIO`, are dropped); dropped : outlier columns left out.
    """

    slots: np.ndarray
    transfer: np.ndarray
    singular: np.ndarray
    gamma: float | None
    channels: str
    columns: int
    dropped: int = 0

    @property
    def n(self) -> int:
        return int(self.slots.shape[0])

    def truncated(self, n: int) -> "PrtFit":
        """The same fit with only the first n slots (SVD truncation and ridge rows are nested)."""
        return PrtFit(self.slots[:n], self.transfer[:, :n], self.singular, self.gamma, self.channels, self.columns,
                      self.dropped)


def _columns(direct, target, gamma, channels):
    """Training columns: (d (K, Mdim), y (K, Ldim), channel (K,)) in gamma space, unnormalized."""
    D = gamma_encode(np.asarray(direct, np.float64), gamma)   # (N, M, 3)
    Y = gamma_encode(np.asarray(target, np.float64), gamma)   # (N, L, 3)
    N = D.shape[0]
    if channels == "mono":  # PRT §5.2: colour channels as separate vectors
        d = D.transpose(2, 0, 1).reshape(3 * N, -1)
        y = Y.transpose(2, 0, 1).reshape(3 * N, -1)
        ch = np.repeat(np.arange(3), N)
    else:
        d = D.reshape(N, -1)
        y = Y.reshape(N, -1)
        ch = np.zeros(N, np.int64)
    return d, y, ch


def _ridge_solve(C, Dt, ridge: float):
    """``[M, b]`` with ``C ≈ M Dtᵀ + b 1ᵀ``: PRT eq 14 on centred data plus an intercept.

    C : (r, K) coefficients, Dt : (K, Mdim) normalized direct vectors as rows. With the centred
    D = (Dt - mean)ᵀ = P S Qᵀ (SVD), ``M = C_c (DᵀD + λI)⁻¹ Dᵀ = C_c Q diag(s / (s² + λ)) Pᵀ`` (eq 14;
    the pseudo-inverse of eq 13 when λ = 0, singular values below max(K, Mdim)·ε·s_max dropped) and
    ``b = mean(C) - M·mean(Dt)``. Returns (r, Mdim + 1).
    """
    dm = Dt.mean(axis=0)
    cm = C.mean(axis=1)
    Q, s, Pt = np.linalg.svd(Dt - dm, full_matrices=False)   # Dt - dm = Q S Pᵀ
    if ridge > 0:
        f = s / (s * s + ridge)
    else:
        cut = max(Dt.shape) * np.finfo(np.float64).eps * (s[0] if s.size else 0.0)
        f = np.where(s > cut, 1.0 / np.where(s > cut, s, 1.0), 0.0)
    M = ((C - cm[:, None]) @ Q) * f @ Pt                      # eq 14
    return np.concatenate([M, (cm - M @ dm)[:, None]], axis=1)


def fit(direct, target, n: int, ridge: float = 1e-3, gamma: float | None = None, channels: str = "mono") -> PrtFit:
    """Basis and transfer from a dataset (PRT §4.2, eq 7-10 and 14).

    Parameters
    ----------
    direct : (N, M, 3) float — direct vectors x_k (outgoing radiance at the measurement points).
    target : (N, L, 3) float — indirect vectors y_k (any linear quantity per slot and channel).
    n : int >= 1 — slots kept, the mean included (so n - 1 singular vectors; fewer when the data has
        fewer non-zero singular values, the remaining slots then being zero).
    ridge : λ of eq 14, relative to unit-norm direct vectors (0: pseudo-inverse, eq 13).
    gamma : exponent of §5.3, or None for linear space.
    channels : "mono" (§5.2: shared basis, one transfer per channel) or "multi".
    """
    if channels not in ("mono", "multi"):
        raise ValueError(f"fit: channels must be 'mono' or 'multi', got {channels!r}")
    direct = np.asarray(direct)
    target = np.asarray(target)
    if direct.ndim != 3 or target.ndim != 3 or direct.shape[2] != 3 or target.shape[2] != 3 \
            or direct.shape[0] != target.shape[0]:
        raise ValueError(f"fit: direct (N, M, 3) and target (N, L, 3) expected, got {direct.shape}, {target.shape}")
    if n < 1:
        raise ValueError("fit: n must be >= 1")
    d, y, ch = _columns(direct, target, gamma, channels)
    norm = np.linalg.norm(d, axis=1)
    keep = norm > 1e-12 * max(float(norm.max(initial=0.0)), 1e-300)
    d, y, ch, norm = d[keep], y[keep], ch[keep], norm[keep]
    L = y.shape[1]
    n_ch = 3 if channels == "mono" else 1
    mdim = d.shape[1]
    slots = np.zeros((n, L), np.float64)
    transfer = np.zeros((n_ch, n, mdim + 1), np.float64)
    transfer[:, 0, mdim] = 1.0                               # u_0 = ‖x‖: the mean's coefficient (§4.2)
    if d.shape[0] == 0:
        return PrtFit(_shape_slots(slots, channels), transfer.astype(np.float32), np.zeros(0), gamma, channels, 0)
    dn = d / norm[:, None]                                   # PRT §4.2: normalize by the direct norm
    yn = y / norm[:, None]
    ratio = np.linalg.norm(yn, axis=1)
    sane = ratio <= OUTLIER_RATIO * np.median(ratio)
    dropped = int((~sane).sum())
    d, dn, yn, ch = d[sane], dn[sane], yn[sane], ch[sane]
    mean = yn.mean(axis=0)                                   # PRT §4.2: mean-subtracted
    Z = yn - mean
    # SVD of Zᵀ (L x K) through the K x K Gram matrix (Turk & Pentland 1991; PRT §4.2)
    G = np.zeros((Z.shape[0], Z.shape[0]))
    for a in range(0, L, 8192):
        blk = Z[:, a:a + 8192]
        G += blk @ blk.T
    ev, V = np.linalg.eigh(G)
    ev, V = ev[::-1], V[:, ::-1]
    sing = np.sqrt(np.clip(ev, 0.0, None))
    tol = max(G.shape) * np.finfo(np.float64).eps * (sing[0] ** 2 if sing.size else 0.0)
    r = int(min(n - 1, np.count_nonzero(ev > max(tol, 0.0))))
    slots[0] = mean
    if r:
        U = (Z.T @ V[:, :r]) / sing[:r]                      # eq 7: Zᵀ = U Σ Vᵀ
        U /= np.linalg.norm(U, axis=0)                      # re-orthonormalize against Gram round-off
        flip = np.sign(U[np.abs(U).argmax(axis=0), np.arange(r)])
        U *= np.where(flip == 0, 1.0, flip)                  # deterministic signs
        slots[1:1 + r] = U.T
        C = U.T @ Z.T                                        # eq 8: coefficients C_n (r x K)
        for c in range(n_ch):
            sel = ch == c
            if sel.any():
                transfer[c, 1:1 + r] = _ridge_solve(C[:, sel], dn[sel], ridge)   # eq 14 per channel (§5.2)
    return PrtFit(_shape_slots(slots, channels), transfer.astype(np.float32), sing, gamma, channels,
                  int(d.shape[0]), dropped)


def _shape_slots(slots, channels):
    s = slots.astype(np.float32)
    return s if channels == "mono" else s.reshape(s.shape[0], -1, 3)


def _coefficients(fitted: PrtFit, x):
    """(n, C) coefficients and the gamma-space direct of (M, 3) x; C = 3 (mono) or 1 (multi)."""
    xg = gamma_encode(np.asarray(x, np.float64), fitted.gamma)
    T = fitted.transfer.astype(np.float64)
    if fitted.channels == "mono":
        xa = np.concatenate([xg, np.linalg.norm(xg, axis=0)[None]], axis=0)   # [x_c, ‖x_c‖]
        return np.einsum("cnm,mc->nc", T, xa)                # u_c = T_c x⁺_c (eq 10, one per channel)
    flat = xg.reshape(-1)
    return (T[0] @ np.append(flat, np.linalg.norm(flat)))[:, None]


def reconstruct(fitted: PrtFit, x) -> np.ndarray:
    """y ≈ g⁻¹(‖x‖·μ + U·M x) for a direct vector x (M, 3): (L, 3) float64 (PRT eq 10 + §4.2, §5.3)."""
    u = _coefficients(fitted, x)
    S = fitted.slots.astype(np.float64)
    if fitted.channels == "mono":
        y = S.T @ u                                          # (L, n) @ (n, 3)
    else:
        y = np.einsum("nlc,n->lc", S, u[:, 0])
    return gamma_decode(y, fitted.gamma)


def project(fitted: PrtFit, x, y) -> np.ndarray:
    """The best the basis can do for a known result: ``‖x‖·μ + U·Uᵀ(y/‖x‖ - μ)``·‖x‖ in gamma space.

    The mean keeps its coefficient ‖x‖ and the rest of y is projected orthogonally onto the basis
    vectors (the "projecting the reference in the basis" curve of PRT Fig 14). x (M, 3), y (L, 3).
    """
    xg = gamma_encode(np.asarray(x, np.float64), fitted.gamma)
    yg = gamma_encode(np.asarray(y, np.float64), fitted.gamma)
    S = fitted.slots.astype(np.float64)
    if fitted.channels == "mono":
        nx = np.linalg.norm(xg, axis=0)                      # (3,)
        mu, U = S[0], S[1:]
        res = yg - nx * mu[:, None]
        out = nx * mu[:, None] + U.T @ (U @ res)
    else:
        nx = np.linalg.norm(xg)
        mu, U = S[0].reshape(-1), S[1:].reshape(S.shape[0] - 1, -1)
        res = yg.reshape(-1) - nx * mu
        out = (nx * mu + U.T @ (U @ res)).reshape(yg.shape)
    return gamma_decode(out, fitted.gamma)


# ------------------------------------------------------------------------------------------- packing
def pack_rgba(slots) -> np.ndarray:
    """(n, ...) mono slots -> (ceil(n/4), ..., 4) float32: four basis slots per RGBA texel (PRT §5.2)."""
    s = np.asarray(slots, np.float32)
    g = -(-s.shape[0] // 4)
    pad = np.zeros((4 * g,) + s.shape[1:], np.float32)
    pad[:s.shape[0]] = s
    return np.ascontiguousarray(np.moveaxis(pad.reshape((g, 4) + s.shape[1:]), 1, -1))


def unpack_rgba(groups, n: int) -> np.ndarray:
    """Inverse of :func:`pack_rgba`: (G, ..., 4) -> (n, ...)."""
    a = np.asarray(groups)
    s = np.moveaxis(a, -1, 1)
    return np.ascontiguousarray(s.reshape((-1,) + a.shape[1:-1])[:n])


# ------------------------------------------------------------------------------------------ lightmap
def _shelf_pack(sizes, res: int):
    """Place (w, h) integer rectangles in a res x res square, tallest first, left to right in shelves.

    Returns (k, 2) offsets (x, y) or None when they do not fit."""
    order = sorted(range(len(sizes)), key=lambda i: (-sizes[i][1], -sizes[i][0], i))
    off = np.zeros((len(sizes), 2), np.int64)
    x = y = shelf = 0
    for i in order:
        w, h = sizes[i]
        if w > res or h > res:
            return None
        if x + w > res:
            x, y, shelf = 0, y + shelf, 0
        if y + h > res:
            return None
        off[i] = (x, y)
        x += w
        shelf = max(shelf, h)
    return off


def chart_layout(triangles, uv, chart, res: int, padding: int = 2):
    """Pack UV charts into one res x res lightmap at a uniform texel density.

    Each chart (triangles sharing a ``chart`` id >= 0, each with its own UV space, e.g. one glTF
    node's TEXCOORD_1) keeps its internal layout; its UV bounding box is scaled by
    √(world area / UV area) so texels cover the same area everywhere, the boxes are shelf-packed with
    ``padding`` texels around each, and the largest density that fits is found by bisection.

    Parameters
    ----------
    triangles : (T, 3, 3) float, metres; uv : (T, 3, 2) float; chart : (T,) int (-1: not in the map).

    Returns
    -------
    atlas_uv : (T, 3, 2) float32 — lightmap UVs (texel (row r, col c) centred at
        ``((c + 0.5)/res, (r + 0.5)/res)``, glTF convention: v runs down the rows); zeros for chart -1
        and for charts with no UV area.
    texels_per_metre : float
    """
    tri = np.asarray(triangles, np.float64)
    uv = np.asarray(uv, np.float64)
    chart = np.asarray(chart)
    out = np.zeros(uv.shape, np.float32)
    wa = triangle_areas(tri)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    ua = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    ids, lo, ext, scale = [], [], [], []
    for c in np.unique(chart[chart >= 0]):
        sel = chart == c
        a_uv, a_w = ua[sel].sum(), wa[sel].sum()
        if not (a_uv > 0 and a_w > 0):
            continue
        pts = uv[sel].reshape(-1, 2)
        ids.append(c)
        lo.append(pts.min(axis=0))
        ext.append(np.maximum(pts.max(axis=0) - pts.min(axis=0), 1e-9))
        scale.append(math.sqrt(a_w / a_uv))                  # metres per UV unit
    if not ids:
        return out, 0.0
    lo, ext, scale = np.array(lo), np.array(ext), np.array(scale)
    metres = ext * scale[:, None]                              # chart box size, metres

    def sizes(rho):
        return [(int(math.ceil(w * rho)) + 2 * padding, int(math.ceil(h * rho)) + 2 * padding) for w, h in metres]

    lo_r, hi_r = 0.0, res / max(float(metres.max()), 1e-12)
    for _ in range(40):                                      # bisection on the texel density
        mid = 0.5 * (lo_r + hi_r)
        if _shelf_pack(sizes(mid), res) is not None:
            lo_r = mid
        else:
            hi_r = mid
    rho = lo_r
    offsets = _shelf_pack(sizes(rho), res)
    if offsets is None or rho <= 0:
        return out, 0.0
    for k, c in enumerate(ids):
        sel = chart == c
        texel = offsets[k] + padding + (uv[sel] - lo[k]) * scale[k] * rho   # texel-space coordinates
        out[sel] = (texel / res).astype(np.float32)
    return out, float(rho)


def rasterize(atlas_uv, res: int):
    """Texels whose centre lies in a triangle's lightmap footprint.

    Parameters
    ----------
    atlas_uv : (T, 3, 2) float, lightmap UVs (see :func:`chart_layout`); all-zero rows are skipped.

    Returns
    -------
    tri : (res, res) int32, the triangle covering each texel centre (row = v, col = u), -1 if none
        (where footprints overlap, the later triangle wins);
    bary : (res, res, 2) float32, its barycentrics (u, v) in the ray-hit convention
        ``x = (1 - u - v)·v0 + u·v1 + v·v2``.
    """
    uvs = np.asarray(atlas_uv, np.float64) * res
    tri_map = np.full((res, res), -1, np.int32)
    bary = np.zeros((res, res, 2), np.float32)
    lo = np.floor(uvs.min(axis=1) - 0.5).astype(np.int64).clip(0, res - 1)
    hi = np.ceil(uvs.max(axis=1) - 0.5).astype(np.int64).clip(0, res - 1)
    live = np.any(uvs != 0, axis=(1, 2))
    for t in np.flatnonzero(live):
        (x0, y0), (x1, y1), (x2, y2) = uvs[t]
        det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if det == 0:
            continue
        cols = np.arange(lo[t, 0], hi[t, 0] + 1)
        rows = np.arange(lo[t, 1], hi[t, 1] + 1)
        px = cols[None, :] + 0.5
        py = rows[:, None] + 0.5
        bu = ((px - x0) * (y2 - y0) - (x2 - x0) * (py - y0)) / det
        bv = ((x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)) / det
        eps = -1e-9
        inside = (bu >= eps) & (bv >= eps) & (bu + bv <= 1 - eps)
        if not inside.any():
            continue
        rr, cc = np.nonzero(inside)
        tri_map[rows[rr], cols[cc]] = t
        bary[rows[rr], cols[cc], 0] = bu[rr, cc]
        bary[rows[rr], cols[cc], 1] = bv[rr, cc]
    return tri_map, bary


def dilate(images, mask, iterations: int = 2):
    """Grow images into empty texels: each pass fills every empty texel with a filled 8-neighbour by the
    mean of its filled neighbours (a linear operation, so it commutes with weighted sums of images —
    dilating the basis dilates every relit lightmap).

    images : (..., H, W) float; mask : (H, W) bool, True where filled. Returns (dilated images, new mask).
    """
    img = np.array(images, np.float32, copy=True)
    m = np.asarray(mask, bool).copy()
    H, W = m.shape
    for _ in range(iterations):
        acc = np.zeros_like(img)
        cnt = np.zeros((H, W), np.float32)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy == 0 and dx == 0:
                    continue
                ys = slice(max(dy, 0), H + min(dy, 0))
                yd = slice(max(-dy, 0), H + min(-dy, 0))
                xs = slice(max(dx, 0), W + min(dx, 0))
                xd = slice(max(-dx, 0), W + min(-dx, 0))
                src = m[ys, xs]
                acc[..., yd, xd] += img[..., ys, xs] * src
                cnt[yd, xd] += src
        grow = ~m & (cnt > 0)
        if not grow.any():
            break
        img[..., grow] = acc[..., grow] / cnt[grow]
        m |= grow
    return img, m
