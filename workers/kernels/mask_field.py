"""The refined sample grid of Mask Decomposition, shared by colouring and mask fitting (MD §3.1.1, §3.4).

MD stores per refined-grid sample x the visibility θ_i(x) of the 8 probes of x's cell (§3.4 step 1) and
weighs probe i there by its trilinear weight φ_i(x) (§3.1.2, eq 2). This module holds the conventions and
checks that :mod:`workers.kernels.coloring` (§3.3, eq 4, 6-8) and :mod:`workers.kernels.mask_fit` (§3.4,
eq 5, 9) both read; numpy / numba only, no I/O.

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

import numba
import numpy as np

from workers.kernels.grid import OFF

__all__ = ["check_counts", "check_field", "off_flags", "check_labels", "join_theta", "field_fractions",
           "corner_weight", "corner_probe"]


def check_counts(counts) -> np.ndarray:
    """``counts`` as (3,) int64 probes per axis (nx, ny, nz); ValueError unless every axis has at least one."""
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


def check_field(theta, dont_care, counts, S):
    """Validated (theta (Z,Y,X,8) uint8, dont_care (Z,Y,X) bool, counts (3,), S, cells (3,))."""
    counts = check_counts(counts)
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


def off_flags(states, P: int) -> np.ndarray:
    """(P,) bool, True where a probe is OFF (``states`` (P,) probe states; None: no probe is OFF)."""
    if states is None:
        return np.zeros(P, bool)
    st = np.asarray(states).reshape(-1)
    if st.shape != (P,):
        raise ValueError(f"states must hold {P} probes, got shape {np.asarray(states).shape}")
    return np.ascontiguousarray(st == OFF)


def check_labels(g, P: int, K: int) -> np.ndarray:
    """The colouring g as (P,) int64 in [0, K) (one cluster per probe), or ValueError."""
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
    counts = check_counts(counts)
    S = int(S)
    cells, fracs = [], []
    for axis in range(3):
        n = int(max(counts[axis] - 1, 1)) * S
        f = np.arange(n, dtype=np.int64)
        cells.append(f // S)
        fracs.append(np.zeros(n) if counts[axis] == 1 else ((f % S) + 0.5) / S)
    return (*cells, *fracs)


@numba.njit(cache=True, inline="always")
def corner_weight(c, fx, fy, fz):
    """Trilinear weight of corner c (offset (c&1, c>>1&1, c>>2&1)) at in-cell fraction (fx, fy, fz)."""
    wx = fx if c & 1 else 1.0 - fx
    wy = fy if (c >> 1) & 1 else 1.0 - fy
    wz = fz if (c >> 2) & 1 else 1.0 - fz
    return wx * wy * wz  # φ_i(x) of MD eq 2-3


@numba.njit(cache=True, inline="always")
def corner_probe(ci, cj, ck, c, nx, ny, nz):
    """Flat index of corner c of cell (ci, cj, ck), clamped to the grid on a one-probe axis."""
    i = min(ci + (c & 1), nx - 1)
    j = min(cj + ((c >> 1) & 1), ny - 1)
    k = min(ck + ((c >> 2) & 1), nz - 1)
    return i + nx * (j + ny * k)
