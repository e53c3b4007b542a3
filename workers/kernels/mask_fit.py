"""Mask Decomposition, masks: per-sample fit, light-aware refit, fill and filter, cluster volumes (MD §3.4.1).

Given the colouring g (:mod:`workers.kernels.coloring`), eq 3 ``L(x) = Σ_k m_k(x) · Σ_i φ_i(x) g_i^k P_i``
needs a K-channel mask m(x) per refined-grid sample. This module computes it, numpy / numba only, no I/O
(stages/masks.py calls it):

1. :func:`fit_masks` — m per refined-grid sample minimizing eq 5 locally (§3.4 step 4),
   :func:`light_aware_fit` (eq 9, step 5), :func:`fill_dont_care`, :func:`gaussian_filter` (step 6);
2. :func:`mask_residual` (eq 5), :func:`quantize` (RGBA8), :func:`canonicalize` (free values to 0 for
   compression, §3.4.2), :func:`cluster_volumes` (per-cluster SH and weight volumes of eq 3).

The refined grid, θ layout and OFF probes: :mod:`workers.kernels.mask_field`. Sums over x are over
care samples, each weighing 1 (in samples, as in :mod:`workers.kernels.coloring`).

References
----------
.. [MD] J. Zhou, Y. Chen, Y. Li, S. Cao, Y. Wu, X. Jin, "Fast Probe-Leaking Elimination Using Mask
   Decomposition" (``../shared/papers/mask-decomposition.txt``).
"""
from __future__ import annotations

import numba
import numpy as np

from workers.kernels.mask_field import (check_counts, check_field, check_labels, corner_probe, corner_weight,
                                        field_fractions, off_flags)

__all__ = ["rgba_group", "fit_masks", "mask_residual", "light_aware_fit", "fill_dont_care", "gaussian_filter", "quantize",
           "cluster_volumes", "canonicalize", "half_volume"]


# ---------------------------------------------------------------------- 1. masks (eq 5)
@numba.njit(cache=True, inline="always")
def _weighted_median(v, w, n):
    """argmin_m Σ w_i |v_i − m| over the first n entries (w ≥ 0, Σ w > 0); sorts v, w in place.

    The lower weighted median; where the cumulative weight hits exactly half the total, every value
    between two consecutive sorted v is optimal and the midpoint is taken.
    """
    for a in range(1, n):  # insertion sort by v (n ≤ 8)
        va, wa = v[a], w[a]
        b = a - 1
        while b >= 0 and v[b] > va:
            v[b + 1], w[b + 1] = v[b], w[b]
            b -= 1
        v[b + 1], w[b + 1] = va, wa
    total = 0.0
    for a in range(n):
        total += w[a]
    half = 0.5 * total
    tol = 1e-12 * total
    cum = 0.0
    for a in range(n):
        cum += w[a]
        if cum >= half - tol:
            if abs(cum - half) <= tol and a + 1 < n:
                return 0.5 * (v[a] + v[a + 1])
            return v[a]
    return v[n - 1]


@numba.njit(cache=True, nogil=True)
def _fit_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, K, out):
    Z, Y, X = dc.shape
    vals = np.empty((K, 8))
    wts = np.empty((K, 8))
    cnt = np.zeros(K, np.int64)
    for z in range(Z):
        for y in range(Y):
            for x in range(X):
                if dc[z, y, x]:
                    continue
                cnt[:] = 0
                for c in range(8):
                    p = corner_probe(cx[x], cy[y], cz[z], c, nx, ny, nz)
                    ph = corner_weight(c, tx[x], ty[y], tz[z])
                    if off[p] or ph <= 0.0:
                        continue
                    k = g[p]
                    vals[k, cnt[k]] = theta[z, y, x, c] * (1.0 / 255.0)
                    wts[k, cnt[k]] = ph
                    cnt[k] += 1
                for k in range(K):
                    # MD eq 5 per cluster: argmin_m Σ_{i: g_i = k} φ_i |θ_i − m|, the φ-weighted median
                    out[z, y, x, k] = _weighted_median(vals[k], wts[k], cnt[k]) if cnt[k] > 0 else 0.0


def fit_masks(theta, dont_care, counts, S, g, K: int, states=None) -> np.ndarray:
    """Masks m minimizing MD eq 5 locally at every care sample, given the colouring g (§3.4 step 4).

    With g one-hot, ``m·g_i = m_{g_i}`` and eq 5 at a sample splits by cluster:
    ``Σ_k Σ_{i: g_i = k} φ_i |θ_i − m_k|``. Each term is minimized over m_k ∈ [0, 1] by the
    φ-weighted median of the θ of cluster k's (non-OFF) corners of the sample's cell — exact, so with
    one corner per cluster (K = 8, parity colouring) ``m_k = θ`` of that corner and eq 5 is 0 (§3.2).
    A cluster with no corner in the cell gets 0 (any value is optimal; 0 keeps m sparse). Don't-care
    samples are left at 0 (see :func:`fill_dont_care`).

    Returns m : (Z, Y, X, K) float32 in [0, 1].
    """
    theta, dc, counts, S, _ = check_field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    P = nx * ny * nz
    K = int(K)
    g = check_labels(g, P, K)
    off = off_flags(states, P)
    cx, cy, cz, tx, ty, tz = field_fractions(counts, S)
    out = np.zeros(dc.shape + (K,), np.float32)
    _fit_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, K, out)
    return out


@numba.njit(cache=True, nogil=True)
def _residual_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, m):
    Z, Y, X = dc.shape
    r = 0.0
    mass = 0.0
    for z in range(Z):
        for y in range(Y):
            for x in range(X):
                if dc[z, y, x]:
                    continue
                for c in range(8):
                    p = corner_probe(cx[x], cy[y], cz[z], c, nx, ny, nz)
                    if off[p]:
                        continue
                    ph = corner_weight(c, tx[x], ty[y], tz[z])
                    th = theta[z, y, x, c] * (1.0 / 255.0)
                    r += ph * abs(th - m[z, y, x, g[p]])  # MD eq 5
                    mass += ph * th
    return r, mass


def mask_residual(theta, dont_care, counts, S, g, masks, states=None) -> tuple[float, float]:
    """``(R̂, Σ φθ)``: MD eq 5 ``Σ_x Σ_i φ_i |θ_i − m·g_i|`` over care samples and non-OFF probes, and
    the visible mass ``Σ_x Σ_i φ_i θ_i`` (for a relative residual), both in samples.

    masks : (Z, Y, X, K) float in [0, 1], or uint8 (read as byte / 255, as the shader reads them).
    """
    theta, dc, counts, S, _ = check_field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    m = np.asarray(masks)
    # bytes read with the same arithmetic as θ (byte · (1/255)), so equal bytes give exactly 0
    m = m.astype(np.float64) * (1.0 / 255.0) if m.dtype == np.uint8 else m.astype(np.float64)
    if m.shape[:3] != dc.shape:
        raise ValueError(f"masks must have shape {dc.shape + ('K',)}, got {m.shape}")
    K = m.shape[3]
    g = check_labels(g, nx * ny * nz, K)
    off = off_flags(states, nx * ny * nz)
    cx, cy, cz, tx, ty, tz = field_fractions(counts, S)
    r, mass = _residual_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, np.ascontiguousarray(m))
    return float(r), float(mass)


@numba.njit(cache=True, nogil=True)
def _light_fit_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, sh, K, m, lam_scaled, iters,
                      A, b, G, h, pen):
    """Per care sample: coordinate descent on ‖A m − b‖² + λ'·Σ_k pen_k m_k, 0 ≤ m ≤ 1 (eq 9)."""
    Z, Y, X = dc.shape
    D = sh.shape[1]
    before = 0.0
    after = 0.0
    for z in range(Z):
        for y in range(Y):
            for x in range(X):
                if dc[z, y, x]:
                    continue
                A[:, :] = 0.0
                b[:] = 0.0
                wsum = 0.0
                for c in range(8):
                    p = corner_probe(cx[x], cy[y], cz[z], c, nx, ny, nz)
                    if off[p]:
                        continue
                    ph = corner_weight(c, tx[x], ty[y], tz[z])
                    th = theta[z, y, x, c] * (1.0 / 255.0)
                    k = g[p]
                    for d in range(D):
                        A[d, k] += ph * sh[p, d]        # cluster k's volume at x: Σ_i φ_i g_i^k P_i (MD eq 3)
                        b[d] += th * ph * sh[p, d]      # MD eq 2
                    wsum += th * ph
                if wsum > 0.0:
                    for d in range(D):
                        b[d] /= wsum                    # normalized as RTXGI: the reference L(x)
                else:
                    b[:] = 0.0
                for k in range(K):
                    pen[k] = 1.0 if m[z, y, x, k] == 0.0 else 0.0   # MD eq 9: channels 0 before the fit
                    hk = 0.0
                    for d in range(D):
                        hk += A[d, k] * b[d]
                    h[k] = hk
                    for j in range(K):
                        s = 0.0
                        for d in range(D):
                            s += A[d, k] * A[d, j]
                        G[k, j] = s
                bb = 0.0
                for d in range(D):
                    bb += b[d] * b[d]
                before += _objective(G, h, bb, m[z, y, x], pen, lam_scaled, K)
                for _ in range(iters):
                    change = 0.0
                    for k in range(K):
                        if G[k, k] <= 0.0:
                            continue  # the cluster has no probe in this cell: m_k cannot matter
                        r = h[k] - 0.5 * lam_scaled * pen[k]
                        for j in range(K):
                            if j != k:
                                r -= G[k, j] * m[z, y, x, j]
                        v = min(max(r / G[k, k], 0.0), 1.0)
                        change = max(change, abs(v - m[z, y, x, k]))
                        m[z, y, x, k] = v
                    if change < 1e-7:
                        break
                after += _objective(G, h, bb, m[z, y, x], pen, lam_scaled, K)
    return before, after


@numba.njit(cache=True, inline="always")
def _objective(G, h, bb, mv, pen, lam_scaled, K):
    """MD eq 9 at one sample: ‖A m − b‖² + λ'·Σ_k pen_k m_k, with G = AᵀA, h = Aᵀb, bb = ‖b‖²."""
    s = bb
    for k in range(K):
        s -= 2.0 * h[k] * mv[k]
        s += lam_scaled * pen[k] * mv[k]
        for j in range(K):
            s += mv[k] * G[k, j] * mv[j]
    return s


def light_aware_fit(masks, theta, dont_care, counts, S, g, probe_sh, *, penalty: float = 0.001, states=None,
                    iterations: int = 100) -> tuple[np.ndarray, dict]:
    """Refit the masks to the light field, MD eq 9 (§3.4 step 5), per care sample.

    Minimizes, independently at every care sample x,
    ``‖Σ_k m_k C_k(x) − L(x)‖² / s + λ·Σ_k 1[m_k^init = 0]·m_k`` over ``0 ≤ m_k ≤ 1``, where
    ``C_k(x) = Σ_i φ_i g_i^k P_i`` (cluster k's volume at x), ``L(x) = Σ θ_i φ_i P_i / Σ θ_i φ_i``
    (eq 2 normalized as RTXGI; 0 where nothing is visible), P the probes' L1 radiance SH of the
    three colour channels (12 numbers), ``m^init`` the eq-5 masks, ``s`` the mean of ‖L(x)‖² over the
    care samples (so λ is dimensionless: the same penalty works whatever the light units), and
    ``|m_k| = m_k`` since m ≥ 0. The upper bound 1 is the RGBA8 storage range. It is a convex QP in K
    ≤ 8 unknowns, solved exactly (to 1e-7) by cyclic coordinate descent with clamping, starting from
    the eq-5 masks (so it never ends above their loss). Only the unnormalized ``mask`` mode is
    targeted (eq 3); clusters absent from the cell keep m = 0.

    Parameters
    ----------
    masks : (Z, Y, X, K) float32, the eq-5 masks (:func:`fit_masks`); not modified.
    probe_sh : (P, 4, 3) or (P, 9, 3) float radiance SH per probe (L1 part used; OFF probes ignored).
    penalty : λ of eq 9.

    Returns ``(masks (Z, Y, X, K) float32, {"loss_before", "loss_after", "scale"})`` (losses are
    eq 9 summed over care samples, in units of s).
    """
    theta, dc, counts, S, _ = check_field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    P = nx * ny * nz
    m = np.array(masks, np.float64, copy=True)
    if m.shape[:3] != dc.shape:
        raise ValueError(f"masks must have shape {dc.shape + ('K',)}, got {m.shape}")
    K = m.shape[3]
    g = check_labels(g, P, K)
    off = off_flags(states, P)
    sh = np.asarray(probe_sh, np.float64)
    if sh.ndim != 3 or sh.shape[0] != P or sh.shape[1] not in (4, 9):
        raise ValueError(f"probe_sh must be (P = {P}, 4 | 9, C), got {sh.shape}")
    sh = np.ascontiguousarray(sh[:, :4, :].reshape(P, -1))
    cx, cy, cz, tx, ty, tz = field_fractions(counts, S)
    D = sh.shape[1]
    bufs = (np.empty((D, K)), np.empty(D), np.empty((K, K)), np.empty(K), np.empty(K))
    # s = mean ‖L(x)‖² over the care samples: the objective of m = 0 with λ = 0 and no iterations
    zero = np.zeros_like(m)
    ssum, _ = _light_fit_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, sh, K, zero, 0.0, 0, *bufs)
    n_care = int((~dc).sum())
    scale = ssum / n_care if n_care else 0.0
    if scale <= 0.0:
        return m.astype(np.float32), {"loss_before": 0.0, "loss_after": 0.0, "scale": 0.0}
    before, after = _light_fit_kernel(theta, dc, cx, cy, cz, tx, ty, tz, nx, ny, nz, g, off, sh, K, m,
                                      float(penalty) * scale, int(iterations), *bufs)
    return m.astype(np.float32), {"loss_before": before / scale, "loss_after": after / scale, "scale": scale}


@numba.njit(cache=True, nogil=True)
def _fill_kernel(m, dc, level, queue):
    """Multi-source BFS from the care samples over 6-neighbours; each don't-care sample gets the mean
    of its neighbours one BFS layer closer (already final when it is reached)."""
    Z, Y, X, K = m.shape
    head, tail = 0, 0
    for z in range(Z):
        for y in range(Y):
            for x in range(X):
                if dc[z, y, x]:
                    level[z, y, x] = -1
                else:
                    level[z, y, x] = 0
    # seed: don't-care samples next to a care sample
    for z in range(Z):
        for y in range(Y):
            for x in range(X):
                if level[z, y, x] != -1:
                    continue
                near = False
                for a in range(6):
                    zz, yy, xx = _nb(z, y, x, a)
                    if 0 <= zz < Z and 0 <= yy < Y and 0 <= xx < X and level[zz, yy, xx] == 0:
                        near = True
                if near:
                    level[z, y, x] = 1
                    queue[tail, 0], queue[tail, 1], queue[tail, 2] = z, y, x
                    tail += 1
    acc = np.zeros(K)
    while head < tail:
        z, y, x = queue[head, 0], queue[head, 1], queue[head, 2]
        head += 1
        L = level[z, y, x]
        acc[:] = 0.0
        n = 0
        for a in range(6):
            zz, yy, xx = _nb(z, y, x, a)
            if not (0 <= zz < Z and 0 <= yy < Y and 0 <= xx < X):
                continue
            lv = level[zz, yy, xx]
            if lv == L - 1:
                for k in range(K):
                    acc[k] += m[zz, yy, xx, k]
                n += 1
            elif lv == -1:
                level[zz, yy, xx] = L + 1
                queue[tail, 0], queue[tail, 1], queue[tail, 2] = zz, yy, xx
                tail += 1
        for k in range(K):
            m[z, y, x, k] = acc[k] / n
    return tail


@numba.njit(cache=True, inline="always")
def _nb(z, y, x, a):
    if a == 0:
        return z, y, x - 1
    if a == 1:
        return z, y, x + 1
    if a == 2:
        return z, y - 1, x
    if a == 3:
        return z, y + 1, x
    if a == 4:
        return z - 1, y, x
    return z + 1, y, x


def fill_dont_care(masks, dont_care) -> tuple[np.ndarray, int]:
    """Give don't-care samples (inside geometry) masks from their neighbours, in place.

    A shading point on a surface lies within half a sample of samples inside the solid; were those
    left at 0 (or at their meaningless θ, mostly 0 from inside), trilinear filtering would drag the
    surface's masks towards 0 and darken it. Instead the care values are pushed inward, like texture
    padding: by breadth-first layers over the 6-neighbours, each don't-care sample takes the mean of
    its neighbours in the previous layer (the closest filled samples). Don't-care samples with no care
    sample in their connected region keep 0. Eq 5-6 give these samples weight 0, so the fill changes
    no loss. masks (Z, Y, X, K) float (modified in place and returned); returns (masks, filled count).
    """
    m = masks
    dc = np.ascontiguousarray(np.asarray(dont_care).reshape(m.shape[:3]), bool)
    if not dc.any():
        return m, 0
    if not (~dc).any():
        m[...] = 0
        return m, 0
    level = np.empty(dc.shape, np.int32)
    queue = np.empty((int(dc.sum()), 3), np.int64)
    n = _fill_kernel(m, dc, level, queue)
    return m, int(n)


def _gauss_kernel(sigma: float) -> np.ndarray:
    r = max(int(4.0 * sigma + 0.5), 1)  # truncate at 4σ, as scipy.ndimage
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def gaussian_filter(masks, sigma: float, *, keep_zeros: bool = True) -> np.ndarray:
    """Separable Gaussian of standard deviation ``sigma`` samples over the three field axes (§3.4 step 6).

    Edges repeat the border sample (clamp-to-edge, as the texture is sampled); kernel truncated at
    4σ and normalized (scipy.ndimage.gaussian_filter with mode="nearest"). sigma = 0 returns the
    input unchanged. masks (Z, Y, X, K) float → float32.

    ``keep_zeros`` (our departure from MD step 6, on by default): a channel that is 0 at a sample
    stays 0 — the filter smooths a cluster's mask only where that cluster is (partly) visible. Filtering
    everything spreads the mask of a cluster behind a wall into the samples on the other side (one
    sample away: 11% of it at σ = 0.5), and trilinear filtering of the cluster's probes there brings
    their light through the wall; normalized mask GI amplifies it where the visible cluster's weight is
    small. On two-rooms (9x4x5, S = 8, K = 4) the mean |error| of normalized mask GI against the
    visibility-weighted reference in room B within 0.8 m of the wall is 0.25 (of 1.1) with plain
    filtering at σ = 0.5, 0.0007 unfiltered. Keeping zeros also keeps m sparse (fewer cluster fetches,
    better block merging in compression).
    """
    m = np.asarray(masks, np.float32)
    sigma = float(sigma)
    if sigma < 0:
        raise ValueError(f"sigma must be >= 0, got {sigma}")
    if sigma == 0:
        return m
    from scipy.ndimage import correlate1d

    k = _gauss_kernel(sigma)
    out = m.astype(np.float32)
    for axis in range(3):  # separable, clamp-to-edge ("nearest"); scipy's C loop, float32
        out = correlate1d(out, k.astype(np.float32), axis=axis, mode="nearest")  # MD §3.4.1 step 6
    if keep_zeros:
        out[m == 0] = 0.0
    return np.clip(out, 0.0, 1.0, out=out)


def quantize(masks) -> np.ndarray:
    """Masks in [0, 1] → uint8 ``round(255·m)`` (RGBA8 UNORM storage)."""
    m = np.clip(np.asarray(masks, np.float32), 0.0, 1.0)
    return np.rint(m * np.float32(255.0), out=m).astype(np.uint8)


# ---------------------------------------------------------------------- 2. cluster volumes
def cluster_volumes(sh_l1, g, K: int, states=None) -> tuple[list[np.ndarray], np.ndarray]:
    """Per-cluster probe volumes for eq 3 and normalized mask GI (DESIGN stage 4).

    Parameters
    ----------
    sh_l1 : (nz, ny, nx, 4, C) float
        L0 + L1 radiance SH per probe and colour channel (the light stage's ``sh_l1_{r,g,b}``
        stacked on the last axis).
    g : (P,) int colours; K : number of clusters; states : (P,) probe states (OFF gets 0).

    Returns
    -------
    sh : list of K arrays (nz, ny, nx, 4, C) float32
        ``g_i^k · P_i``: the SH of cluster k's probes, 0 elsewhere and at OFF probes.
    weights : (nz, ny, nx, K) float32
        ``g_i^k`` (1 for non-OFF probes of cluster k), so that trilinear filtering gives
        ``w_k(x) = Σ_i φ_i(x) g_i^k``.
    """
    sh = np.asarray(sh_l1, np.float32)
    nz, ny, nx = sh.shape[:3]
    P = nx * ny * nz
    g = check_labels(g, P, int(K))
    on = ~off_flags(states, P)
    weights = np.zeros((P, int(K)), np.float32)
    weights[np.arange(P)[on], g[on]] = 1.0
    weights = weights.reshape(nz, ny, nx, int(K))
    vols = [sh * weights[..., k][..., None, None] for k in range(int(K))]  # g_i^k · P_i of MD eq 3
    return vols, weights


def canonicalize(q: np.ndarray, dont_care: np.ndarray, counts, S: int, g, K: int, states=None) -> np.ndarray:
    """Give every mask value that no shading point needs one canonical value, 0, so that identical blocks
    merge in compression (MD §3.4.2) and the runtime skips the cluster (it samples only clusters whose
    mask is marked, m_k > 0: MD §1); returns a new (Z, Y, X, K) uint8 array.

    - Channel k of a cell none of whose non-OFF corners is in cluster k: eq 3 multiplies m_k by
      cluster k's trilinear probe volume, which is 0 everywhere in that cell (and so is w_k of the
      normalized variant), so m_k is free there. The runtime reads a cell's own samples only
      (:func:`workers.kernels.compress.mask_lookup_texel`), so the 0 never filters into a neighbour.
    - Don't-care samples (inside geometry) with no care sample among their 26 neighbours: only points
      inside geometry read them. Samples next to a surface keep their filled values.
    """
    from scipy.ndimage import binary_dilation

    cnt = check_counts(counts)
    nx, ny, nz = (int(c) for c in cnt)
    P = nx * ny * nz
    off = off_flags(states, P)                                               # (P,) True where OFF
    lab = check_labels(g, P, K)
    cx, cy, cz = (max(int(c) - 1, 1) for c in cnt)
    relevant = np.zeros((cz, cy, cx, K), bool)
    ck, cj, ci = np.meshgrid(np.arange(cz), np.arange(cy), np.arange(cx), indexing="ij")
    for c in range(8):
        i = np.minimum(ci + (c & 1), nx - 1)
        j = np.minimum(cj + ((c >> 1) & 1), ny - 1)
        k = np.minimum(ck + ((c >> 2) & 1), nz - 1)
        p = i + nx * (j + ny * k)
        live = ~off[p]
        np.put_along_axis(relevant, lab[p][..., None], (np.take_along_axis(relevant, lab[p][..., None], -1)
                                                         | live[..., None]), axis=-1)
    Z, Y, X = q.shape[:3]
    rel = relevant[np.arange(Z)[:, None, None] // S, np.arange(Y)[None, :, None] // S,
                   np.arange(X)[None, None, :] // S]                       # (Z, Y, X, K)
    out = np.where(rel, q, np.uint8(0))  # m_k = 0 unmarks cluster k (MD §1: sample marked volumes only)
    dc = np.asarray(dont_care, bool).reshape(Z, Y, X)
    deep = dc & ~binary_dilation(~dc, structure=np.ones((3, 3, 3), bool))
    out[deep] = 0
    return np.ascontiguousarray(out, np.uint8)


HALF_MAX = 65504.0  # the largest float16


def rgba_group(channels: np.ndarray, start: int) -> np.ndarray:
    """Channels ``start … start + 3`` of (..., K) as (..., 4), zero-padded past K: one RGBA volume of a group of four
    clusters (``masks_0123``, ``cluster_weights_4567``, …)."""
    out = np.zeros(channels.shape[:-1] + (4,), channels.dtype)
    part = channels[..., start:start + 4]
    out[..., :part.shape[-1]] = part
    return np.ascontiguousarray(out)


def half_volume(a, clamped: list) -> np.ndarray:
    """A probe volume as stored (proto/bundle.md 5.2, RGBA16F): float16 of ``a``, magnitudes beyond the half range
    clamped to ±65504 (their count added to ``clamped[0]``). Relative rounding error ≤ 2^-11."""
    a = np.asarray(a, np.float32)
    clamped[0] += int((np.abs(a) > HALF_MAX).sum())
    return np.ascontiguousarray(np.clip(a, -HALF_MAX, HALF_MAX).astype(np.float16))
