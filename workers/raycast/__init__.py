"""Ray casting against the scene's triangles: one interface, one backend (Embree).

Like trimesh's ``ray/`` package, the interface lives here and backends live in modules
(``embree.py``); stages use :class:`RayCaster` and :class:`Hits` and never import a backend.

A ray caster is built from world-space triangles ``(T, 3, 3) float32`` (metres, glTF frame,
counter-clockwise front faces) and answers, for N rays:

- ``intersect(origins, dirs, tnear=0, tfar=inf) -> Hits``: closest hit in [tnear, tfar];
- ``occluded(origins, dirs, tfar=inf, tnear=0) -> (N,) bool``: any hit in [tnear, tfar];
- ``inside_parity(points, n_dirs=3) -> (N,) bool``: whether points are inside closed geometry.

Results depend only on the rays, never on the thread count or chunking.

Stages get theirs from ``caster_for_scene(scene)``: the same interface, with alpha-tested cutouts
(glTF alphaMode MASK) transparent where their alpha is below the cutoff (:mod:`workers.raycast.cutout`),
built once per scene and process and shared by every stage (:mod:`workers.raycast.cache`).

Modules: ``embree.py`` (the backend), ``cutout.py`` (alpha cutouts over it), ``cache.py`` (one caster per
scene), ``probes.py`` (the probe rays of relocate and trace: :func:`workers.raycast.probes.trace_probes`).

Consumers: stages (place, relocate, trace, visibility, light, prt, reference, evaluate).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Hits", "RayCaster", "EmbreeRayCaster", "CutoutRayCaster", "caster_for_scene"]


@dataclass(frozen=True)
class Hits:
    """Closest hits of N rays.

    Attributes
    ----------
    t : (N,) float32
        Ray parameter of the hit, ``hit = origin + t * dir``: distance in metres for unit
        ``dir``. ``inf`` on a miss.
    tri : (N,) int32
        Index of the hit triangle in the caster's ``triangles``; -1 on a miss.
    u, v : (N,) float32
        Barycentrics of the hit: ``hit = (1 - u - v) * v0 + u * v1 + v * v2`` for the
        triangle's vertices v0, v1, v2. 0 on a miss.
    backface : (N,) bool
        True when the ray hit the back side: ``dot(dir, n_geom) > 0`` with the geometric
        normal ``n_geom = (v1 - v0) × (v2 - v0)`` (counter-clockwise front faces, glTF).
        False on a miss.
    """

    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray
    backface: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: True where the ray hit a triangle."""
        return self.tri >= 0

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def points(self, origins, dirs) -> np.ndarray:
        """(N, 3) float32 hit positions ``origins + t * dirs`` (world space); NaN on a miss."""
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(dirs, dtype=np.float64)
        t = np.where(self.hit, self.t, np.nan).astype(np.float64)
        return (o + t[:, None] * d).astype(np.float32)


from .embree import EmbreeRayCaster  # noqa: E402  (the backend needs Hits defined above)

RayCaster = EmbreeRayCaster
"""The default backend: :class:`workers.raycast.embree.EmbreeRayCaster`."""

from .cutout import CutoutRayCaster  # noqa: E402  (alpha-tested cutouts over the backend)
from .cache import caster_for_scene  # noqa: E402  (one caster per scene and process)
