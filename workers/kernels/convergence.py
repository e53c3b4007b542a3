"""When the bounce series has converged: a per-probe estimate of the light still to come.

The light stage sums the Neumann series of the bounce operator, ``E = Σ_k T^k E_0`` (DDGI-I §3.5: each
bounce re-shades the probe-ray hits with the previous bounce's irradiance). After bounce b the increment of
probe p is ``δ_p(b) = Σ_texels |E_b − E_{b−1}|``; past the first few bounces the increments fall
geometrically, ``δ_p(b+1) ≈ r_p δ_p(b)``, with ``r_p`` the operator's dominant eigenvalue as seen from p
(about the albedo of the room p stands in). The light still missing is the tail of that series,
``δ_p(b) · r_p / (1 − r_p)``; relative to the probe's value it is the residual

    ρ_p(b) = δ_p(b) · r_p / ((1 − r_p) · Σ_texels |E_b|_p),   r_p = max(δ_p(b)/δ_p(b−1), δ_p(b−1)/δ_p(b−2))

(the larger of the last two ratios, so a series still speeding up is not taken for converged; r_p ≥ 1
gives ρ = ∞). The bake has converged when ``max_p ρ_p < tolerance`` over the probes that matter: every
probe whose irradiance is at least ``floor`` × the brightest probe's. A global criterion (the whole grid's
change) stops while a dark albedo-1 room next to a sunlit yard is still 30% short: sunlit probes converge
in a few bounces and dominate any sum.
"""
from __future__ import annotations

import numpy as np

__all__ = ["probe_sums", "relative_tail", "RELEVANT_FLOOR"]

NOISE = 1e-6
"""Per-probe increments below this fraction of the probe's value are float32 rounding (the maps are float32:
their relative resolution is 6e-8 per texel, and sums over texels add that up), not light still to come."""

RELEVANT_FLOOR = 1e-6
"""Probes dimmer than this fraction of the brightest probe do not hold the bake back (they are black to
any display; their own residual is still computed)."""


def probe_sums(maps: np.ndarray) -> np.ndarray:
    """Σ |x| per probe (and per configuration): ``maps`` (P, ...) or (P, ..., k·3) -> (P,) float64.

    With ``k`` configurations interleaved in the last axis as (k, 3), pass ``maps.reshape(P, -1, k, 3)``
    and get (P, k) back by summing axes 1 and 3 yourself; this helper covers the single-configuration case.
    """
    a = np.abs(np.asarray(maps)).reshape(maps.shape[0], -1)
    return a.sum(axis=1, dtype=np.float64)


def relative_tail(deltas: list[np.ndarray], value: np.ndarray, floor: float = RELEVANT_FLOOR) -> tuple[float, np.ndarray]:
    """The residual of the module doc.

    Parameters
    ----------
    deltas : list of (P,) or (P, k) float64
        Per-probe increments of the bounces so far, oldest first (at least the last three are used).
    value : (P,) or (P, k) float64
        Per-probe Σ |E_b| after the latest bounce.
    floor : float
        Probes below ``floor`` × the brightest (per configuration) are not counted in the maximum.

    Returns
    -------
    residual : float or (k,) float64
        ``max_p ρ_p`` over the probes that matter (0 when none does); ∞ with fewer than 3 bounces.
    rho : (P,) or (P, k) float64
        ``ρ_p`` per probe (0 where the probe is black).
    """
    value = np.asarray(value, np.float64)
    if len(deltas) < 3:
        rho = np.full(value.shape, np.inf)
        res = np.full(value.shape[1:], np.inf)
        return (float(res) if res.ndim == 0 else res), rho
    d0, d1, d2 = (np.asarray(d, np.float64) for d in deltas[-3:])      # δ(b−2), δ(b−1), δ(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(d1 > 0, d2 / d1, np.where(d2 > 0, np.inf, 0.0))
        r0 = np.where(d0 > 0, d1 / d0, np.where(d1 > 0, np.inf, 0.0))
        r = np.maximum(r0, r1)
        tail = np.where(r < 1.0, d2 * r / (1.0 - r), np.where(d2 > 0, np.inf, 0.0))
        rho = np.where(value > 0, tail / value, np.where(tail > 0, np.inf, 0.0))
    # increments at the float32 rounding of the stored maps are noise (their ratio says nothing): done
    rho = np.where(d2 <= NOISE * value, 0.0, rho)
    brightest = value.max(axis=0) if value.size else np.zeros(value.shape[1:])
    matters = value >= floor * brightest
    matters &= value > 0
    res = np.where(matters, rho, 0.0).max(axis=0) if value.size else np.zeros(value.shape[1:])
    return (float(res) if np.ndim(res) == 0 else res), rho
