"""Stage ``clusters``: each cluster's probe volumes, what the mask modes shade with (MD §3.4; DESIGN stage 4).

Reads ``trace`` (``probe_states``), ``light`` (``sh_l1_full``, ``probe_sh``) and ``anneal`` (``clusters``, the colouring
g, and its K); no config of its own. Split from ``masks`` so that the masks,
which do not depend on the light, and their compression run beside the light stage; this stage is the only part of
the mask decomposition that waits for the light, and it is small (zdm2-sauerbraten: 20,387 probes, K = 4, 0.03-0.13 s).

Outputs (half floats, zstd 9)
-----------------------------
``cluster_sh_{k}_{r,g,b}`` for k < K : (nz, ny, nx, 4) RGBA16F — the L0 + L1 radiance SH of colour channel r/g/b
    (``sh_l1_*`` layout: L0, L1y, L1z, L1x) of the probes of cluster k; 0 for the other probes and for OFF probes.
``cluster_sh_l2_{k}`` for k < K, when the light stage's ``probe_sh`` is L2 (``light.sh_order`` 2, the default) :
    (7·(nz+2), ny, nx, 4) RGBA16F — the 9 radiance SH coefficients of cluster k's probes (0 elsewhere and for OFF
    probes) in the ``sh_l2`` layout (three.js LightProbeGrid, :func:`workers.kernels.sh.sh_l2_atlas`): what the mask
    modes shade with by default (the GLSL stacks the K of them in one texture).
``cluster_weights_0123`` (and ``_4567`` when K > 4) : (nz, ny, nx, 4) RGBA16F — channel k = g_i^k (1 for non-OFF
    probes of cluster k, else 0), so trilinear filtering gives w_k(x) = Σ_i φ_i g_i^k and normalized mask GI divides
    by Σ_k m_k w_k.
Half floats (issue 17: the mask GI payload ≤ 100 B per probe as stored): the weights are 0 / 1, exact; SH
coefficients round to 11 significant bits (relative error ≤ 2^-11 ≈ 0.05%; magnitudes beyond the half range,
65504, clamp and are counted in ``half_clamped``). Each cluster's volumes are 0 outside the cluster, which zstd
stores almost for free, so the K volumes cost about one SH per probe as stored.
stats : ``clusters`` (K), ``half_clamped``.
"""
from __future__ import annotations

import numpy as np

from workers.kernels.mask_fit import cluster_volumes, half_volume as _half, rgba_group
from workers.kernels.sh import sh_l2_atlas
from workers.stages.base import Artifact, StageContext, StageOutput, probe_sh_l1

ZSTD_PROBES = 9    # the cluster probe volumes (zdm2: 1.58 MB at 9 in 0.16 s, 1.45 MB at 19 in 3.2 s)


def run_clusters(ctx: StageContext) -> StageOutput:
    K = int(ctx.inputs["anneal"].stats["clusters"])                 # the colouring's K (its key holds masks.clusters)
    states = ctx.inputs["trace"]["probe_states"].reshape(-1)
    g = ctx.inputs["anneal"]["clusters"].reshape(-1).astype(np.int64)
    light = ctx.inputs["light"]
    vols, weights = cluster_volumes(probe_sh_l1(light), g, K, states)
    clamped = [0]
    arts = []
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
    arts.append(Artifact("cluster_weights_0123", _half(rgba_group(weights, 0), clamped), zstd_level=ZSTD_PROBES,
                         meta={"clusters": K},
                         description="g_i^k of clusters 0-3 per probe: trilinear gives w_k = Σ φ_i g_i^k"))
    if K > 4:
        arts.append(Artifact("cluster_weights_4567", _half(rgba_group(weights, 4), clamped), zstd_level=ZSTD_PROBES,
                             meta={"clusters": K},
                             description="g_i^k of clusters 4-7 per probe"))
    return StageOutput(artifacts=arts, stats={"clusters": K, "half_clamped": clamped[0]})
