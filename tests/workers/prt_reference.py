"""The light stage's computation for one PRT configuration: what a PRT transfer is fit to, for checking it.

A test helper (tests/workers/test_prt_stage.py, tests/render/test_artifacts.py, tests/bench/bench_prt.py): it
runs the bounce integrator one configuration at a time with the DDGI sampler itself
(:class:`workers.kernels.gather.SamplerGather`, reading what ``light.gather`` says), as the light stage does, where
the PRT stage solves batches (through the sampler's sparse matrix, :class:`workers.kernels.gather.MatrixGather`,
with ``light.gather = "octahedral"``).
"""
from __future__ import annotations

import numpy as np

from workers.kernels.bounce import integrate_one
from workers.kernels.ddgi import sample_irradiance
from workers.kernels.gather import SamplerGather
from workers.kernels.grid import OFF
from workers.kernels.sh import sh_project_probes
from workers.kernels.shading import direct_irradiance


def light_stage_reference(ds, lights: list[dict], light_section, lightmap: bool = True):
    """The light stage's own computation for ``lights`` alone (emission 0, sky 0), for checking a transfer.

    ds : the PRT stage's dataset (``PrtDataset``: its cached hits, probes and lightmap texels); light_section :
    ``BakeConfig.light`` (bounces, max_bounces, tolerance, sh_order). The hits are shaded as the dataset shades them
    (its ``probes["shading"]``, ``["horizon"]``, ``["near"]``: the light stage's bent normals, horizon factor and
    near-field occlusion). Returns ``(sh (P, K, 3) float32,
    texels (L, 3) float32 or None)``: the probes' radiance SH (OFF probes 0) and the DDGI irradiance
    (:func:`workers.kernels.ddgi.sample_irradiance`) of the converged probes at the lightmap texels.
    """
    pr = ds.probes
    surf = pr["surf"]
    e = direct_irradiance(surf.position, surf.normal, lights, pr["caster"], pr["eps"], **(pr.get("shading") or {}))
    gather = SamplerGather(surf.position, surf.normal, surf.view, pr["grid"], pr["positions"], pr["states"],
                           pr["depth"], pr["bias"], pr["visible"], read=light_section.gather)
    irr, radiance, _, _ = integrate_one(surf.index, surf.miss, surf.albedo, e, pr["dirs"], pr["states"], pr["n"],
                                        gather, bounces=light_section.bounces, max_bounces=light_section.max_bounces,
                                        tolerance=light_section.tolerance, indirect_scale=pr.get("horizon"),
                                        near=pr.get("near"))
    sh = sh_project_probes(pr["dirs"], radiance, order=light_section.sh_order).astype(np.float32)
    sh[pr["states"] == OFF] = 0.0
    tex = None
    if lightmap and ds.lightmap is not None:
        g = pr["grid"]
        lm = ds.lightmap
        tex = sample_irradiance(lm["position"], lm["normal"], lm["normal"], g["counts"], g["origin"], g["spacing"],
                                pr["positions"], pr["states"], irr, pr["depth"], pr["bias"], visible=lm["visible"])
    return sh, tex
