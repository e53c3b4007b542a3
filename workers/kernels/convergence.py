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

**The tail is added, not waited for** (:func:`extrapolated_tail`, light stage 12): once a probe's ratios have
settled, the tail ``δ_p(b) · r/(1 − r)`` is an estimate good to far better than its own size, so the series stops
when the *uncertainty* of that estimate is small, and the bounce loop adds the tail to each probe's maps and rays
(per colour channel, with that channel's latest ratio: the channels are independent operators, a wood floor's red
and blue decay at different rates). A geometric series' tail is exact with the true ratio; the estimate's error
comes from the ratio still moving, bounded by the spread of the last three ratios ``r_hi − r_lo``:

    u_p(b) = δ_p(b) · (r_hi − r_lo) / ((1 − r_hi)² · Σ_texels |E_b|_p)        (d/dr of r/(1−r) is 1/(1−r)²)

and the residual is ``2·u_p`` (measured: the worst probe's error after the tail was added was up to 1.2x ``u_p``)
where ``ρ_p ≤`` :data:`RHO_CAP`, else ``ρ_p`` itself (a tail still that large is not extrapolated). Measured against
the same bakes iterated to ρ < 1e-5 (max over the probes that matter of Σ|E − E_∞| / Σ|E_∞|; tolerance 0.5%):
two-storey 32 bounces, error 0.38% → 23 bounces, 0.30%; two-rooms 26, 0.46% → 18, 0.22%; rooms-unequal 22, 0.46%
→ 16, 0.21%; Cornell 16, 0.47% → 13, 0.10%; zdm2-sauerbraten (sun and sky) 16, 0.31% → 14, 0.09%. A fixed
``light.bounces`` is a count: nothing is added there, and its residual is ``ρ``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["probe_sums", "relative_tail", "extrapolated_tail", "RELEVANT_FLOOR", "RHO_CAP"]

NOISE = 1e-5
"""Per-probe increments below this fraction of the probe's value are float32 rounding (the maps are float32:
their relative resolution is 6e-8 per texel, and sums over texels add that up), not light still to come. Rounding
can also settle into a cycle: on sealed-box two probes toggled between two roundings from bounce 12 to 40, an
increment of 1.1e-6 and 2.4e-6 of their value every bounce (ratio exactly 1, a tail that never ends), so the floor
is 1e-5 (was 1e-6; the old rule stopped there only when both happened to read a ratio below 1 at once). The light it
could ignore is at most 1e-5 · r/(1 − r) of a probe: 2e-4 at r = 0.95, far below any tolerance."""

RELEVANT_FLOOR = 1e-6
"""Probes dimmer than this fraction of the brightest probe do not hold the bake back (they are black to
any display; their own residual is still computed)."""

RHO_CAP = 0.25
"""A probe whose tail ``ρ_p`` is larger than this is not extrapolated (its ratios may not have settled: light still
arriving from far rooms); its residual is ``ρ_p``."""

SAFETY = 2.0
"""The residual after extrapolation is this many times the estimate's uncertainty ``u_p`` (module doc)."""

R_MAX = 0.95
"""Ratios are clipped here before ``r/(1 − r)`` (a factor of at most 19)."""


def probe_sums(maps: np.ndarray) -> np.ndarray:
    """Σ |x| per probe (and per configuration): ``maps`` (P, ...) or (P, ..., k·3) -> (P,) float64.

    With ``k`` configurations interleaved in the last axis as (k, 3), pass ``maps.reshape(P, -1, k, 3)``
    and get (P, k) back by summing axes 1 and 3 yourself; this helper covers the single-configuration case.
    """
    a = np.abs(np.asarray(maps)).reshape(maps.shape[0], -1)
    return a.sum(axis=1, dtype=np.float64)


def relative_tail(deltas: list[np.ndarray], value: np.ndarray,
                  floor: float = RELEVANT_FLOOR) -> tuple[float, np.ndarray]:
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


def extrapolated_tail(deltas: list[np.ndarray], value: np.ndarray,
                      floor: float = RELEVANT_FLOOR) -> tuple[float | np.ndarray, np.ndarray]:
    """The residual after the tail is added, and the factor that adds it (module doc, "The tail is added").

    Parameters
    ----------
    deltas : list of (P, k, 3) float64
        Per-probe, per-configuration, per-channel increments ``Σ_texels |E_b − E_{b−1}|`` of the bounces so far,
        oldest first (the last four are used).
    value : (P, k) float64
        Per-probe Σ |E_b| after the latest bounce (all channels).
    floor : float
        As :func:`relative_tail`.

    Returns
    -------
    residual : (k,) float64
        Max over the probes that matter of ``2·u_p`` (``ρ_p`` where ``ρ_p >`` :data:`RHO_CAP`); ∞ with fewer than
        four bounces.
    factor : (P, k, 3) float64
        ``r/(1 − r)`` per probe, configuration and channel (r the channel's latest ratio, clipped at
        :data:`R_MAX`), 0 where the probe is not extrapolated: ``E_∞ ≈ E_b + factor · (E_b − E_{b−1})``.
    """
    value = np.asarray(value, np.float64)
    if len(deltas) < 4:
        return np.full(value.shape[1:], np.inf), np.zeros(value.shape + (3,))
    dc = [np.asarray(d, np.float64) for d in deltas[-4:]]
    ds = [d.sum(axis=-1) for d in dc]                                   # δ(b−3) .. δ(b), (P, k)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rs = [np.where(ds[i] > 0, ds[i + 1] / ds[i], np.where(ds[i + 1] > 0, np.inf, 0.0)) for i in range(3)]
        r_hi = np.maximum(np.maximum(rs[0], rs[1]), rs[2])
        r_lo = np.minimum(np.minimum(rs[0], rs[1]), rs[2])
        unc = np.where(r_hi < 1.0, ds[3] * (r_hi - r_lo) / (1.0 - r_hi) ** 2, np.where(ds[3] > 0, np.inf, 0.0))
        u = np.where(value > 0, unc / value, np.where(unc > 0, np.inf, 0.0))
        rc = np.where(dc[2] > 0, dc[3] / dc[2], 0.0)
    _, rho = relative_tail(ds[1:], value, floor)                        # ρ_p, the whole tail (0 where rounding)
    noise = ds[3] <= NOISE * value                                      # float32 rounding: done, nothing to add
    extrapolate = (rho <= RHO_CAP) & ~noise
    est = np.where(noise, 0.0, np.where(extrapolate, SAFETY * u, rho))
    rc = np.clip(rc, 0.0, R_MAX)
    factor = np.where(extrapolate[..., None], rc / (1.0 - rc), 0.0)
    brightest = value.max(axis=0) if value.size else np.zeros(value.shape[1:])
    matters = (value >= floor * brightest) & (value > 0)
    res = np.where(matters, est, 0.0).max(axis=0) if value.size else np.zeros(value.shape[1:])
    return res, factor
