"""Metrics of a GI mode at the reference's points, each with its standard error from the reference's noise.

Inputs per point i (N points; :mod:`workers.stages.reference`): the reference's direct irradiance ``D_i``,
path-traced indirect irradiance ``R_i`` with its standard error ``s_i`` (RGB, from the point's own paths),
the surface's albedo ``a_i`` and emission ``e_i``, and the mode's indirect irradiance ``T_i``. Luminance Y is
Rec. 709 (:func:`workers.kernels.metrics.luminance`).

Metrics (:func:`point_metrics`)
-------------------------------
``rmse``
    MD §4.2 on the shading result: the exitant radiance ``L = e + a/π (D + E)`` with E = T (test) or R
    (reference), tone mapped with the exposure of the reference's points (:func:`workers.kernels.metrics.tonemap`,
    the previews' tone map), ``sqrt(mean_i mean_RGB (C_i − C'_i)²)``, less the reference's noise ("Noise bias").
``indirect_relative_rmse``
    ``sqrt(mean_i |T_i − R_i|²) / mean_i |R_i|`` (RGB vectors), less the reference's noise ("Noise bias").
``leak``
    The leak score of :func:`workers.kernels.metrics.leak_score` over the points: in the dark points (reference
    luminance ≤ 5% of the mean) the mean |T − R| as a fraction of the mean reference.
``indirect_excess``
    ``mean_i max(0, Y(T_i) − Y(R_i))``, lux: the leak where the whole set is dark in the reference.
``mean_ratio``
    ``mean_i Y(T_i) / mean_i Y(R_i)`` (1 = the right amount of light on average; None where the reference is 0).

Standard errors (:func:`metrics_with_stderr`)
--------------------------------------------
The reference is a Monte Carlo estimate, so each metric carries the noise of its ``R_i``. It is propagated by a
parametric bootstrap: ``replicas`` references ``R*_i = max(0, R_i + s_i z_i)`` with independent standard normal
``z_i`` per point (one per point for all three channels: a point's channels come from the same paths), the metric
recomputed on each, its standard deviation reported as ``<metric>_stderr`` — except for ``rmse`` and
``indirect_relative_rmse``, see "Standard errors of the debiased rmse". Deterministic (seeded). The leak's
replicas keep the reference's dark set: its standard error is the noise of ``|T − R|`` at those points, given the
set. Re-picking the set per replica would let a Gaussian tail move a point across the threshold and the score jump
from 0 (no dark point) to a whole point's deviation — the spread of a discontinuity, not of the estimate (two-rooms,
no dark point: ±0.07 that way). Membership itself is seldom in doubt: the points near the threshold are refined
(:func:`workers.kernels.reference.refine_points`). The exposure
of the tone map stays that of the reference (a display constant). This is the error of the metric as an
estimate of its value against the exact reference at the same points; which points were drawn is not part of
it (they are fixed per scene).

Noise bias
----------
A Monte Carlo reference ``R̂_i = R_i + noise`` adds its own variance to every squared error in expectation:
``E|T_i − R̂_i|² = |T_i − R_i|² + |s_i|²``. Left in, it made the reference's noise look like the mode's error
(two-rooms at 128 paths: ``indirect_relative_rmse`` 0.121 for normalized mask GI, 0.090 at 192 paths, the same
bake). :func:`point_metrics` with ``err`` (and :func:`metrics_with_stderr`, always) subtracts it: ``mean_i |s_i|²``
from the mean squared irradiance error of ``indirect_relative_rmse``, and from the mean squared tone-mapped error
of ``rmse`` the variance of each tone-mapped channel by the delta method (the tone map's slope at the reference,
a central difference of ±s_i). Clamped at 0. What remains is the error against the exact reference up to the
accuracy of the ``s_i`` themselves (unbiased: the spread of each point's independent stratified sets of paths,
:mod:`workers.kernels.pathtrace`, as long as nothing chose the
points' path counts on those same paths: :func:`workers.kernels.reference.refine_points` chooses on a pilot pass;
two-rooms, ddgi: 0.057 with the choice made on the first pass, 0.039 with the pilot, 0.038-0.044 unrefined at 192
and 384 paths). ``leak`` (a mean absolute
difference) and ``indirect_excess`` are not corrected; ``mean_ratio`` is linear and unbiased.

Standard errors of the debiased rmse
-----------------------------------
For ``rmse`` and ``indirect_relative_rmse`` the bootstrap above understated the error where it matters most,
for the accurate modes: its replicas add their noise on top of a reference that already carries its own, so
their squared errors sit at the raw, un-debiased level (two-rooms: the mode's mean squared error 0.15 under 0.57
of noise) where the square root is far flatter. Simulated references around one truth (two-rooms' values,
the ddgi and normalized mask modes 4% off, 120 draws): it read 0.58-0.77 of the spread of the values. So these
two take the delta method instead (:func:`_debiased_rmse_stderr`): per point the variance of the debiased squared
error ``|d − u z|² − |û|²`` (d the error, u the reference's standard error, one noise draw z per point for all
channels) is ``4 (d·u)² + 2|u|⁴ (1 + 1/ν)``, estimated without bias from the noisy error and standard error
(``4 (d̂·û)² − 2 (ν − 1)/(ν + 2) |û|⁴``, ν = :data:`NOISE_DOF` degrees of freedom of the path tracer's
replicate standard errors, Gaussian noise), summed, and taken through the square root (blended to the fourth root
of the variance near 0). ``indirect_relative_rmse`` adds the noise of its denominator in quadrature; ``rmse``
uses the tone-mapped errors and the delta-method noise of "Noise bias". In the simulation the reported errors
read 0.85-1.14 of the spread (test_point_metrics.py: 0.94 and 0.89, the bootstrap 0.69 and 0.65).

Paired deltas
-------------
Two bakes of one scene and lighting are scored against the same cached reference, so the difference of their
metrics carries the reference's noise once, correlated, not twice independently (:func:`paired_delta_stderr`, the
standard errors of ``GET /v1/compare``'s deltas). For the debiased ``rmse`` the noise terms that do not depend on
the test (``|u z|²`` and the subtracted ``|û|²``) are the same in both and cancel exactly in
``Δmse = mse_b − mse_a``, which is linear in the noise: per point ``−2 z (u·(C_b − C_a))`` (tone-mapped, ``u`` the
delta-method noise of "Noise bias", over N·3 values), so ``Var(Δmse) = 4 Σ_i (u_i·(C_b,i − C_a,i))² / (3N)²`` —
exact for one noise draw per point, and free of the reference's noise (``C_b − C_a`` holds no reference). Then
``Δrmse = Δmse / (rmse_a + rmse_b)`` (an identity); the noise of the denominator, shared by both roots, adds the
term of a ratio (:func:`_paired_root_delta_stderr`; it matters where the delta is large against its error: in the
simulation of test_point_metrics.py, without it the irradiance rmse delta's error read 0.68 of its spread). ``indirect_relative_rmse`` the same in irradiance (``s_i`` and ``T_b − T_a``), its common
denominator's noise added in quadrature. ``leak``, ``indirect_excess`` and ``mean_ratio``: the bootstrap of
"Standard errors", paired (both tests against the same replicas and dark set). Two bakes that read the same have a
delta of 0 ± 0.

What a smaller standard error costs (:func:`paths_for_stderr`)
--------------------------------------------------------------
With k times the reference's paths at every point the standard errors become ``s/√k``. The bootstrap metrics'
errors fall as ``1/√k``; the debiased rmse's variance has a part in ``1/k`` (the error times the noise) and one in
``1/k²`` (the noise squared); where a mode's error is below the reference's noise the second dominates, and
halving its relative error takes 2x the paths (4x where the first dominates) — but from far: two-rooms' ddgi, tone-mapped
``rmse`` 0.0037 against a noise of about 0.007 per point and channel, reads ± 16% and would need about 25x the paths
for 2% (tests/bench/bench_evaluate.py ``--cost`` prints it per metric). The function says what k a target takes;
the stage does not spend it.

Regions (:func:`region_ratios`): for named groups of check points, the ratio of the group's mean luminance to
the reference's, with its bootstrap standard error the same way.

The evaluate stage's summaries: :func:`point_summary` (every mode over the surface points),
:func:`check_point_report` (every mode at the check points, per region).
"""
from __future__ import annotations

import math

import numpy as np

from workers.kernels import metrics as MT

__all__ = ["point_metrics", "metrics_with_stderr", "paths_for_stderr", "paired_delta_stderr", "reference_mean_stderr",
           "region_ratios", "radiance", "point_summary", "check_point_report", "METRICS", "REPLICAS"]

METRICS = ("rmse", "indirect_relative_rmse", "leak", "indirect_excess", "mean_ratio")
REPLICAS = 128
NOISE_DOF = 7
"""Degrees of freedom of a reference point's squared standard error: the path tracer's
:data:`workers.kernels.pathtrace.REPLICATES` − 1 (its standard error is the spread of that many independent
stratified sets' means). Used by :func:`_debiased_rmse_stderr`."""


def radiance(e_direct, e_indirect, albedo, emission) -> np.ndarray:
    """(N, 3) exitant radiance ``emission + albedo/π (E_direct + E_indirect)`` (Lambertian surfaces)."""
    return np.asarray(emission) + np.asarray(albedo) / math.pi * (np.asarray(e_direct) + np.asarray(e_indirect))


def _noise_variance(ref, err, e_direct, albedo, emission, exposure: float) -> tuple[np.ndarray, np.ndarray]:
    """Per point, what the reference's own noise adds in expectation to the squared errors (module doc, "Noise
    bias"): ``(|s_i|², (N,) lux²; var of the tone-mapped C_i per channel, (N, 3))``, the second by the delta method
    through the tone map's slope at the reference (central difference of ±s_i in irradiance)."""
    r, s = np.asarray(ref, np.float64), np.asarray(err, np.float64)
    d, a, e = (np.asarray(x, np.float64) for x in (e_direct, albedo, emission))
    lo_r = np.maximum(r - s, 0.0)                                  # the slope over [max(R − s, 0), R + s]
    hi = MT.tonemap(radiance(d, r + s, a, e), exposure).astype(np.float64)
    lo = MT.tonemap(radiance(d, lo_r, a, e), exposure).astype(np.float64)
    width = r + s - lo_r
    return np.sum(s * s, axis=-1), np.where(width > 0, (hi - lo) * s / np.where(width > 0, width, 1.0), 0.0) ** 2


def _prepare(refs, d, a, e, exposure: float) -> dict:
    """What the metrics need of K references (K, N, 3), whatever the test: computed once for every mode."""
    r = np.asarray(refs, np.float64)
    return {"refs": r, "tonemapped": MT.tonemap(radiance(d[None], r, a[None], e[None]), exposure).astype(np.float64),
            "luminance": MT.luminance(r), "mean_norm": np.mean(np.linalg.norm(r, axis=-1), axis=1)}


def _metrics_batch(test, refs, e_direct, albedo, emission, exposure: float, dark=None,
                   noise=None) -> dict[str, np.ndarray]:
    """The metrics (module doc) of one test against K references ``refs`` (K, N, 3, or :func:`_prepare` of them)
    at once: {name: (K,)}, NaN where
    undefined (mean_ratio of a black reference). ``dark`` (N,) bool: the leak's dark set, else each reference's.
    ``noise``: :func:`_noise_variance` of the reference, subtracted from the squared errors of ``rmse`` and
    ``indirect_relative_rmse`` (module doc, "Noise bias"); None: not (a noise-free reference)."""
    t = np.asarray(test, np.float64)
    d, a, e = (np.asarray(x, np.float64) for x in (e_direct, albedo, emission))
    prep = refs if isinstance(refs, dict) else _prepare(refs, d, a, e, exposure)
    r, lr, yr, den = prep["refs"], prep["tonemapped"], prep["luminance"], prep["mean_norm"]
    v_irr, v_tm = (0.0, 0.0) if noise is None else (float(noise[0].mean()), float(noise[1].mean()))
    lt = MT.tonemap(radiance(d, t, a, e), exposure).astype(np.float64)             # (N, 3)
    rmse = np.sqrt(np.maximum(np.mean((lt[None] - lr) ** 2, axis=(1, 2)) - v_tm, 0.0))
    num = np.sqrt(np.maximum(np.mean(np.sum((t[None] - r) ** 2, axis=-1), axis=1) - v_irr, 0.0))
    rel = np.where(den > 0, num / np.where(den > 0, den, 1.0), np.where(num == 0, 0.0, np.inf))
    yt = MT.luminance(t)                                                              # (N,)
    mean_r = yr.mean(axis=1)
    dark = yr <= MT.LEAK_TAU * mean_r[:, None] if dark is None else np.broadcast_to(np.asarray(dark, bool), yr.shape)
    n_dark = dark.sum(axis=1)
    dev = (np.abs(yt[None] - yr) * dark).sum(axis=1) / np.maximum(n_dark, 1)
    leak = np.where((mean_r > 0) & (n_dark > 0), dev / np.where(mean_r > 0, mean_r, 1.0), 0.0)
    excess = np.maximum(yt[None] - yr, 0.0).mean(axis=1)
    ratio = np.where(mean_r > 0, yt.mean() / np.where(mean_r > 0, mean_r, 1.0), np.nan)
    return {"rmse": rmse, "indirect_relative_rmse": rel, "leak": leak, "indirect_excess": excess,
            "mean_ratio": ratio}


def _value(x) -> float | None:
    v = float(x)
    return v if math.isfinite(v) else None


def point_metrics(test, ref, e_direct, albedo, emission, exposure: float, err=None) -> dict:
    """The metrics of the module doc for (N, 3) test and reference indirect irradiance (no standard errors);
    ``err`` (N, 3): the reference's standard errors, whose noise bias is then removed (module doc)."""
    r = np.asarray(ref, np.float64)
    if len(r) == 0:
        return {k: None for k in METRICS}
    noise = None if err is None else _noise_variance(r, err, e_direct, albedo, emission, exposure)
    b = _metrics_batch(test, r[None], e_direct, albedo, emission, exposure, noise=noise)
    return {k: _value(v[0]) for k, v in b.items()}


def _img(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, np.float64).reshape(-1, 1, 3)


def _replicas(ref, err, replicas: int, seed: int) -> np.ndarray:
    r = np.asarray(ref, np.float64)
    s = np.asarray(err, np.float64)
    z = np.random.default_rng([int(seed), 0xB007]).standard_normal((int(replicas), len(r), 1))
    return np.maximum(r[None] + s[None] * z, 0.0)


def _debiased_rmse_stderr(diff, noise, mse: float, dof: int = NOISE_DOF, channels: int = 1) -> float:
    """Standard error of ``sqrt(max(mse, 0))``, a root of a debiased mean squared error (module doc, "Standard
    errors of the debiased rmse").

    ``diff`` (N, C): the errors against the noisy reference at each point; ``noise`` (N, C): the reference's
    standard error per channel (the channels share one noise draw per point); ``mse``: the debiased
    ``mean_i sum_c diff² / channels − mean noise²`` (``channels`` = C for a mean over the channels, 1 for a sum).
    Per point ``Var(|d − u z|²) = 4 (d·u)² + 2|u|⁴`` plus the noise of the subtracted ``|û|²`` (``2|u|⁴/ν``);
    estimated without bias from the noisy ``d̂ = d − u z₀`` and ``û`` (ν = ``dof`` degrees of freedom, Gaussian):
    ``4 (d̂·û)² − 2 (ν − 1)/(ν + 2) |û|⁴``, summed, and never below the noise's own part ``2 |u|⁴ (1 + 1/ν)``
    (a sum that can fall below 0 where the noise dominates: a standard error of 0 there would be false). Then the delta method through the square root, blended to the fourth
    root of the variance where the rmse is near 0: ``sqrt(V) / (r + sqrt(r² + sqrt(V)))``."""
    d, u = np.asarray(diff, np.float64), np.asarray(noise, np.float64)
    n = len(d)
    u4 = np.sum(u * u, axis=1) ** 2
    per = 4.0 * np.sum(d * u, axis=1) ** 2 - 2.0 * (dof - 1) / (dof + 2) * u4
    # at least the noise's own part, 2|u|⁴(1 + 1/ν) (unbiased: E|û|⁴ = |u|⁴(ν + 2)/ν): the unbiased sum can fall
    # below it, even below 0, where the noise dominates the error
    v = max(float(per.sum()), 2.0 * (dof + 1) / (dof + 2) * float(u4.sum())) / (n * n * channels * channels)
    r = math.sqrt(max(mse, 0.0))
    return math.sqrt(v) / (r + math.sqrt(r * r + math.sqrt(v))) if v > 0 else 0.0


def _mean_norm_stderr(ref, err) -> float:
    """Standard error of ``mean_i |R_i|`` (the denominator of ``indirect_relative_rmse``): the noise along each
    ``R_i``, one draw per point for all channels."""
    r, s = np.asarray(ref, np.float64), np.asarray(err, np.float64)
    norm = np.linalg.norm(r, axis=-1, keepdims=True)
    along = np.sum(np.divide(r, norm, out=np.zeros_like(r), where=norm > 0) * s, axis=-1)
    return math.sqrt(float(np.sum(along ** 2))) / len(r)


def reference_mean_stderr(err) -> float:
    """Standard error of the mean luminance of a reference over its points, ``err`` (..., 3) their RGB standard
    errors (one draw per point for all channels)."""
    e = np.asarray(err, np.float64).reshape(-1, 3)
    return float(np.sqrt(np.sum((e @ MT.REC709) ** 2)) / len(e))


def metrics_with_stderr(test, ref, err, e_direct, albedo, emission, *, replicas: int = REPLICAS,
                        seed: int = 0, exposure: float | None = None, cache: dict | None = None) -> dict:
    """:func:`point_metrics` plus ``<metric>_stderr`` for each (module doc); ``exposure`` default: from the
    reference's points. ``cache``: a dict kept across calls with the same reference, seed and exposure (the
    modes of one bake): the replicas and the noise terms are computed once."""
    r = np.asarray(ref, np.float64)
    if exposure is None:
        exposure = MT.exposure_for(_img(radiance(e_direct, r, albedo, emission))) if len(r) else 1.0
    if len(r) == 0:
        return {**{k: None for k in METRICS}, **{f"{k}_stderr": None for k in METRICS}}
    cache = {} if cache is None else cache
    if "noise" not in cache:
        d, a, e = (np.asarray(x, np.float64) for x in (e_direct, albedo, emission))
        cache["noise"] = _noise_variance(r, err, d, a, e, exposure)
        cache["replicas"] = _prepare(_replicas(r, err, replicas, seed), d, a, e, exposure)
    b = _metrics_batch(test, r[None], e_direct, albedo, emission, exposure, noise=cache["noise"])
    out = {k: _value(v[0]) for k, v in b.items()}          # point_metrics(..., err=err), its noise terms cached
    yr = MT.luminance(r)
    dark = yr <= MT.LEAK_TAU * yr.mean()           # the leak's standard error is conditional on its dark set
    reps = _metrics_batch(test, cache["replicas"], e_direct, albedo, emission, exposure, dark, cache["noise"])
    for k in METRICS:
        xs = reps[k][np.isfinite(reps[k])]
        out[f"{k}_stderr"] = float(np.std(xs, ddof=1)) if xs.size > 1 and out[k] is not None else None
    # the debiased rmse metrics: not the bootstrap (module doc, "Standard errors of the debiased rmse")
    d, a, e = (np.asarray(x, np.float64) for x in (e_direct, albedo, emission))
    t, s = np.asarray(test, np.float64), np.asarray(err, np.float64)
    v_irr, v_tm = cache["noise"]
    lt = MT.tonemap(radiance(d, t, a, e), exposure).astype(np.float64)
    lr = MT.tonemap(radiance(d, r, a, e), exposure).astype(np.float64)
    mse_tm = float(np.mean((lt - lr) ** 2) - v_tm.mean())
    out["rmse_stderr"] = _debiased_rmse_stderr(lt - lr, np.sqrt(v_tm), mse_tm, channels=3)
    den = float(np.mean(np.linalg.norm(r, axis=-1)))
    if out["indirect_relative_rmse"] is not None and den > 0:
        mse = float(np.mean(np.sum((t - r) ** 2, axis=-1)) - v_irr.mean())
        sd_num = _debiased_rmse_stderr(t - r, s, mse)
        sd_den = _mean_norm_stderr(r, s)              # and the denominator's noise, in quadrature
        out["indirect_relative_rmse_stderr"] = math.hypot(sd_num / den, out["indirect_relative_rmse"] * sd_den / den)
    return out


def _debiased_terms(diff, noise, dof: int = NOISE_DOF) -> tuple[float, float]:
    """The two parts of ``Var(Σ_i |d_i − u_i z_i|² − |û_i|²)`` (:func:`_debiased_rmse_stderr`), estimated from the
    noisy errors ``diff`` and standard errors ``noise`` (N, C): ``(A, B)`` with ``A = 4 Σ(d·u)²`` (the error times
    the noise: falls as 1/k with k times the paths) and ``B = 2 (1 + 1/ν) Σ|u|⁴`` (the noise squared: 1/k²); their
    sum is the variance :func:`_debiased_rmse_stderr` uses (``A`` clamped at 0)."""
    d, u = np.asarray(diff, np.float64), np.asarray(noise, np.float64)
    u4 = np.sum(u * u, axis=1) ** 2
    b = 2.0 * (dof + 1) / (dof + 2) * float(u4.sum())                         # E|û|⁴ = |u|⁴ (ν + 2)/ν
    a = 4.0 * float(np.sum(np.sum(d * u, axis=1) ** 2 - dof / (dof + 2) * u4))  # E(d̂·û)² ≈ (d·u)² + |u|⁴
    return max(a, 0.0), b


def _root_paths(a: float, b: float, scale: float, extra: float, target: float) -> float | None:
    """The smallest k with ``(a/k + b/k²)/scale + extra/k <= target²``: the relative variance of a debiased root
    (``scale = 4 r⁴ (N·C)²``) plus a linear part's (``extra``), at k times the reference's paths."""
    a1, b1 = a / scale + extra, b / scale
    t2 = target * target
    if b1 <= 0:
        return a1 / t2 if a1 > 0 else 0.0
    x = (-a1 + math.sqrt(a1 * a1 + 4.0 * b1 * t2)) / (2.0 * b1)               # x = 1/k
    return 1.0 / x if x > 0 else None


def paths_for_stderr(test, ref, err, e_direct, albedo, emission, *, target: float = 0.02,
                     exposure: float | None = None, stderr: dict | None = None) -> dict:
    """How many times the reference's paths (at every point) each metric of one test would need for its standard
    error to be ``target`` of its value: ``{metric: k}`` (k < 1: already there; None: the value is 0 or undefined,
    no relative error exists). Arguments as :func:`metrics_with_stderr`; ``stderr``: its result, if at hand.

    A reference of k times the paths has standard errors ``s/√k``. The debiased ``rmse`` and
    ``indirect_relative_rmse`` (module doc, "Standard errors of the debiased rmse") have a variance of two parts,
    ``A/k + B/k²`` (:func:`_debiased_terms`: the error times the noise, and the noise squared — which dominates
    where a mode's error is below the reference's noise), solved for k at the value measured now (the debiased
    value does not move with k in expectation). The bootstrap metrics (``leak``, ``indirect_excess``,
    ``mean_ratio``) scale as ``1/√k``: ``k = (stderr / value / target)²`` — for the leak a lower bound where the
    reference's noise at the dark points makes much of its value (a mean absolute difference is not debiased, so it
    falls as the noise does). This says what the reference would cost (tests/bench/bench_evaluate.py ``--cost``),
    not what the stage does."""
    r = np.asarray(ref, np.float64)
    if len(r) == 0:
        return {k: None for k in METRICS}
    d, a, e = (np.asarray(x, np.float64) for x in (e_direct, albedo, emission))
    t, s = np.asarray(test, np.float64), np.asarray(err, np.float64)
    if exposure is None:
        exposure = MT.exposure_for(_img(radiance(d, r, a, e)))
    m = stderr or metrics_with_stderr(t, r, s, d, a, e, exposure=exposure)
    out = {}
    for k in ("leak", "indirect_excess", "mean_ratio"):
        v, se = m.get(k), m.get(f"{k}_stderr")
        out[k] = (se / abs(v) / target) ** 2 if v and se is not None else None
    v_irr, v_tm = _noise_variance(r, s, d, a, e, exposure)
    n = len(r)
    rv = m.get("rmse")
    if rv:
        lt = MT.tonemap(radiance(d, t, a, e), exposure).astype(np.float64)
        lr = MT.tonemap(radiance(d, r, a, e), exposure).astype(np.float64)
        A, B = _debiased_terms(lt - lr, np.sqrt(v_tm))
        out["rmse"] = _root_paths(A, B, 4.0 * rv ** 4 * (3 * n) ** 2, 0.0, target)
    else:
        out["rmse"] = None
    rel = m.get("indirect_relative_rmse")
    den = float(np.mean(np.linalg.norm(r, axis=-1)))
    if rel and den > 0:
        A, B = _debiased_terms(t - r, s)
        root = rel * den
        out["indirect_relative_rmse"] = _root_paths(A, B, 4.0 * root ** 4 * n * n, (_mean_norm_stderr(r, s) / den) ** 2,
                                                    target)
    else:
        out["indirect_relative_rmse"] = None
    return out


def _paired_root_delta_stderr(diff_a, diff_b, noise, ra: float, rb: float, channels: int = 1,
                              dof: int = NOISE_DOF) -> float:
    """Standard error of ``rb − ra``, the difference of two debiased roots ``r = sqrt(max(mse, 0))`` of errors
    against ONE noisy reference (module doc, "Paired deltas").

    ``diff_a``, ``diff_b`` (N, C): each test's errors against the noisy reference; ``noise`` (N, C): the reference's
    standard error per channel (one draw per point for all channels); ``channels`` as in
    :func:`_debiased_rmse_stderr`. ``rb − ra = Δmse / g`` with ``g = ra + rb``; per point the noise of
    ``Δmse − Δ·g`` is ``−2z(u·Δd − Δw) − Δk|u|²(z² − 1)`` (``w = u·(d_a/2ra + d_b/2rb)``, ``k = 1/2ra + 1/2rb``),
    whose variance ``4(u·Δd − Δw)² + 2Δ²k²|u|⁴(1 + 1/ν)`` is estimated without bias from the noisy ``d̂``, ``û``
    as in :func:`_debiased_rmse_stderr`; its root ``sd`` divided by ``(g + sqrt(g² + 4 sd)) / 2`` (``g`` where
    ``g² ≫ sd``; ``sqrt(sd)``, the scale of a root of a quantity ±sd, as both roots approach 0).
    Where a root is clamped at 0, its slope is undefined: the delta of the mse alone, ``4 Σ(u·Δd)²``."""
    da, db, u = (np.asarray(x, np.float64) for x in (diff_a, diff_b, noise))
    n = len(u)
    lin = np.sum(u * (db - da), axis=1)                                   # u·Δd, free of the reference's noise
    u4 = np.sum(u * u, axis=1) ** 2
    g = ra + rb
    if ra > 0 and rb > 0:
        delta, k = rb - ra, 0.5 / ra + 0.5 / rb
        w = np.sum(u * (da / (2 * ra) + db / (2 * rb)), axis=1)
        per = 4.0 * (lin - delta * w) ** 2 - 2.0 * (dof - 1) / (dof + 2) * delta * delta * k * k * u4
        floor = 2.0 * (dof + 1) / (dof + 2) * delta * delta * k * k * float(u4.sum())   # as _debiased_rmse_stderr
    else:
        per, floor = 4.0 * lin ** 2, 0.0
    v = max(float(per.sum()), floor) / (n * n * channels * channels)
    if v <= 0:
        return 0.0
    sd = math.sqrt(v)
    return sd / (0.5 * (g + math.sqrt(g * g + 4.0 * sd)))


def paired_delta_stderr(test_a, test_b, ref, err, e_direct, albedo, emission, *, replicas: int = REPLICAS,
                        seed: int = 0, exposure: float | None = None, cache: dict | None = None) -> dict:
    """Standard errors of ``metric(test_b) − metric(test_a)`` for two tests scored against ONE reference
    (module doc, "Paired deltas"): ``{metric: stderr}`` for :data:`METRICS` (None where a metric is undefined).

    ``test_a``, ``test_b``, ``ref``, ``err``, ``e_direct``, ``albedo``, ``emission``: (N, 3) as in
    :func:`metrics_with_stderr`, linear RGB, lux; ``exposure`` default: from the reference's points (the same as
    the bakes' own metrics). Two bakes of one scene and lighting share the cached reference, so its noise is
    common to both metrics and largely cancels in their difference; ``sqrt(seA² + seB²)`` counts it twice, and in
    full, however close the two bakes are. ``cache``: a dict kept across calls with the same reference, seed and
    exposure (the modes of two bakes): the noise terms and the replicas are computed once."""
    r, s = np.asarray(ref, np.float64), np.asarray(err, np.float64)
    if len(r) == 0:
        return {k: None for k in METRICS}
    d, a, e = (np.asarray(x, np.float64) for x in (e_direct, albedo, emission))
    ta, tb = np.asarray(test_a, np.float64), np.asarray(test_b, np.float64)
    if exposure is None:
        exposure = MT.exposure_for(_img(radiance(d, r, a, e)))
    cache = {} if cache is None else cache
    if "noise" not in cache:
        cache["noise"] = _noise_variance(r, s, d, a, e, exposure)
        cache["replicas"] = _prepare(_replicas(r, s, replicas, seed), d, a, e, exposure)
    noise, reps = cache["noise"], cache["replicas"]
    # the bootstrap, paired: both tests against the same replicas (and the same dark set of the leak)
    yr = MT.luminance(r)
    dark = yr <= MT.LEAK_TAU * yr.mean()
    ba = _metrics_batch(ta, reps, d, a, e, exposure, dark, noise)
    bb = _metrics_batch(tb, reps, d, a, e, exposure, dark, noise)
    out = {}
    for k in METRICS:
        diff = bb[k] - ba[k]
        diff = diff[np.isfinite(diff)]
        out[k] = float(np.std(diff, ddof=1)) if diff.size > 1 else None
    # the two debiased rmse: Δmse is linear in the noise, Var exact for one draw per point (module doc)
    v_irr, v_tm = noise
    lr = MT.tonemap(radiance(d, r, a, e), exposure).astype(np.float64)
    la = MT.tonemap(radiance(d, ta, a, e), exposure).astype(np.float64)
    lb = MT.tonemap(radiance(d, tb, a, e), exposure).astype(np.float64)
    root = [math.sqrt(max(float(np.mean((x - lr) ** 2) - v_tm.mean()), 0.0)) for x in (la, lb)]
    out["rmse"] = _paired_root_delta_stderr(la - lr, lb - lr, np.sqrt(v_tm), *root, channels=3)
    den = float(np.mean(np.linalg.norm(r, axis=-1)))
    if den > 0:
        root = [math.sqrt(max(float(np.mean(np.sum((x - r) ** 2, axis=-1)) - v_irr.mean()), 0.0)) for x in (ta, tb)]
        sd_den = _mean_norm_stderr(r, s)
        delta = (root[1] - root[0]) / den
        out["indirect_relative_rmse"] = math.hypot(_paired_root_delta_stderr(ta - r, tb - r, s, *root) / den,
                                                   delta * sd_den / den)
    else:
        out["indirect_relative_rmse"] = None
    return out


def region_ratios(test, ref, err, regions: dict, *, replicas: int = REPLICAS, seed: int = 0) -> dict:
    """Per region (name -> point indices into (P, D, 3) arrays): ``{name: {"mean_ratio", "mean_ratio_stderr",
    "reference_mean", "reference_mean_stderr", "mean"}}`` of luminance over the region's points and normals."""
    t = np.asarray(test, np.float64)
    r = np.asarray(ref, np.float64)
    s = np.asarray(err, np.float64)
    out = {}
    for name, idx in (regions or {}).items():
        idx = np.asarray(idx, np.int64)
        yt = MT.luminance(t[idx]).ravel()
        rr, ss = r[idx].reshape(-1, 3), s[idx].reshape(-1, 3)
        yr = MT.luminance(rr)
        mr = float(yr.mean())
        reps = MT.luminance(_replicas(rr, ss, replicas, seed)).mean(axis=1)       # (replicas,)
        ratio = float(yt.mean()) / mr if mr > 0 else None
        ratios = [float(yt.mean()) / m for m in reps if m > 0]
        out[name] = {"mean_ratio": ratio,
                     "mean_ratio_stderr": float(np.std(ratios, ddof=1)) if ratio is not None and len(ratios) > 1
                     else None,
                     "mean": float(yt.mean()), "reference_mean": mr,
                     "reference_mean_stderr": reference_mean_stderr(ss)}
    return out


def point_summary(modes, recon: dict, pts: dict, seed: int) -> tuple[dict, dict]:
    """Flat ``{"<mode>.<metric>": value}`` (and ``_stderr``) over the surface points, and per mode the dicts of
    :func:`metrics_with_stderr`; plus ``reference.mean_indirect`` (lux) and its standard error.

    ``recon[mode]`` (N, 3): the mode's indirect irradiance at the points; ``pts``: the reference's column groups
    (:func:`workers.kernels.reference_layout.point_columns`). The exposure is the reference's (module doc).
    """
    summary, per_mode = {}, {}
    if len(pts["position"]) == 0:
        return summary, per_mode
    exposure = MT.exposure_for(radiance(pts["e_direct"], pts["e_indirect"], pts["albedo"],
                                        pts["emission"]).reshape(-1, 1, 3))
    cache: dict = {}
    for m in modes:
        r = metrics_with_stderr(recon[m], pts["e_indirect"], pts["stderr"], pts["e_direct"], pts["albedo"],
                                pts["emission"], seed=seed, exposure=exposure, cache=cache)
        per_mode[m] = r
        for k, v in r.items():
            if v is not None and math.isfinite(v):
                summary[f"{m}.{k}"] = float(v)
    lum = MT.luminance(pts["e_indirect"])
    summary["reference.mean_indirect"] = float(lum.mean())
    summary["reference.mean_indirect_stderr"] = reference_mean_stderr(pts["stderr"])
    return summary, per_mode


def check_point_report(doc: dict, modes, mode_values, seed: int, summary: dict) -> dict:
    """The ``check_points`` document: the reference's check points ``doc`` (points (P, 3), normals (P, D, 3),
    reference_direct / _indirect / _stderr [point][normal] RGB, regions {name: [point index]}) with each mode's
    values, ``mode_values(mode, points (P·D, 3), normals (P·D, 3)) -> (P·D, 3)``; with regions, per region and
    mode :func:`region_ratios`, and ``<mode>.region.<name>.mean_ratio`` (and ``_stderr``) added to ``summary``."""
    cp = np.asarray(doc["points"], np.float64)
    cn = np.asarray(doc["normals"], np.float64)                       # (P, D, 3)
    P, D = cn.shape[:2]
    cpts, cnrm = np.repeat(cp, D, axis=0), cn.reshape(-1, 3)
    check = {k: doc[k] for k in ("points", "normals", "reference_direct", "reference_indirect", "reference_stderr")}
    check["modes"] = {}
    cref = np.asarray(doc["reference_indirect"], np.float64)
    cerr = np.asarray(doc["reference_stderr"], np.float64)
    for m in modes:
        v = mode_values(m, cpts, cnrm).reshape(P, D, 3)
        check["modes"][m] = v.tolist()
        if doc.get("regions"):
            for name, r in region_ratios(v, cref, cerr, doc["regions"], seed=seed).items():
                for k in ("mean_ratio", "mean_ratio_stderr"):
                    if r[k] is not None and math.isfinite(r[k]):
                        summary[f"{m}.region.{name}.{k}"] = float(r[k])
    if doc.get("regions"):
        check["regions"] = {name: {"points": idx, **{m: region_ratios(
            np.asarray(check["modes"][m]), cref, cerr, {name: idx}, seed=seed)[name]
            for m in modes}} for name, idx in doc["regions"].items()}
    return check
