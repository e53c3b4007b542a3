"""Mask Decomposition, colouring: edge loss, probe colouring, simulated annealing (MD §3.2-3.3; DESIGN stage 4).

MD replaces the visibility-weighted blend of eq 2, ``L(x) = Σ_i θ_i(x) φ_i(x) P_i``, by eq 3,
``L(x) = Σ_k m_k(x) · Σ_i φ_i(x) g_i^k P_i``: the probes are split into K clusters by a one-hot
colouring g, each cluster is its own trilinearly filtered probe volume, and a K-channel mask m(x)
on the refined grid says how much of each cluster x sees. This module finds g, numpy / numba only,
no I/O (stages/anneal.py calls it; the masks for a g are :mod:`workers.kernels.mask_fit`):

1. :func:`edge_loss` — E(i, j) of eq 6 for every pair of probes sharing a cell, one pass over θ
   (§3.4 step 2);
2. :func:`convex_division`, :func:`parity_coloring`, :func:`anneal` — the colouring g (§3.3, eq 4,
   eq 7 + eq 8, simulated annealing from a convex division, §3.4 step 3); :func:`coloring_loss`,
   :func:`random_loss` score a colouring.

The refined grid, θ layout and OFF probes: :mod:`workers.kernels.mask_field`.

Sums over x (eq 5-9) are the paper's discrete sums over the samples that are not "don't care"
(each sample weighs 1, so E and R̂ are in **samples**: a sample whose two probes differ fully in θ
adds its min φ). With these units the paper's λ = 0.001 of eq 8 is tiny against any E that a
single sample makes, and does what MD §3.3.1 says it is for: among edges with E = 0 it prefers one
colour, so m stays sparse. (Normalizing the sums to cell volumes, 1/S³ per sample, would make the
same λ 512 times stronger at S = 8 and let eq 8 outweigh real visibility differences.)

References
----------
.. [MD] J. Zhou, Y. Chen, Y. Li, S. Cao, Y. Wu, X. Jin, "Fast Probe-Leaking Elimination Using Mask
   Decomposition" (``../shared/papers/mask-decomposition.txt``).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from workers.kernels.mask_field import (check_counts, check_field, check_labels, corner_probe, corner_weight,
                                        field_fractions, off_flags)

__all__ = ["HALF_DIRECTIONS", "edge_loss", "coloring_loss", "random_loss", "parity_coloring", "convex_division",
           "temperature_schedule", "anneal"]

_U = np.uint64
_GAMMA = _U(0x9E3779B97F4A7C15)
_M1 = _U(0xBF58476D1CE4E5B9)
_M2 = _U(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = _U(30), _U(27), _U(31), _U(11)
_INV53 = 1.0 / float(1 << 53)

# The 13 neighbour offsets (di, dj, dk) with a positive flat-index difference: a pair of probes
# sharing a cell is stored once, as (lower flat index, direction).
HALF_DIRECTIONS = np.array([(di, dj, dk) for dk in (-1, 0, 1) for dj in (-1, 0, 1) for di in (-1, 0, 1)
                            if (dk, dj, di) > (0, 0, 0)], np.int64)
# corner pairs of a cell, c1 < c2 (28)
_PAIRS = np.array([(a, b) for a in range(8) for b in range(a + 1, 8)], np.int64)


# ---------------------------------------------------------------------- 1. edge loss (eq 6)
@numba.njit(cache=True, nogil=True)
def _edge_cells(theta, dc, cx, cy, cz, tx, ty, tz, pairs, ncx, ncy, out):
    """out[cell, pair] += min(φ_a, φ_b)·|θ_a − θ_b| over the care samples of each cell (eq 6)."""
    Z, Y, X = dc.shape
    phi = np.empty(8)
    th = np.empty(8)
    for z in range(Z):
        for y in range(Y):
            for x in range(X):
                if dc[z, y, x]:
                    continue  # "don't care": weight 0
                for c in range(8):
                    phi[c] = corner_weight(c, tx[x], ty[y], tz[z])
                    th[c] = theta[z, y, x, c] * (1.0 / 255.0)
                cell = cx[x] + ncx * (cy[y] + ncy * cz[z])
                for q in range(pairs.shape[0]):
                    a, b = pairs[q, 0], pairs[q, 1]
                    out[cell, q] += min(phi[a], phi[b]) * abs(th[a] - th[b])  # eq 6


@numba.njit(cache=True)
def _edge_scatter(cell_loss, pairs, ncx, ncy, ncz, nx, ny, nz, dir_of, dense):
    """Sum the per-cell pair losses into dense[p_low, direction] (pairs of the same two probes merge)."""
    for ck in range(ncz):
        for cj in range(ncy):
            for ci in range(ncx):
                cell = ci + ncx * (cj + ncy * ck)
                for q in range(pairs.shape[0]):
                    pa = corner_probe(ci, cj, ck, pairs[q, 0], nx, ny, nz)
                    pb = corner_probe(ci, cj, ck, pairs[q, 1], nx, ny, nz)
                    if pa == pb:
                        continue  # corners merged on a one-probe axis
                    lo, hi = min(pa, pb), max(pa, pb)
                    di = hi % nx - lo % nx
                    dj = (hi // nx) % ny - (lo // nx) % ny
                    dk = hi // (nx * ny) - lo // (nx * ny)
                    d = dir_of[(di + 1) + 3 * ((dj + 1) + 3 * (dk + 1))]
                    dense[lo, d] += cell_loss[cell, q]


def edge_loss(theta, dont_care, counts, S, states=None) -> tuple[np.ndarray, np.ndarray]:
    """E(i, j) of MD eq 6 for every pair of probes sharing a cell, in one pass over θ.

    ``E(i, j) = Σ_x min(φ_i(x), φ_j(x)) · |θ_i(x) − θ_j(x)|`` over the care samples x of the cells
    holding both probes (θ as stored, byte / 255).

    Parameters
    ----------
    theta : (Z, Y, X, 8) uint8
        θ·255 per refined-grid sample and cell corner (:func:`join_theta`).
    dont_care : (Z, Y, X) or (Z, Y, X, 1) bool / uint8
        Samples inside geometry: weight 0.
    counts : (3,) int
        Probes per axis (nx, ny, nz).
    S : int
        Samples per cell axis.
    states : (P,) probe states, optional
        Edges touching an OFF probe are dropped (module doc).

    Returns
    -------
    pairs : (n_edges, 2) int32
        ``(i, j)`` flat probe indices, ``i < j``, every pair of non-OFF probes that share a cell (E = 0
        included: eq 8 counts them), sorted by (i, direction).
    weights : (n_edges,) float64
        E(i, j) ≥ 0, in samples (module doc).
    """
    theta, dc, counts, S, cells = check_field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    P = nx * ny * nz
    off = off_flags(states, P)
    ncx, ncy, ncz = (int(v) for v in cells)
    cx, cy, cz, tx, ty, tz = field_fractions(counts, S)
    cell_loss = np.zeros((ncx * ncy * ncz, len(_PAIRS)))
    _edge_cells(theta, dc, cx, cy, cz, tx, ty, tz, _PAIRS, ncx, ncy, cell_loss)
    dir_of = np.full(27, -1, np.int64)
    for d, (di, dj, dk) in enumerate(HALF_DIRECTIONS):
        dir_of[(di + 1) + 3 * ((dj + 1) + 3 * (dk + 1))] = d
    dense = np.zeros((P, len(HALF_DIRECTIONS)))
    _edge_scatter(cell_loss, _PAIRS, ncx, ncy, ncz, nx, ny, nz, dir_of, dense)
    # every pair sharing a cell: neighbour in bounds, no step along a one-probe axis
    p = np.arange(P)
    ijk = np.stack([p % nx, (p // nx) % ny, p // (nx * ny)], axis=1)
    nb = ijk[:, None, :] + HALF_DIRECTIONS[None, :, :]                     # (P, 13, 3)
    valid = np.all((nb >= 0) & (nb < counts), axis=2)
    lo_idx, d_idx = np.nonzero(valid)
    hi_idx = nb[lo_idx, d_idx, 0] + nx * (nb[lo_idx, d_idx, 1] + ny * nb[lo_idx, d_idx, 2])
    keep = ~off[lo_idx] & ~off[hi_idx]
    pairs = np.stack([lo_idx[keep], hi_idx[keep]], axis=1).astype(np.int32)
    return pairs, dense[lo_idx[keep], d_idx[keep]]


# ---------------------------------------------------------------------- 2. colouring (eq 4, 7, 8)
def coloring_loss(pairs, weights, g, regularization=0.0) -> tuple[float, float]:
    """``(eq 7, eq 8)`` of colouring g: ``Σ_edges 1[g_i = g_j]·E_ij`` and ``λ·Σ_edges 1[g_i ≠ g_j]``.

    Eq 8's ``λ/2 Σ_i Σ_{j∈N(i)}`` counts each unordered pair twice, hence λ per edge; N(i) is the
    set of probes sharing a cell with i (the edge list). pairs (n, 2) int, weights (n,), g (P,) int.
    """
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    w = np.asarray(weights, np.float64)
    g = np.asarray(g).reshape(-1)
    same = g[pairs[:, 0]] == g[pairs[:, 1]]
    return float(w[same].sum()), float(regularization) * float((~same).sum())  # MD eq 7, eq 8


def random_loss(pairs, weights, P: int, K: int, seed: int = 0, trials: int = 8) -> float:
    """Mean eq-7 loss of ``trials`` uniformly random K-colourings (numpy ``default_rng(seed)``)."""
    rng = np.random.default_rng(seed)
    return float(np.mean([coloring_loss(pairs, weights, rng.integers(0, K, P))[0] for _ in range(trials)]))


def parity_coloring(counts) -> np.ndarray:
    """MD eq 4 for K = 8: ``g(i, j, k) = (i & 1) | (j & 1) << 1 | (k & 1) << 2`` as (P,) int64.

    Bit d of the colour is the parity of the probe's index on axis d, so the 8 corners of any cell
    get 8 different colours (corner c of a cell with even base gets colour c).
    """
    nx, ny, nz = (int(v) for v in check_counts(counts))
    p = np.arange(nx * ny * nz)
    i, j, k = p % nx, (p // nx) % ny, p // (nx * ny)
    return ((i & 1) | ((j & 1) << 1) | ((k & 1) << 2)).astype(np.int64)  # MD eq 4


def convex_division(counts, K: int, spacing=None) -> np.ndarray:
    """Initial colouring of MD §3.4 step 3: the probe grid cut into K axis-aligned boxes, one colour each.

    Recursive bisection: a box holding k colours is cut across its longest axis (world extent
    ``n·spacing`` when ``spacing`` is given, else probe count) into parts of ``⌊k/2⌋`` and ``⌈k/2⌉``
    colours, in proportion to the probe count. Each part is a box of probes (convex). A box too thin
    to split leaves some colours unused. Returns (P,) int64 colours in [0, K).
    """
    counts = check_counts(counts)
    K = int(K)
    if K < 1:
        raise ValueError(f"K must be >= 1, got {K}")
    sp = np.ones(3) if spacing is None else np.where(np.asarray(spacing, np.float64) > 0, spacing, 1.0)
    nx, ny, nz = (int(v) for v in counts)
    g = np.zeros((nz, ny, nx), np.int64)

    def split(lo, hi, k0, k):
        if k == 1:
            g[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]] = k0
            return
        n = np.asarray(hi) - np.asarray(lo)
        axis = int(np.argmax(np.where(n > 1, n * sp, -1.0)))
        if n[axis] <= 1:
            g[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]] = k0
            return
        k1 = k // 2
        cut = lo[axis] + min(max(int(round(n[axis] * k1 / k)), 1), n[axis] - 1)
        hi1, lo2 = list(hi), list(lo)
        hi1[axis], lo2[axis] = cut, cut
        split(lo, hi1, k0, k1)
        split(lo2, hi, k0 + k1, k - k1)

    split([0, 0, 0], [nx, ny, nz], 0, K)  # MD §3.4.1 step 3: the initial g, a convex division
    return g.reshape(-1)


@numba.njit(cache=True, inline="always")
def _next(state):
    """splitmix64: advance the state, return (state, 64 random bits)."""
    state = state + _GAMMA
    z = state
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return state, z ^ (z >> _S31)


@numba.njit(cache=True)
def _exact_loss(ei, ej, ew, g, lam):
    s = 0.0
    for e in range(ei.shape[0]):
        if g[ei[e]] == g[ej[e]]:
            s += ew[e]  # eq 7
        else:
            s += lam  # eq 8 (λ/2 per ordered pair = λ per edge)
    return s


_RESYNC_SWEEPS = 64
"""The tracked loss is recomputed exactly every this many sweeps (it is otherwise accumulated from Δs)."""


@numba.njit(cache=True, nogil=True)
def _anneal_kernel(indptr, nbr, w, order, g, K, temps, seed, ei, ej, ew, lam, loss, best):
    """Metropolis sweeps at the temperatures ``temps``; ``loss[s]`` = eq 7 + eq 8 after sweep s.

    A move recolours node i from a to b (b uniform among the other K − 1 colours). With
    ``w_ij = E_ij − λ`` its change of eq 7 + eq 8 is ``Σ_{j: g_j = b} w_ij − Σ_{j: g_j = a} w_ij``;
    accepted when ≤ 0, else with probability exp(−Δ/T). The sums are gathered per colour without
    branches (``acc[g_j] += w_ij``: 2.4x faster than comparing g_j with a and b). The loss is the sum
    of the accepted Δs, recomputed exactly every ``_RESYNC_SWEEPS`` sweeps. ``best`` receives the
    colouring of the lowest loss seen at a sweep end (the initial one included). Returns (exact loss
    of ``best``, accepted moves).
    """
    state = _U(seed) * _U(0x2545F4914F6CDD1D) + _U(0x5EED)
    cur = _exact_loss(ei, ej, ew, g, lam)
    loss[0] = cur
    best_loss = cur
    best[:] = g
    accepted = 0
    acc = np.zeros(K)
    for s in range(temps.shape[0]):
        T = temps[s]
        for q in range(order.shape[0]):
            i = order[q]
            a = g[i]
            state, r = _next(state)
            b = np.int64((r >> _S11) % _U(K - 1))
            if b >= a:
                b += 1
            for c in range(K):
                acc[c] = 0.0
            for e in range(indptr[i], indptr[i + 1]):
                acc[g[nbr[e]]] += w[e]
            delta = acc[b] - acc[a]  # change of MD eq 7 + eq 8 when i moves from a to b
            if delta > 0.0:
                if T <= 0.0:
                    continue
                state, r = _next(state)
                u = np.float64(r >> _S11) * _INV53
                if u >= math.exp(-delta / T):  # Metropolis acceptance (MD §3.3: simulated annealing)
                    continue
            g[i] = b
            cur += delta
            accepted += 1
        if (s + 1) % _RESYNC_SWEEPS == 0:
            cur = _exact_loss(ei, ej, ew, g, lam)
        loss[s + 1] = cur
        if cur < best_loss:
            best_loss = cur
            best[:] = g
    return _exact_loss(ei, ej, ew, best, lam), accepted


def temperature_schedule(weights, sweeps: int, regularization: float = 0.0) -> np.ndarray:
    """The annealing temperatures, one per sweep (geometric cooling).

    With Ē the mean of the positive edge losses E: ``T0 = 3·Ē`` (an uphill move that makes one
    typical edge same-coloured is accepted with probability e^(−1/3) at the start),
    ``T_end = 1e-3·Ē``, lowered to ``0.1·λ`` when that is smaller (so the last sweeps resolve eq 8);
    ``T_s = T0·(T_end/T0)^(s/(n−1))`` for s = 0 … n − 1. The last sweeps are effectively greedy
    descent. One sweep runs at T_end. With no positive E, Ē = λ (or 1).

    Measured on zdm2-sauerbraten (16x8x16 probes, S = 8, 1000 sweeps, 3 seeds): T0 = 3·Ē ends 4% (K = 3)
    and 2% (K = 4) lower than T0 = Ē, 15-25% lower than T0 = 0.1·Ē; 10x more sweeps gain another 2-6%.
    """
    w = np.asarray(weights, np.float64)
    pos = w[w > 0]
    lam = float(regularization)
    mean = float(pos.mean()) if pos.size else (lam if lam > 0 else 1.0)
    t0 = 3.0 * mean
    t_end = 1e-3 * mean
    if lam > 0:
        t_end = min(t_end, 0.1 * lam)
    if sweeps <= 0:
        return np.zeros(0)
    if sweeps == 1:
        return np.array([t_end])
    return t0 * (t_end / t0) ** (np.arange(sweeps) / (sweeps - 1))


def anneal(pairs, weights, P: int, K: int, *, sweeps: int = 1000, regularization: float = 0.001, seed: int = 0,
           init=None, states=None, temperatures=None) -> tuple[np.ndarray, np.ndarray, dict]:
    """K-colour the probe graph by simulated annealing on MD eq 7 + eq 8 (§3.3, §3.4 step 3).

    Parameters
    ----------
    pairs, weights : the edge list of :func:`edge_loss` ((n, 2) int, (n,) float E).
    P : int, number of probes. K : int, colours (1 … 255).
    sweeps : int
        Sweeps over all movable probes (probes with at least one edge and not OFF), visited in flat
        index order; :func:`temperature_schedule` gives each sweep's temperature.
    regularization : float, λ of eq 8.
    seed : int, seeds the splitmix64 stream of proposals and acceptances (same seed, same g).
    init : (P,) int, optional; the starting colouring (default :func:`convex_division` by probe count).
    states : (P,) probe states, optional; OFF probes are never moved (module doc).
    temperatures : (sweeps,) float, optional; replaces :func:`temperature_schedule` (experiments).

    Returns
    -------
    g : (P,) int64
        The colouring with the lowest loss seen at a sweep end (so never above the initial loss).
    loss : (sweeps + 1,) float64
        eq 7 + eq 8 of the initial colouring and after each sweep (the current, not the best, state).
    info : dict
        ``initial_loss``, ``final_loss`` (of the returned g), ``t0``, ``t_end``, ``accepted`` (moves),
        ``movable`` (probes).
    """
    K = int(K)
    if not 1 <= K <= 255:
        raise ValueError(f"K must be in [1, 255], got {K}")
    sweeps = int(sweeps)
    if sweeps < 0:
        raise ValueError(f"sweeps must be >= 0, got {sweeps}")
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    w = np.ascontiguousarray(weights, np.float64)
    if w.shape != (pairs.shape[0],):
        raise ValueError(f"weights must have shape ({pairs.shape[0]},), got {w.shape}")
    if pairs.size and (pairs.min() < 0 or pairs.max() >= P):
        raise ValueError("pairs index probes outside [0, P)")
    g = (convex_division([P, 1, 1], K) if init is None else check_labels(init, P, K)).copy()
    lam = float(regularization)
    off = off_flags(states, P)
    keep = ~off[pairs[:, 0]] & ~off[pairs[:, 1]]
    pairs, w = pairs[keep], w[keep]
    # CSR adjacency, both directions, weights E − λ
    src = np.concatenate([pairs[:, 0], pairs[:, 1]])
    dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
    ww = np.concatenate([w, w]) - lam  # w_ij = E_ij − λ: MD eq 7 (same colour) against eq 8 (different)
    o = np.argsort(src, kind="stable")
    src, dst, ww = src[o], dst[o], ww[o]
    indptr = np.zeros(P + 1, np.int64)
    np.add.at(indptr, src + 1, 1)
    indptr = np.cumsum(indptr)
    order = np.flatnonzero((indptr[1:] > indptr[:-1]) & ~off).astype(np.int64)
    temps = temperature_schedule(w, sweeps, lam) if temperatures is None else np.asarray(temperatures, np.float64)
    if temps.shape != (sweeps,):
        raise ValueError(f"temperatures must have shape ({sweeps},), got {temps.shape}")
    loss = np.zeros(sweeps + 1)
    best = np.empty_like(g)
    if K == 1 or order.size == 0:
        temps = np.zeros(0)
    best_loss, accepted = _anneal_kernel(indptr, np.ascontiguousarray(dst), np.ascontiguousarray(ww), order, g, K,
                                         temps, int(seed) & 0xFFFFFFFF, pairs[:, 0].copy(), pairs[:, 1].copy(), w,
                                         lam, loss, best)
    if temps.size < sweeps:  # nothing to move: the loss stays where it started
        loss[temps.size + 1:] = loss[temps.size]
    info = {"initial_loss": float(loss[0]), "final_loss": float(best_loss), "accepted": int(accepted),
            "t0": float(temps[0]) if temps.size else 0.0, "t_end": float(temps[-1]) if temps.size else 0.0,
            "movable": int(order.size)}
    return best, loss, info
