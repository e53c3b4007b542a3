"""Stage ``masks``: per-sample masks (MD §3.2-3.4 steps 4-6; DESIGN stage 4).

Reads ``place`` (grid stats), ``trace`` (``probe_states``), ``visibility`` (``theta_0123``, ``theta_4567``,
``dont_care``) and ``anneal`` (``clusters``), and ``light`` (``sh_l1_full``) only with ``masks.light_aware``; config
``masks`` (sigma, light_aware, light_aware_penalty). (``relocate`` is an input of the stage for its cache key only.)
Without the light-aware fit nothing here depends on the light, so a bake runs this stage and ``compress`` beside the
light stage (:func:`proto.stages.expand`); the cluster probe volumes, which do, are stage ``clusters``
(:mod:`workers.stages.clusters`).

Per refined-grid sample (:mod:`workers.kernels.mask_fit`):

1. eq 5 minimized locally given g: ``m_k`` = the φ-weighted median of θ over cluster k's non-OFF
   corners of the sample's cell (exact minimizer of ``Σ_{i: g_i = k} φ_i |θ_i − m_k|``); 0 for a
   cluster with no corner there;
2. optional (``light_aware``): eq 9, a box-constrained (0 ≤ m ≤ 1) least-squares refit of m against
   the visibility-weighted reference light field (eq 2 normalized) built from the probes' L1 SH, with
   the λ penalty on channels that were 0 — exact per-sample coordinate descent (numba);
3. don't-care samples (inside geometry) filled from their neighbours (breadth-first layers, mean
   of the closer layer), so trilinear filtering at surfaces is not dragged to 0;
4. a Gaussian filter of ``sigma`` samples (0 = none), clamp-to-edge, that keeps zero channels zero
   (departure from MD step 6: filtering a cluster's mask across a wall leaks its light; see
   :func:`workers.kernels.mask_fit.gaussian_filter`);
5. quantized to bytes ``round(255·m)``.

Outputs
-------
``masks_0123`` (and ``masks_4567`` when K > 4) : (Z, Y, X, 4) uint8 RGBA8 UNORM, zstd 3 — m_k·255 for
    clusters 0-3 (4-7); channels of clusters ≥ K are 0. Same refined grid and addressing as θ.
stats : ``clusters``, ``residual_eq5`` (R̂ of the eq-5 masks, in samples), ``residual_stored``
    (R̂ of the stored bytes, after light-aware fit, fill and filter), ``visible_mass`` (Σ φθ), their
    ratios ``relative_residual_eq5`` / ``relative_residual_stored``, ``channels_per_sample`` (mean
    nonzero stored channels per care sample), ``multi_channel_fraction`` (care samples with ≥ 2),
    ``filled`` (don't-care samples filled), ``light_aware`` (loss before/after or null), seconds.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from workers.kernels.mask_field import join_theta
from workers.kernels.mask_fit import (canonicalize, fill_dont_care, fit_masks, gaussian_filter, light_aware_fit,
                                      mask_residual, quantize, rgba_group)
from workers.stages.base import Artifact, StageContext, StageOutput, probe_sh_l1

ZSTD_LEVEL = 3


def run_masks(ctx: StageContext) -> StageOutput:
    sec = ctx.config.masks
    place = ctx.inputs["place"].stats
    counts = [int(c) for c in place["counts"]]
    nx, ny, nz = counts
    P = nx * ny * nz
    K = int(sec.clusters)
    vis = ctx.inputs["visibility"]
    theta = join_theta(vis["theta_0123"], vis["theta_4567"])
    S = theta.shape[2] // max(nx - 1, 1)                                     # samples per cell axis
    dont_care = np.asarray(vis["dont_care"]).reshape(theta.shape[:3]).astype(bool)
    states = ctx.inputs["trace"]["probe_states"].reshape(-1)
    g = ctx.inputs["anneal"]["clusters"].reshape(-1).astype(np.int64)
    # the residuals are statistics: each runs on a second thread (its kernel holds no GIL) beside what follows
    side = ThreadPoolExecutor(1, thread_name_prefix="kiln-masks")
    t0 = time.perf_counter()
    m = fit_masks(theta, dont_care, counts, S, g, K, states)                               # eq 5
    m5 = m
    residual5 = side.submit(mask_residual, theta, dont_care, counts, S, g, m5, states)
    t_fit = time.perf_counter() - t0
    ctx.report(0.3)

    la = None
    t1 = time.perf_counter()
    if sec.light_aware:                                                                     # eq 9
        sh_l1 = probe_sh_l1(ctx.inputs["light"])
        m, la = light_aware_fit(m, theta, dont_care, counts, S, g, sh_l1.reshape(P, 4, 3),
                                penalty=sec.light_aware_penalty, states=states)
    t_light = time.perf_counter() - t1
    ctx.report(0.6)

    t2 = time.perf_counter()
    if m is m5:                                     # fill_dont_care writes in place: the residual reads m5 first
        residual5.result()
    m, filled = fill_dont_care(m, dont_care)
    m = gaussian_filter(m, sec.sigma)                                                       # §3.4 step 6
    q = quantize(m)                                                                         # (Z, Y, X, K) bytes
    q = canonicalize(q, dont_care, counts, S, g, K, states)                                 # free values -> 0
    t_post = time.perf_counter() - t2
    residual_q = side.submit(mask_residual, theta, dont_care, counts, S, g, q, states)
    care = ~dont_care
    nonzero = (q[care] > 0).sum(axis=1) if care.any() else np.zeros(0)
    ctx.report(0.85)

    meta = {"samples_per_cell": S, "clusters": K}
    arts = [Artifact("masks_0123", rgba_group(q, 0), zstd_level=ZSTD_LEVEL, meta=meta,
                     description="mask m·255 of clusters 0-3 per refined-grid sample (MD eq 3, 5)")]
    if K > 4:
        arts.append(Artifact("masks_4567", rgba_group(q, 4), zstd_level=ZSTD_LEVEL, meta=meta,
                             description="mask m·255 of clusters 4-7 per refined-grid sample"))
    (r5, mass), (rq, _) = residual5.result(), residual_q.result()
    side.shutdown()
    stats = {
        "clusters": K, "samples_per_cell": S, "shape": list(q.shape[:3]),
        "residual_eq5": r5, "residual_stored": rq, "visible_mass": mass,
        "relative_residual_eq5": r5 / mass if mass > 0 else 0.0,
        "relative_residual_stored": rq / mass if mass > 0 else 0.0,
        "channels_per_sample": float(nonzero.mean()) if nonzero.size else 0.0,
        "multi_channel_fraction": float((nonzero >= 2).mean()) if nonzero.size else 0.0,
        "filled": int(filled), "light_aware": la,
        "fit_seconds": t_fit, "light_aware_seconds": t_light, "post_seconds": t_post,
    }
    ctx.report(1.0)
    return StageOutput(artifacts=arts, stats=stats)
