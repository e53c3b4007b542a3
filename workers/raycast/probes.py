"""Probe rays: the same direction set traced from every probe (DDGI-I §3.2, DDGI-P §5 and §6).

Stages ``relocate`` and ``trace`` cast their rays through :func:`trace_probes`; the relocation step
(:mod:`workers.kernels.relocation`), the classification (:mod:`workers.kernels.classification`) and the
depth moments (:mod:`workers.kernels.depth_moments`) read what it returns.

Back faces of double-sided triangles count as front faces (a thin double-sided plane has no inside);
the per-triangle flags come from :func:`workers.kernels.materials.double_sided_triangles`.
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["trace_probes"]


def trace_probes(caster, positions: np.ndarray, dirs: np.ndarray, double_sided: np.ndarray):
    """Trace the same direction set from every probe.

    Parameters
    ----------
    caster : RayCaster
        :func:`workers.raycast.caster_for_scene` of the scene.
    positions : (P, 3) float
        Probe positions, world space, metres (cast as float32).
    dirs : (R, 3) float
        Unit ray directions, world space (cast as float32).
    double_sided : (T,) bool
        Per triangle: its back faces count as front faces.

    Returns
    -------
    ``t (P, R)`` float32 hit distances, metres (inf on a miss), ``tri (P, R)`` int32 (-1 on a miss),
    ``u, v (P, R)`` float32 barycentrics, ``backface (P, R)`` bool (hit the back of a single-sided
    triangle; False on a miss), and the seconds spent in the ray caster. Row p, column r is the ray
    ``positions[p] + t·dirs[r]``.
    """
    P, R = positions.shape[0], dirs.shape[0]
    origins = np.repeat(positions.astype(np.float32), R, axis=0)
    d = np.tile(dirs.astype(np.float32), (P, 1))
    t0 = time.perf_counter()
    hits = caster.intersect(origins, d)
    seconds = time.perf_counter() - t0
    tri = hits.tri.reshape(P, R)
    hit = tri >= 0
    back = hits.backface.reshape(P, R) & hit
    if double_sided.any():
        back &= ~double_sided[np.where(hit, tri, 0)]
    return (hits.t.reshape(P, R), tri, hits.u.reshape(P, R), hits.v.reshape(P, R), back, seconds)
