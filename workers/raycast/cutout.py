"""Rays through alpha cutouts: alphaMode MASK (and BLEND, baked as a cutout) for every ray a bake casts.

glTF 3.9.6: a MASK material is "rendered fully opaque if alpha >= alphaCutoff, else fully transparent".
A ray must therefore pass through a cutout triangle where the alpha at the hit is below the cutoff —
foliage, fences, grilles. Embree's filter callbacks are not reachable through embreex, so the caster
re-casts instead:

- :meth:`CutoutRayCaster.intersect`: closest hit on all triangles; hits on a cutout triangle whose alpha
  test fails are continued from just past the hit (``t + step``), layer after layer (at most
  :data:`MAX_LAYERS`; a ray still in a hole after that keeps its last hit: a stack of more than 64
  transparent layers along one ray is treated as opaque);
- :meth:`CutoutRayCaster.occluded`: an occlusion query on the opaque triangles only (one Embree call), then
  the rays it did not stop walk the cutout triangles' own BVH the same way.

The alpha test itself is the caller's (``opaque(tri, u, v) -> (H,) bool``,
:func:`workers.kernels.materials.opaque_at_hits`), so this module holds no material logic. Results do not
depend on threads or chunking, as for :class:`workers.raycast.embree.EmbreeRayCaster`.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from . import Hits
from .embree import EmbreeRayCaster

MAX_LAYERS = 64
"""Cutout layers one ray may pass through before the last one counts as opaque."""

STEP = 1e-6
"""Continuation step past a transparent hit, as a fraction of the caster's ``scale`` (plus 1e-6 relative)."""


class CutoutRayCaster:
    """A ray caster whose cutout triangles are transparent where their alpha test fails.

    Parameters
    ----------
    triangles : (T, 3, 3) float
        World-space triangles (metres), as :class:`EmbreeRayCaster`.
    cutout : (T,) bool
        Which triangles carry an alpha-tested material.
    opaque : callable ``(tri (H,) int64, u (H,), v (H,)) -> (H,) bool``
        Alpha test at hits on cutout triangles (triangle indices into ``triangles``).
    **kwargs
        Passed to each :class:`EmbreeRayCaster` (threads, chunk_size, robust).
    """

    def __init__(self, triangles, cutout, opaque: Callable, **kwargs):
        tri = np.ascontiguousarray(triangles, dtype=np.float32)
        cut = np.asarray(cutout, bool).reshape(-1)
        if cut.shape[0] != tri.shape[0]:
            raise ValueError(f"CutoutRayCaster: cutout has {cut.shape[0]} entries for {tri.shape[0]} triangles")
        self._all = EmbreeRayCaster(tri, **kwargs)
        self._solid = EmbreeRayCaster(tri[~cut], **kwargs)
        self._cut_index = np.flatnonzero(cut).astype(np.int64)
        self._cuts = EmbreeRayCaster(tri[cut], **kwargs)
        self._cutout = cut
        self._opaque = opaque
        self.triangles = self._all.triangles
        self.scale = self._all.scale
        self.diagonal = self._all.diagonal
        self.quantum = self._all.quantum
        self.threads = self._all.threads

    def __repr__(self) -> str:
        return f"CutoutRayCaster(triangles={self.triangles.shape[0]}, cutout={self._cut_index.size})"

    def _step(self, t: np.ndarray) -> np.ndarray:
        return t.astype(np.float64) * (1.0 + 1e-6) + STEP * self.scale

    def intersect(self, origins, dirs, tnear=0.0, tfar=np.inf) -> Hits:
        """Closest hit in [tnear, tfar] that passes the alpha test (see the module doc)."""
        h = self._all.intersect(origins, dirs, tnear, tfar)
        t, tri, u, v, back = (np.array(a) for a in (h.t, h.tri, h.u, h.v, h.backface))
        n = t.shape[0]
        o = np.asarray(origins, np.float64).reshape(n, 3)
        d = np.asarray(dirs, np.float64).reshape(n, 3)
        tf = np.broadcast_to(np.asarray(tfar, np.float64), (n,))
        live = np.flatnonzero(tri >= 0)
        for _ in range(MAX_LAYERS):
            live = live[self._cutout[tri[live]]]
            if live.size == 0:
                break
            keep = self._opaque(tri[live].astype(np.int64), u[live], v[live])
            live = live[~keep]                         # rays that fell through a hole
            if live.size == 0:
                break
            tn = self._step(t[live])
            ok = tn <= tf[live]
            gone = live[~ok]
            t[gone], tri[gone], u[gone], v[gone], back[gone] = np.inf, -1, 0.0, 0.0, False
            live = live[ok]
            if live.size == 0:
                break
            nh = self._all.intersect(o[live], d[live], tn[ok], tf[live])
            t[live], tri[live], u[live], v[live], back[live] = nh.t, nh.tri, nh.u, nh.v, nh.backface
            live = live[nh.tri >= 0]
        return Hits(t=t, tri=tri, u=u, v=v, backface=back)

    def occluded(self, origins, dirs, tfar=np.inf, tnear=0.0) -> np.ndarray:
        """Whether an opaque triangle, or a cutout where its alpha test passes, lies in [tnear, tfar]."""
        occ = self._solid.occluded(origins, dirs, tfar=tfar, tnear=tnear)
        if self._cut_index.size == 0:
            return occ
        n = occ.shape[0]
        rest = np.flatnonzero(~occ)
        if rest.size == 0:
            return occ
        o = np.asarray(origins, np.float64).reshape(n, 3)[rest]
        d = np.asarray(dirs, np.float64).reshape(n, 3)[rest]
        tn = np.broadcast_to(np.asarray(tnear, np.float64), (n,))[rest].copy()
        tf = np.broadcast_to(np.asarray(tfar, np.float64), (n,))[rest]
        idx = np.arange(rest.size)
        for _ in range(MAX_LAYERS):
            h = self._cuts.intersect(o[idx], d[idx], tn[idx], tf[idx])
            hit = h.tri >= 0
            idx, t_hit = idx[hit], h.t[hit]
            if idx.size == 0:
                break
            solid = self._opaque(self._cut_index[h.tri[hit]], h.u[hit], h.v[hit])
            occ[rest[idx[solid]]] = True
            idx, t_hit = idx[~solid], t_hit[~solid]
            tn[idx] = self._step(t_hit)
            ok = tn[idx] <= tf[idx]
            idx = idx[ok]
            if idx.size == 0:
                break
        else:
            occ[rest[idx]] = True                      # more layers than MAX_LAYERS: opaque
        return occ

    def inside_parity(self, points, n_dirs: int = 3, rule: str = "parity") -> np.ndarray:
        """As :meth:`EmbreeRayCaster.inside_parity`, on every triangle (cutouts are thin surfaces)."""
        return self._all.inside_parity(points, n_dirs=n_dirs, rule=rule)


def build_caster(scene, **kwargs):
    """A new ray caster of a :class:`workers.scene.NormalizedScene`: a plain :class:`EmbreeRayCaster` when no
    material is a cutout, else a :class:`CutoutRayCaster` testing alpha with
    :func:`workers.kernels.materials.opaque_at_hits`. Stages use the cached
    :func:`workers.raycast.caster_for_scene` instead."""
    from workers.kernels.materials import cutout_materials, material_table, opaque_at_hits

    cut_mat = cutout_materials(scene)
    mat = np.asarray(scene.material)
    if not cut_mat.any() or not cut_mat[mat].any():
        return EmbreeRayCaster(scene.triangles, **kwargs)
    table = material_table(scene.materials)
    return CutoutRayCaster(scene.triangles, cut_mat[mat],
                           lambda t, u, v: opaque_at_hits(scene, t, u, v, table=table), **kwargs)
