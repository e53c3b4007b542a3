"""Mask Decomposition: edge loss, probe colouring, per-sample masks (MD §3.2-3.4; DESIGN stage 4).

MD replaces the visibility-weighted blend of eq 2, ``L(x) = Σ_i θ_i(x) φ_i(x) P_i``, by eq 3,
``L(x) = Σ_k m_k(x) · Σ_i φ_i(x) g_i^k P_i``: the probes are split into K clusters by a one-hot
colouring g, each cluster is its own trilinearly filtered probe volume, and a K-channel mask m(x)
on the refined grid says how much of each cluster x sees. This module holds the math, numpy /
numba only, no I/O (stages/anneal.py and stages/masks.py call it):

1. :func:`edge_loss` — E(i, j) of eq 6 for every pair of probes sharing a cell, one pass over θ;
2. :func:`convex_division`, :func:`parity_coloring`, :func:`anneal` — the colouring g (§3.3, eq 4,
   eq 7 + eq 8, simulated annealing from a convex division, §3.4 step 3);
3. :func:`fit_masks` — m per refined-grid sample minimizing eq 5 locally (§3.4 step 4),
   :func:`light_aware_fit` (eq 9, step 5), :func:`fill_dont_care`, :func:`gaussian_filter` (step 6);
4. :func:`mask_residual` (eq 5), :func:`cluster_volumes` (per-cluster SH and weight volumes).

Conventions
-----------
Probe grid (:mod:`workers.kernels.grid`): ``counts = (nx, ny, nz)``, probe (i, j, k) has flat index
``p = i + nx·(j + ny·k)``; states OFF = 0. Refined grid (:mod:`workers.kernels.visibility`): S
samples per cell axis, field ``(Z, Y, X) = (cz·S, cy·S, cx·S)`` with ``c = max(n − 1, 1)`` cells per
axis; sample (x, y, z) lies in cell ``(x // S, y // S, z // S)`` at fraction
``t = ((x, y, z) % S + 0.5) / S`` of the cell. Corner c of a cell has offset
``(c & 1, c >> 1 & 1, c >> 2 & 1)`` (clamped to the grid on a one-probe axis). θ comes as
``theta (Z, Y, X, 8) uint8`` (θ·255 per corner; the visibility stage's ``theta_0123`` and
``theta_4567`` concatenated on the last axis) and ``dont_care (Z, Y, X) bool``.

φ, the trilinear weight of corner c at a sample, is the product over axes of ``t`` (offset 1) or
``1 − t`` (offset 0), computed from the sample's position in its cell. On an axis with one probe
``t = 0`` (the sample lies in the probe plane; the weight goes to the offset-0 corner, as
:func:`workers.kernels.grid.cell_coords` gives α = 0 there).

Sums over x (eq 5-9) are the paper's discrete sums over the samples that are not "don't care"
(each sample weighs 1, so E and R̂ are in **samples**: a sample whose two probes differ fully in θ
adds its min φ). With these units the paper's λ = 0.001 of eq 8 is tiny against any E that a
single sample makes, and does what MD §3.3.1 says it is for: among edges with E = 0 it prefers one
colour, so m stays sparse. (Normalizing the sums to cell volumes, 1/S³ per sample, would make the
same λ 512 times stronger at S = 8 and let eq 8 outweigh real visibility differences.)

OFF probes
----------
An OFF probe (stuck in geometry) has θ = 0 everywhere and P = 0 (the light stage zeroes it): its
terms vanish from eq 2, from eq 3 and from the bound R ≤ ∫ Σ_i φ_i ‖P_i‖ |θ_i − m·g_i| of which
eq 5 is the simplification, so it is left out of the whole problem: its edges are dropped from E
(and from eq 8), it is never moved by the annealing (it keeps its initial colour, which is still
written to ``clusters``), it takes no part in the per-sample fit, and the cluster volumes give it
SH 0 and weight 0. Counting it would only waste colours separating nothing from its neighbours.

References
----------
.. [MD] J. Zhou, Y. Chen, Y. Li, S. Cao, Y. Wu, X. Jin, "Fast Probe-Leaking Elimination Using Mask
   Decomposition" (``../shared/papers/mask-decomposition.txt``).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from workers.kernels.grid import OFF

__all__ = [
    "HALF_DIRECTIONS",
    "field_fractions",
    "edge_loss",
    "coloring_loss",
    "random_loss",
    "parity_coloring",
    "convex_division",
    "temperature_schedule",
    "anneal",
    "fit_masks",
    "light_aware_fit",
    "fill_dont_care",
    "gaussian_filter",
    "mask_residual",
    "quantize",
    "cluster_volumes",
    "join_theta",
]

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


# ---------------------------------------------------------------------- validation helpers
def _counts(counts) -> np.ndarray:
    c = np.asarray(counts, np.int64).reshape(3)
    if (c < 1).any():
        raise ValueError(f"counts must be >= 1 on every axis, got {c.tolist()}")
    return c


def join_theta(theta_0123, theta_4567) -> np.ndarray:
    """``(Z, Y, X, 8) uint8`` θ from the visibility stage's two RGBA8 volumes (corners 0-3, 4-7)."""
    a, b = np.asarray(theta_0123), np.asarray(theta_4567)
    if a.shape != b.shape or a.ndim != 4 or a.shape[3] != 4:
        raise ValueError(f"theta volumes must both be (Z, Y, X, 4), got {a.shape} and {b.shape}")
    return np.ascontiguousarray(np.concatenate([a, b], axis=3).astype(np.uint8, copy=False))


def _field(theta, dont_care, counts, S):
    """Validated (theta (Z,Y,X,8) uint8, dont_care (Z,Y,X) bool, counts (3,), S, cells (3,))."""
    counts = _counts(counts)
    S = int(S)
    if S < 1:
        raise ValueError(f"S must be >= 1, got {S}")
    cells = np.maximum(counts - 1, 1)
    shape = (int(cells[2]) * S, int(cells[1]) * S, int(cells[0]) * S)
    theta = np.ascontiguousarray(theta, np.uint8)
    if theta.shape != shape + (8,):
        raise ValueError(f"theta must have shape {shape + (8,)} for counts {counts.tolist()} and S = {S}, "
                         f"got {theta.shape}")
    dc = np.asarray(dont_care)
    if dc.shape == shape + (1,):
        dc = dc[..., 0]
    if dc.shape != shape:
        raise ValueError(f"dont_care must have shape {shape}, got {dc.shape}")
    return theta, np.ascontiguousarray(dc, bool), counts, S, cells


def _states(states, P: int) -> np.ndarray:
    if states is None:
        return np.zeros(P, bool)
    st = np.asarray(states).reshape(-1)
    if st.shape != (P,):
        raise ValueError(f"states must hold {P} probes, got shape {np.asarray(states).shape}")
    return np.ascontiguousarray(st == OFF)


def _labels(g, P: int, K: int) -> np.ndarray:
    g = np.asarray(g).reshape(-1)
    if g.shape != (P,):
        raise ValueError(f"g must hold {P} probes, got shape {g.shape}")
    if g.size and (g.min() < 0 or g.max() >= K):
        raise ValueError(f"g must be in [0, {K}), got [{g.min()}, {g.max()}]")
    return np.ascontiguousarray(g, np.int64)


def field_fractions(counts, S) -> tuple[np.ndarray, ...]:
    """Per-axis cell index and in-cell fraction of the refined-grid samples.

    Returns ``(cx (X,), cy (Y,), cz (Z,)) int64`` and ``(tx, ty, tz) float64``: sample (x, y, z) is in
    cell ``(cx[x], cy[y], cz[z])`` at fraction ``(tx[x], ty[y], tz[z])`` (``(a + 0.5) / S``; 0 on a
    one-probe axis).
    """
    counts = _counts(counts)
    S = int(S)
    cells, fracs = [], []
    for axis in range(3):
        n = int(max(counts[axis] - 1, 1)) * S
        f = np.arange(n, dtype=np.int64)
        cells.append(f // S)
        fracs.append(np.zeros(n) if counts[axis] == 1 else ((f % S) + 0.5) / S)
    return (*cells, *fracs)


@numba.njit(cache=True, inline="always")
def _phi(c, fx, fy, fz):
    """Trilinear weight of corner c (offset (c&1, c>>1&1, c>>2&1)) at in-cell fraction (fx, fy, fz)."""
    wx = fx if c & 1 else 1.0 - fx
    wy = fy if (c >> 1) & 1 else 1.0 - fy
    wz = fz if (c >> 2) & 1 else 1.0 - fz
    return wx * wy * wz


@numba.njit(cache=True, inline="always")
def _corner(ci, cj, ck, c, nx, ny, nz):
    i = min(ci + (c & 1), nx - 1)
    j = min(cj + ((c >> 1) & 1), ny - 1)
    k = min(ck + ((c >> 2) & 1), nz - 1)
    return i + nx * (j + ny * k)


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
                    phi[c] = _phi(c, tx[x], ty[y], tz[z])
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
                    pa = _corner(ci, cj, ck, pairs[q, 0], nx, ny, nz)
                    pb = _corner(ci, cj, ck, pairs[q, 1], nx, ny, nz)
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
    theta, dc, counts, S, cells = _field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    P = nx * ny * nz
    off = _states(states, P)
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
    return float(w[same].sum()), float(regularization) * float((~same).sum())


def random_loss(pairs, weights, P: int, K: int, seed: int = 0, trials: int = 8) -> float:
    """Mean eq-7 loss of ``trials`` uniformly random K-colourings (numpy ``default_rng(seed)``)."""
    rng = np.random.default_rng(seed)
    return float(np.mean([coloring_loss(pairs, weights, rng.integers(0, K, P))[0] for _ in range(trials)]))


def parity_coloring(counts) -> np.ndarray:
    """MD eq 4 for K = 8: ``g(i, j, k) = (i & 1) | (j & 1) << 1 | (k & 1) << 2`` as (P,) int64.

    Bit d of the colour is the parity of the probe's index on axis d, so the 8 corners of any cell
    get 8 different colours (corner c of a cell with even base gets colour c).
    """
    nx, ny, nz = (int(v) for v in _counts(counts))
    p = np.arange(nx * ny * nz)
    i, j, k = p % nx, (p // nx) % ny, p // (nx * ny)
    return ((i & 1) | ((j & 1) << 1) | ((k & 1) << 2)).astype(np.int64)


def convex_division(counts, K: int, spacing=None) -> np.ndarray:
    """Initial colouring of MD §3.4 step 3: the probe grid cut into K axis-aligned boxes, one colour each.

    Recursive bisection: a box holding k colours is cut across its longest axis (world extent
    ``n·spacing`` when ``spacing`` is given, else probe count) into parts of ``⌊k/2⌋`` and ``⌈k/2⌉``
    colours, in proportion to the probe count. Each part is a box of probes (convex). A box too thin
    to split leaves some colours unused. Returns (P,) int64 colours in [0, K).
    """
    counts = _counts(counts)
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

    split([0, 0, 0], [nx, ny, nz], 0, K)
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
            delta = acc[b] - acc[a]
            if delta > 0.0:
                if T <= 0.0:
                    continue
                state, r = _next(state)
                u = np.float64(r >> _S11) * _INV53
                if u >= math.exp(-delta / T):
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
    g = (convex_division([P, 1, 1], K) if init is None else _labels(init, P, K)).copy()
    lam = float(regularization)
    off = _states(states, P)
    keep = ~off[pairs[:, 0]] & ~off[pairs[:, 1]]
    pairs, w = pairs[keep], w[keep]
    # CSR adjacency, both directions, weights E − λ
    src = np.concatenate([pairs[:, 0], pairs[:, 1]])
    dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
    ww = np.concatenate([w, w]) - lam
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


# ---------------------------------------------------------------------- 3. masks (eq 5)
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
                    p = _corner(cx[x], cy[y], cz[z], c, nx, ny, nz)
                    ph = _phi(c, tx[x], ty[y], tz[z])
                    if off[p] or ph <= 0.0:
                        continue
                    k = g[p]
                    vals[k, cnt[k]] = theta[z, y, x, c] * (1.0 / 255.0)
                    wts[k, cnt[k]] = ph
                    cnt[k] += 1
                for k in range(K):
                    # eq 5 per cluster: argmin_m Σ_{i: g_i = k} φ_i |θ_i − m|, the φ-weighted median
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
    theta, dc, counts, S, _ = _field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    P = nx * ny * nz
    K = int(K)
    g = _labels(g, P, K)
    off = _states(states, P)
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
                    p = _corner(cx[x], cy[y], cz[z], c, nx, ny, nz)
                    if off[p]:
                        continue
                    ph = _phi(c, tx[x], ty[y], tz[z])
                    th = theta[z, y, x, c] * (1.0 / 255.0)
                    r += ph * abs(th - m[z, y, x, g[p]])  # eq 5
                    mass += ph * th
    return r, mass


def mask_residual(theta, dont_care, counts, S, g, masks, states=None) -> tuple[float, float]:
    """``(R̂, Σ φθ)``: MD eq 5 ``Σ_x Σ_i φ_i |θ_i − m·g_i|`` over care samples and non-OFF probes, and
    the visible mass ``Σ_x Σ_i φ_i θ_i`` (for a relative residual), both in samples.

    masks : (Z, Y, X, K) float in [0, 1], or uint8 (read as byte / 255, as the shader reads them).
    """
    theta, dc, counts, S, _ = _field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    m = np.asarray(masks)
    # bytes read with the same arithmetic as θ (byte · (1/255)), so equal bytes give exactly 0
    m = m.astype(np.float64) * (1.0 / 255.0) if m.dtype == np.uint8 else m.astype(np.float64)
    if m.shape[:3] != dc.shape:
        raise ValueError(f"masks must have shape {dc.shape + ('K',)}, got {m.shape}")
    K = m.shape[3]
    g = _labels(g, nx * ny * nz, K)
    off = _states(states, nx * ny * nz)
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
                    p = _corner(cx[x], cy[y], cz[z], c, nx, ny, nz)
                    if off[p]:
                        continue
                    ph = _phi(c, tx[x], ty[y], tz[z])
                    th = theta[z, y, x, c] * (1.0 / 255.0)
                    k = g[p]
                    for d in range(D):
                        A[d, k] += ph * sh[p, d]        # cluster k's volume at x: Σ_i φ_i g_i^k P_i
                        b[d] += th * ph * sh[p, d]      # eq 2
                    wsum += th * ph
                if wsum > 0.0:
                    for d in range(D):
                        b[d] /= wsum                    # normalized as RTXGI: the reference L(x)
                else:
                    b[:] = 0.0
                for k in range(K):
                    pen[k] = 1.0 if m[z, y, x, k] == 0.0 else 0.0   # eq 9: channels 0 before the fit
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
    theta, dc, counts, S, _ = _field(theta, dont_care, counts, S)
    nx, ny, nz = (int(v) for v in counts)
    P = nx * ny * nz
    m = np.array(masks, np.float64, copy=True)
    if m.shape[:3] != dc.shape:
        raise ValueError(f"masks must have shape {dc.shape + ('K',)}, got {m.shape}")
    K = m.shape[3]
    g = _labels(g, P, K)
    off = _states(states, P)
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
        out = correlate1d(out, k.astype(np.float32), axis=axis, mode="nearest")
    if keep_zeros:
        out[m == 0] = 0.0
    return np.clip(out, 0.0, 1.0, out=out)


def quantize(masks) -> np.ndarray:
    """Masks in [0, 1] → uint8 ``round(255·m)`` (RGBA8 UNORM storage)."""
    m = np.clip(np.asarray(masks, np.float32), 0.0, 1.0)
    return np.rint(m * np.float32(255.0), out=m).astype(np.uint8)


# ---------------------------------------------------------------------- 4. cluster volumes
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
    g = _labels(g, P, int(K))
    on = ~_states(states, P)
    weights = np.zeros((P, int(K)), np.float32)
    weights[np.arange(P)[on], g[on]] = 1.0
    weights = weights.reshape(nz, ny, nx, int(K))
    vols = [sh * weights[..., k][..., None, None] for k in range(int(K))]
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

    cnt = _counts(counts)
    nx, ny, nz = (int(c) for c in cnt)
    P = nx * ny * nz
    off = _states(states, P)                                               # (P,) True where OFF
    lab = _labels(g, P, K)
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
    out = np.where(rel, q, np.uint8(0))
    dc = np.asarray(dont_care, bool).reshape(Z, Y, X)
    deep = dc & ~binary_dilation(~dc, structure=np.ones((3, 3, 3), bool))
    out[deep] = 0
    return np.ascontiguousarray(out, np.uint8)
