"""The path-traced reference at G-buffer pixels and at surface points: direct light plus
:func:`workers.kernels.pathtrace.indirect_irradiance` (DESIGN stage 7).

The exitant radiance of a Lambertian surface is ``L_out = Le + albedo/π · (E_direct + E_indirect)``
(the light stage's ray shading, DDGI-I §3.4); :func:`exitant_radiance` forms it per pixel.
Consumers: stage ``reference`` (through :func:`irradiance_at_points` and :func:`reference_at_gbuffer`), tests.
Inverse: none.
"""
from __future__ import annotations

import math
import time

import numpy as np

from workers.kernels import metrics as MT
from workers.kernels.pathtrace import DEFAULT_MAX_PATHS, indirect_irradiance, scene_eps
from workers.kernels.shading import direct_irradiance

__all__ = ["refine_points", "pilot_spp", "tail_guess", "PILOT_FRACTION", "DARK_FRACTION",
           "REFINE_BUDGET", "POOL_NEIGHBOURS", "irradiance_at_points", "reference_at_gbuffer", "exitant_radiance"]


def reference_at_gbuffer(scene, gbuffer, lights=(), *, sky=(0.0, 0.0, 0.0), caster=None, eps=None, spp: int = 64,
                         bounces: int = 4, seed: int = 0, rr_depth: int | None = None,
                         max_paths: int = DEFAULT_MAX_PATHS, emitter_sampling: bool = True, report=None) -> dict:
    """Direct and path-traced indirect irradiance at every shaded pixel of a G-buffer.

    Returns ``{"e_direct", "e_indirect", "stderr", "radiance"}`` (H, W, 3) float32 images (0 outside
    ``gbuffer.shaded``) and ``"stats"``. ``radiance`` = :func:`exitant_radiance`.
    """
    from workers.raycast import caster_for_scene

    caster = caster_for_scene(scene) if caster is None else caster
    eps = scene_eps(scene) if eps is None else float(eps)
    H, W = gbuffer.shape
    sel = gbuffer.shaded.ravel()
    pts = gbuffer.position.reshape(-1, 3)[sel].astype(np.float64)
    nrm = gbuffer.normal.reshape(-1, 3)[sel].astype(np.float64)
    geo = gbuffer.geo_normal.reshape(-1, 3)[sel].astype(np.float64)
    t0 = time.perf_counter()
    e_dir = np.zeros((H * W, 3), np.float32)
    if lights:
        # shadow rays start at x + eps·n (shading normal, facing the camera), as in the light stage
        e_dir[sel] = direct_irradiance(pts, nrm, list(lights), caster, eps)
    t_direct = time.perf_counter() - t0
    res = indirect_irradiance(scene, pts, nrm, lights, sky=sky, spp=spp, bounces=bounces, seed=seed,
                              rr_depth=rr_depth, caster=caster, eps=eps, geo_normals=geo, max_paths=max_paths,
                              emitter_sampling=emitter_sampling, report=report)
    e_ind = np.zeros((H * W, 3), np.float32)
    err = np.zeros((H * W, 3), np.float32)
    e_ind[sel] = res.irradiance
    err[sel] = res.stderr
    e_dir, e_ind, err = (a.reshape(H, W, 3) for a in (e_dir, e_ind, err))
    stats = dict(res.stats, direct_seconds=t_direct, pixels=int(sel.sum()))
    return {"e_direct": e_dir, "e_indirect": e_ind, "stderr": err,
            "radiance": exitant_radiance(gbuffer, e_dir, e_ind), "stats": stats}


def exitant_radiance(gbuffer, e_direct, e_indirect) -> np.ndarray:
    """(H, W, 3) float32 ``emission + albedo/π · (E_direct + E_indirect)`` on shaded pixels, 0 elsewhere
    (back faces of single-sided surfaces, uncovered pixels)."""
    e = np.asarray(e_direct, np.float32) + np.asarray(e_indirect, np.float32)
    out = gbuffer.emission + gbuffer.albedo / np.float32(math.pi) * e
    return np.where(gbuffer.shaded[..., None], out, 0.0).astype(np.float32)



def irradiance_at_points(scene, points, normals, geo_normals, lights=(), *, sky=(0.0, 0.0, 0.0), spp: int = 64,
                         bounces: int = 4, seed: int = 0, rr_depth: int | None = None, caster=None, eps=None,
                         batch_points: int = 256, tail=None,
                         report=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Direct irradiance, path-traced indirect irradiance and its standard error at N points.

    Parameters
    ----------
    points, normals, geo_normals : (N, 3) float
        World-space points (metres), unit shading normals and geometric normals on the lit side.
    lights, sky, spp, bounces, seed, rr_depth, caster, eps, tail
        As :func:`workers.kernels.pathtrace.indirect_irradiance` (``tail``: e.g. :func:`tail_guess` of a pilot).
    batch_points : int
        Points per wavefront chunk (``batch_points × spp`` paths, at most
        :data:`workers.kernels.pathtrace.DEFAULT_MAX_PATHS`); the result does not depend on it.
    report : callable(fraction)
        Progress, after each chunk.

    Returns
    -------
    ``e_direct``, ``e_indirect``, ``stderr`` (N, 3) float64 (linear RGB irradiance, W/m² per unit of the
    lights' and sky's units) and the tracer's stats (``{}`` for N = 0).
    """
    from workers.raycast import caster_for_scene

    n = len(points)
    e_dir = np.zeros((n, 3))
    e_ind = np.zeros((n, 3))
    err = np.zeros((n, 3))
    if n == 0:
        if report is not None:
            report(1.0)
        return e_dir, e_ind, err, {}
    caster = caster_for_scene(scene) if caster is None else caster
    eps = scene_eps(scene) if eps is None else float(eps)
    if lights:
        e_dir[:] = direct_irradiance(points, normals, lights, caster, eps)
    stats = {"rays": 0, "seconds": 0.0, "batches": 0}
    res = indirect_irradiance(scene, points, normals, lights, sky=sky, spp=spp, bounces=bounces, seed=seed,
                              rr_depth=rr_depth, caster=caster, eps=eps, geo_normals=geo_normals,
                              max_paths=min(batch_points * spp, DEFAULT_MAX_PATHS), tail=tail, report=report)
    e_ind[:] = res.irradiance
    err[:] = res.stderr
    stats.update(rays=int(res.stats["rays"]), seconds=float(res.stats["seconds"]),
                 batches=int(math.ceil(n / batch_points)), rr_kills=int(res.stats["rr_kills"]),
                 vertices=int(res.stats["vertices"]), below_surface=int(res.stats["below_surface"]))
    return e_dir, e_ind, err, stats


def tail_guess(e_indirect) -> np.ndarray:
    """(N, 3) the Russian-roulette control variate of :func:`workers.kernels.pathtrace.indirect_irradiance`
    (``tail``) from an independent estimate of the points' indirect irradiance (a pilot pass): ``E/π``, the mean
    radiance a continuing path gathers per unit throughput where the light around it is the point's own."""
    return np.maximum(np.asarray(e_indirect, np.float64), 0.0) / math.pi


DARK_FRACTION = 2 * MT.LEAK_TAU
"""Surface points whose reference luminance is at most this fraction of the mean get ``dark_spp`` paths
(:func:`refine_points`): twice the leak metric's threshold, so that points near it are refined too."""

REFINE_BUDGET = 1.0
"""At most this many times the first pass's paths are spent on noisy points (dark points not counted)."""

DARK_BUDGET = 1.0
"""Dark points share this many times the first pass's paths (N × spp) among them, each at least ``dark_spp`` and at
most :data:`DARK_MAX_SPP` (:func:`refine_points`): where they are few, each gets many more paths than ``dark_spp``."""

DARK_MAX_SPP = 131072
"""The most paths a dark point gets from :data:`DARK_BUDGET` (more only when ``dark_spp`` asks)."""

POOL_NEIGHBOURS = 16
""":func:`refine_points` judges a point's noise by the pilot's paths at this many nearest surface points (itself
included) that face its way (normals within 25.8°: :data:`POOL_COS`)."""

POOL_COS = 0.9


PILOT_FRACTION = 0.25
"""The pilot pass that decides :func:`refine_points`' extra paths has this fraction of ``spp`` paths per point."""


def pilot_spp(spp: int) -> int:
    """Paths per point of the pilot pass (:data:`PILOT_FRACTION` of ``spp``, at least 8)."""
    return max(int(round(PILOT_FRACTION * int(spp))), 8)


def refine_points(trace, e_direct, e_indirect, stderr, spp: int, max_spp: int, *, budget: float = REFINE_BUDGET,
                  pilot=None, surface: dict | None = None, dark_budget: float = DARK_BUDGET,
                  dark_max: int = DARK_MAX_SPP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """More paths where the reference's noise weighs most on the metrics, so that no metric is decided by a few noisy
    points.

    The metrics (:mod:`workers.kernels.point_metrics`) weigh every point alike. Their noise comes from two kinds of
    point: those the leak metrics pick by a threshold on the reference (dark points), and those whose noise is
    largest in the units the two rmse metrics square — irradiance (``indirect_relative_rmse``) and tone-mapped
    exitant radiance (``rmse``), where the tone map's steep foot makes dim points with a heavy tail count most
    (two-rooms, 192 paths: 1% of the points held 44% of the ``rmse`` noise's fourth power, most of them dim points
    at 30-60% relative noise that kept their 192 paths). So after the first pass of ``spp`` paths:

    * **dark** points (luminance at most :data:`DARK_FRACTION` of the mean, or at most twice that and within two
      standard errors of it: a pilot of 48 paths that caught one rare bright path reads a dark point bright) share
      ``dark_budget × N × spp`` paths, each ``spp·2^k`` in all, at least ``max_spp`` and at most ``dark_max`` (or
      ``max_spp`` if more). Only the dark points carry the leak metrics' noise, and where they are few each needs
      many paths: zdm2-sauerbraten (a sun and a sky) has 4 of 2,048, whose leak metrics at 1,024 paths each read
      ± 13-38% (a heavy tail: one point ± 34% of its value) — and a mean absolute difference is not debiased, so
      that noise was most of the accurate modes' leak values;
    * every other point gets ``n = spp·2^k`` paths, the least k with ``n >= c·w`` (at most ``max_spp``), for a weight
      ``w = max((v_E / mean v_E)^½, (v_C / mean v_C)^½)``: ``v_E`` a path's variance of the point's luminance
      irradiance, ``v_C`` of its tone-mapped exitant radiance (the delta method of
      :func:`workers.kernels.point_metrics._noise_variance`, the exposure of the points), means over the points
      that are not dark; ``c`` the largest that spends at most ``budget × N × spp`` extra paths on them. The square
      root is the allocation that minimises ``Σ v_i/n_i`` at a given ``Σ n_i``: the noise of an rmse is
      ``Σ 4(d_i·u_i)² + 2|u_i|⁴`` with ``|u_i|² = v_i/n_i`` and errors ``d_i`` unknown here (they are the mode's).
    * the variances are **pooled** over the point's :data:`POOL_NEIGHBOURS` nearest surface points facing its way
      (``surface``: ``position`` and ``normal``): a pilot of 48 paths does not see its own rare bright paths
      (two-rooms: log-correlation of a pilot point's tone-mapped variance with the refined reference's 0.29 on its
      own, 0.73 pooled over 16).

    Measured (two-rooms, default config, scored on the same bake's modes; docs/architecture.md, the evaluate
    stage): against the rule this replaced (relative noise above 20% of the light, up to 1.5x the paths) the relative
    standard errors of ``rmse`` 0.212 → 0.140 (ddgi) and 0.188 → 0.123 (normalized mask), of
    ``indirect_relative_rmse`` 0.172 → 0.121 and 0.163 → 0.126, at 1.2% fewer paths.

    ``trace(index, paths)`` path-traces the points ``index`` with ``paths`` more paths each (another seed per
    ``paths``) and returns their ``(e_indirect, stderr)``; ``e_direct``, ``e_indirect``, ``stderr`` (N, 3): the
    first pass. The estimates are pooled by path count: ``E = (n₁E₁ + n₂E₂)/(n₁ + n₂)``,
    ``s = sqrt(n₁²s₁² + n₂²s₂²)/(n₁ + n₂)``. Returns the new (N, 3) arrays and the (N,) paths per point.
    ``surface`` (optional): ``position``, ``normal`` (N, 3) for the pooling (else each point alone), ``albedo``
    and ``emission`` (N, 3) for ``v_C`` (else ``v_E`` alone).

    **Pilot** (``pilot = (e_indirect, stderr, paths)`` of an independent pass, :func:`pilot_spp` paths a point, its
    own seed): the choice of which points get more paths is made on the pilot, and the pilot is then discarded.
    Chosen on the first pass itself, the choice selects on that pass's noise: a point whose paths happened to miss
    its rare bright contributions shows a small ``s`` and is left alone, one that caught one is refined and diluted,
    so the pooled values are biased low and their ``s`` biased low — the metrics' noise correction
    (:mod:`workers.kernels.point_metrics`, "Noise bias") then under-corrects. Measured on two-rooms at 192 paths:
    the refined reference read the ddgi mode's ``indirect_relative_rmse`` 0.057 and ``mean_ratio`` 1.039 where the
    same reference without refinement read 0.038 and 1.032. With the choice made on an independent pilot (and the
    pooling over neighbours reads only the pilot), the first pass and the refinement paths are fresh samples whatever
    was chosen: each point's pooled ``E`` and ``s²`` are unbiased (test_reference.py).
    ``pilot=None``: the choice is made on the first pass (biased; kept for callers without a pilot).
    """
    e = np.array(e_indirect, np.float64)
    s = np.array(stderr, np.float64)
    n_pts, spp, max_spp = len(e), int(spp), int(max_spp)
    paths = np.full(n_pts, spp, np.int64)
    if n_pts == 0 or max_spp <= spp:
        return e, s, paths
    # what the choice is made on: the pilot, else the first pass itself; per-path variances (s² × paths)
    e_c, s_c, n_c = (e, s, spp) if pilot is None else (np.asarray(pilot[0], np.float64),
                                                        np.asarray(pilot[1], np.float64), int(pilot[2]))
    y = MT.luminance(e_c)
    mean = float(y.mean())
    thr, sy = DARK_FRACTION * mean, np.abs(s_c @ MT.REC709)
    dark = ((y <= thr) | ((y - 2.0 * sy <= thr) & (y <= 2.0 * thr))) if mean > 0 else np.zeros(n_pts, bool)
    variances = [(s_c @ MT.REC709) ** 2 * n_c]
    surface = surface or {}
    if surface.get("albedo") is not None and surface.get("emission") is not None:
        from workers.kernels import point_metrics as PM
        d, a, em = (np.asarray(x, np.float64) for x in (e_direct, surface["albedo"], surface["emission"]))
        exposure = MT.exposure_for(PM._img(PM.radiance(d, e_c, a, em)))
        variances.append(PM._noise_variance(e_c, s_c, d, a, em, exposure)[1].sum(axis=1) * n_c)
    if surface.get("position") is not None and surface.get("normal") is not None and n_pts > 1:
        from scipy.spatial import cKDTree
        x, nrm = (np.asarray(surface[k], np.float64) for k in ("position", "normal"))
        _, idx = cKDTree(x).query(x, k=min(POOL_NEIGHBOURS, n_pts))
        same = (np.einsum("ij,ikj->ik", nrm, nrm[idx]) > POOL_COS).astype(np.float64)
        same[:, 0] = 1.0                                     # the point itself
        variances = [(v[idx] * same).sum(axis=1) / same.sum(axis=1) for v in variances]
    w = np.zeros(n_pts)
    for v in variances:
        m = float(v[~dark].mean()) if (~dark).any() else 0.0
        if m > 0:
            w = np.maximum(w, np.sqrt(v / m))
    w[dark] = 0.0

    def want_at(c: float) -> np.ndarray:
        n = np.clip(c * w, spp, max_spp)
        return np.minimum(spp * 2.0 ** np.ceil(np.log2(n / spp) - 1e-9), max_spp).astype(np.int64)

    extra = float(budget) * n_pts * spp
    want = np.full(n_pts, spp, np.int64)
    if w.max() > 0 and extra > 0:              # the largest c within the budget (bisection on log c)
        lo, hi = math.log(spp / w.max()), math.log(max_spp / max(w[w > 0].min(), 1e-300)) + 1.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if (want_at(math.exp(mid)) - spp).sum() > extra:
                hi = mid
            else:
                lo = mid
        want = want_at(math.exp(lo))
    if dark.any():                             # the dark points' share: a power-of-two multiple of spp each
        share = spp + float(dark_budget) * n_pts * spp / int(dark.sum())
        share = min(share, max(int(dark_max), max_spp))
        want[dark] = max(max_spp, int(spp * 2.0 ** math.floor(math.log2(share / spp) + 1e-9)))
    for n in np.unique(want[want > spp]):
        idx = np.flatnonzero(want == n)
        n1, n2 = spp, int(n) - spp
        e2, s2 = trace(idx, n2)
        e[idx] = (n1 * e[idx] + n2 * np.asarray(e2, np.float64)) / (n1 + n2)
        s[idx] = np.sqrt((n1 * s[idx]) ** 2 + (n2 * np.asarray(s2, np.float64)) ** 2) / (n1 + n2)
    paths[:] = want
    return e, s, paths
