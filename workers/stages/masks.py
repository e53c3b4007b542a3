"""Stage ``masks``: per-sample masks and per-cluster probe volumes (MD §3.2-3.4 steps 4-6; DESIGN stage 4).

Reads ``place`` (grid stats), ``trace`` (``probe_states``), ``light`` (``sh_l1_{r,g,b}``),
``visibility`` (``theta_0123``, ``theta_4567``, ``dont_care``) and ``anneal`` (``clusters``); config
``masks`` (clusters, sigma, light_aware, light_aware_penalty). (``relocate`` is an input of the stage
for its cache key only.)

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
``cluster_sh_{k}_{r,g,b}`` for k < K : (nz, ny, nx, 4) RGBA16F, zstd — the L0 + L1 radiance SH of
    colour channel r/g/b (``sh_l1_*`` layout: L0, L1y, L1z, L1x) of the probes of cluster k; 0 for the
    other probes and for OFF probes.
``cluster_sh_l2_{k}`` for k < K, when the light stage's ``probe_sh`` is L2 (``light.sh_order`` 2, the default) :
    (7·(nz+2), ny, nx, 4) RGBA16F, zstd — the 9 radiance SH coefficients of cluster k's probes (0 elsewhere and for OFF
    probes) in the ``sh_l2`` layout (three.js LightProbeGrid, :func:`workers.kernels.sh.sh_l2_atlas`): what the mask
    modes shade with by default (the GLSL stacks the K of them in one texture).
``cluster_weights_0123`` (and ``_4567`` when K > 4) : (nz, ny, nx, 4) RGBA16F, zstd — channel k = g_i^k
    (1 for non-OFF probes of cluster k, else 0), so trilinear filtering gives w_k(x) = Σ_i φ_i g_i^k
    and normalized mask GI divides by Σ_k m_k w_k.
Half floats (issue 17: the mask GI payload ≤ 100 B per probe as stored): the weights are 0 / 1, exact; SH
coefficients round to 11 significant bits (relative error ≤ 2^-11 ≈ 0.05%; magnitudes beyond the half range,
65504, clamp and are counted in ``half_clamped``). Each cluster's volumes are 0 outside the cluster, which zstd
stores almost for free, so the K volumes cost about one SH per probe as stored.
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
from workers.kernels.mask_fit import (canonicalize, cluster_volumes, fill_dont_care, fit_masks, gaussian_filter,
                                      half_volume as _half, light_aware_fit, mask_residual, quantize)
from workers.kernels.sh import sh_l2_atlas
from workers.stages.base import Artifact, StageContext, StageOutput

ZSTD_LEVEL = 3
ZSTD_PROBES = 9    # the cluster probe volumes (zdm2: 1.58 MB at 9 in 0.16 s, 1.45 MB at 19 in 3.2 s)


def _rgba(channels: np.ndarray, start: int) -> np.ndarray:
    """Channels ``start … start + 3`` of (..., K) as (..., 4), zero-padded past K."""
    out = np.zeros(channels.shape[:-1] + (4,), channels.dtype)
    part = channels[..., start:start + 4]
    out[..., :part.shape[-1]] = part
    return np.ascontiguousarray(out)


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
    light = ctx.inputs["light"]
    sh_l1 = np.asarray(light["sh_l1_full"], np.float32) if "sh_l1_full" in light else \
        np.stack([light[f"sh_l1_{c}"] for c in "rgb"], axis=-1).astype(np.float32)       # (nz, ny, nx, 4, 3)

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

    vols, weights = cluster_volumes(sh_l1, g, K, states)
    clamped = [0]
    meta = {"samples_per_cell": S, "clusters": K}
    arts = [Artifact("masks_0123", _rgba(q, 0), zstd_level=ZSTD_LEVEL, meta=meta,
                     description="mask m·255 of clusters 0-3 per refined-grid sample (MD eq 3, 5)")]
    if K > 4:
        arts.append(Artifact("masks_4567", _rgba(q, 4), zstd_level=ZSTD_LEVEL, meta=meta,
                             description="mask m·255 of clusters 4-7 per refined-grid sample"))
    for k in range(K):
        for i, c in enumerate("rgb"):
            arts.append(Artifact(f"cluster_sh_{k}_{c}", _half(vols[k][..., i], clamped), zstd_level=ZSTD_PROBES,
                                 description=f"L0 + L1 radiance SH of the {c} channel of cluster {k}'s probes "
                                             f"(0 elsewhere)", meta={"cluster": k}))
    probe_sh = light["probe_sh"] if "probe_sh" in light else None
    if probe_sh is not None and np.shape(probe_sh)[3] == 9:                               # L2 bake
        vols2, _ = cluster_volumes(np.asarray(probe_sh, np.float32), g, K, states)
        for k in range(K):
            arts.append(Artifact(f"cluster_sh_l2_{k}", _half(sh_l2_atlas(vols2[k]), clamped), zstd_level=ZSTD_PROBES,
                                 meta={"cluster": k, "layout": "three.js LightProbeGrid", "texels": 7, "padding": 1},
                                 description=f"L2 radiance SH of cluster {k}'s probes (0 elsewhere), sh_l2 layout"))
    arts.append(Artifact("cluster_weights_0123", _half(_rgba(weights, 0), clamped), zstd_level=ZSTD_PROBES,
                         meta={"clusters": K},
                         description="g_i^k of clusters 0-3 per probe: trilinear gives w_k = Σ φ_i g_i^k"))
    if K > 4:
        arts.append(Artifact("cluster_weights_4567", _half(_rgba(weights, 4), clamped), zstd_level=ZSTD_PROBES,
                             meta={"clusters": K},
                             description="g_i^k of clusters 4-7 per probe"))
    (r5, mass), (rq, _) = residual5.result(), residual_q.result()
    side.shutdown()
    stats = {
        "clusters": K, "samples_per_cell": S, "shape": list(q.shape[:3]),
        "residual_eq5": r5, "residual_stored": rq, "visible_mass": mass,
        "relative_residual_eq5": r5 / mass if mass > 0 else 0.0,
        "relative_residual_stored": rq / mass if mass > 0 else 0.0,
        "channels_per_sample": float(nonzero.mean()) if nonzero.size else 0.0,
        "multi_channel_fraction": float((nonzero >= 2).mean()) if nonzero.size else 0.0,
        "filled": int(filled), "light_aware": la, "half_clamped": clamped[0],
        "fit_seconds": t_fit, "light_aware_seconds": t_light, "post_seconds": t_post,
    }
    ctx.report(1.0)
    return StageOutput(artifacts=arts, stats=stats)
