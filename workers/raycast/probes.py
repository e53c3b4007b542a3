"""Probe rays: a rotated direction pattern traced from every probe (DDGI-I §3.2, DDGI-P §5 and §6).

Stages ``relocate`` and ``trace`` cast their rays through :func:`trace_probes`; the relocation step
(:mod:`workers.kernels.relocation`), the classification (:mod:`workers.kernels.classification`) and the
depth moments (:mod:`workers.kernels.depth_moments`) read what it returns.

Back faces of double-sided triangles count as front faces (a thin double-sided plane has no inside);
the per-triangle flags come from :func:`workers.kernels.materials.double_sided_triangles`.
"""
from __future__ import annotations

import time

import numpy as np

from workers.kernels.sampling import probe_rays

__all__ = ["trace_probes", "PROBE_CHUNK_RAYS"]

PROBE_CHUNK_RAYS = 1 << 22
"""Rays per caster call of :func:`trace_probes` (whole probes): 4M rays hold about 100 MB of rays and hits, where
the 67M rays of a 64x32x64 grid at 256 rays in one call held 2.7 GB. Results do not depend on it."""


def trace_probes(caster, positions: np.ndarray, dirs, double_sided: np.ndarray):
    """Trace each probe's direction pattern.

    Parameters
    ----------
    caster : RayCaster
        :func:`workers.raycast.caster_for_scene` of the scene.
    positions : (P, 3) float
        Probe positions, world space, metres (cast as float32).
    dirs : (R, 3) float or :class:`workers.kernels.sampling.ProbeRays`
        Unit ray directions, world space (cast as float32): one pattern for every probe, or each probe's.
    double_sided : (T,) bool
        Per triangle: its back faces count as front faces.

    Returns
    -------
    ``t (P, R)`` float32 hit distances, metres (inf on a miss), ``tri (P, R)`` int32 (-1 on a miss),
    ``u, v (P, R)`` float32 barycentrics, ``backface (P, R)`` bool (hit the back of a single-sided
    triangle; False on a miss), and the seconds spent in the ray caster. Row p, column r is the ray
    ``positions[p] + t·dirs[r]`` (``rays.patterns[rays.pattern[p], r]``).
    """
    P = positions.shape[0]
    rays = probe_rays(dirs, P)
    R = rays.rays
    pos = positions.astype(np.float32)
    t, u, v = (np.empty((P, R), np.float32) for _ in range(3))
    tri = np.empty((P, R), np.int32)
    back = np.empty((P, R), bool)
    seconds = 0.0
    step = max(1, PROBE_CHUNK_RAYS // max(R, 1))        # probes per caster call: bounded temporaries
    for a in range(0, P, step):
        b = min(P, a + step)
        origins = np.repeat(pos[a:b], R, axis=0)
        t0 = time.perf_counter()
        hits = caster.intersect(origins, rays.of_probes(a, b).reshape(-1, 3))
        seconds += time.perf_counter() - t0
        t[a:b], tri[a:b] = hits.t.reshape(-1, R), hits.tri.reshape(-1, R)
        u[a:b], v[a:b], back[a:b] = hits.u.reshape(-1, R), hits.v.reshape(-1, R), hits.backface.reshape(-1, R)
    hit = tri >= 0
    back &= hit
    if double_sided.any():
        back &= ~double_sided[np.where(hit, tri, 0)]
    return (t, tri, u, v, back, seconds)
