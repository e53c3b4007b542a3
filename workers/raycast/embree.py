"""Embree backend of :mod:`workers.raycast` (through embreex 4.x).

Notes on embreex 4.4 (``embreex.rtcore_scene.EmbreeScene.run``) that shape this module:

- ``run(origins, dirs, dists=None, query='INTERSECT'|'OCCLUDED'|'DISTANCE', output=None)``
  loops over the rays one by one in C (``rtcIntersect1`` / ``rtcOccluded1``) and releases the
  GIL, so Python threads over chunks of rays scale with cores.
- ``tnear`` is always 0: a positive ``tnear`` is emulated by moving the origin to
  ``origin + tnear * dir`` (in float64, then rounded to float32) and adding ``tnear`` back to t.
- ``dists`` given as an array is used as the tfar buffer and overwritten in place with the hit
  distances: always pass a copy.
- A miss leaves tfar at its input (1e37 by default) with primID = -1; we report ``inf``.
- ``OCCLUDED`` returns int32 0 for an occluded ray and -1 for a free one.
- The BVH is built lazily by the first ``run``; two threads doing that first call at once would
  commit the scene concurrently, so the constructor runs one ray to commit it up front.
- ``EmbreeScene(robust=True)`` sets ``RTC_SCENE_FLAG_ROBUST`` ("avoid optimizations that
  reduce arithmetic accuracy", Embree docs); we use it by default because the inside test
  counts crossings and rays must not slip through shared edges. It costs about 15%.

Measured on zdm2-sauerbraten (58,772 triangles, 1 ray/origin uniform in the bounds, uniform
directions, 78% hit; 2-core machine, robust scene): intersect 5.1 Mrays/s with 1 thread and
9.2 Mrays/s with 2; occluded 9.4 and 16.2 Mrays/s. embreex's own loop alone gives 5.8 Mrays/s:
the rest is this wrapper's validation and output assembly.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from workers.kernels.sampling import rotated_directions

from . import Hits

__all__ = ["EmbreeRayCaster"]

DEFAULT_THREADS = 2  # Python threads over chunks of rays (embreex releases the GIL)
DEFAULT_CHUNK_RAYS = 1 << 16  # rays per embreex call; bounds temporary memory per thread
PARITY_MAX_CROSSINGS = 256  # inside_parity gives up counting after this many surfaces per ray
PARITY_STEP = 1e-5  # step past a hit before searching for the next, x scene scale (dimensionless)


def _quaternion_matrix(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# A fixed generic rotation of the inside-test directions, so that none is parallel to the
# axis-aligned walls and edges common in level geometry (quaternion w, x, y, z; arbitrary).
_PARITY_ROTATION = _quaternion_matrix([0.8528, 0.2312, -0.3951, 0.2514])


def _import_embreex():
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "workers.raycast needs the 'embreex' package (Embree 4 bindings): pip install embreex"
        ) from exc
    return rtcore_scene, TriangleMesh


@njit(cache=True, nogil=True)
def _any_nan_or_negative(a):
    for i in range(a.shape[0]):
        if not a[i] >= 0.0:   # NaN too
            return True
    return False


@njit(cache=True, nogil=True)
def _bad_rays(o, d):
    """0 when every ray is usable; 1: a non-finite origin or direction; 2: a zero direction."""
    zero = False
    for i in range(o.shape[0]):
        for a in range(3):
            if not (math.isfinite(o[i, a]) and math.isfinite(d[i, a])):
                return 1
        if d[i, 0] * d[i, 0] + d[i, 1] * d[i, 1] + d[i, 2] * d[i, 2] == 0.0:
            zero = True
    return 2 if zero else 0


@njit(cache=True, nogil=True)
def _store_hits(prim, tfar, u, v, ng, d, tri_out, t_out, u_out, v_out, back_out):
    """embreex's per-ray results into Hits arrays; misses: tri -1, t inf, u = v = 0, not back.

    Embree's Ng = (v1 - v0) x (v2 - v0), unnormalized: the back side is hit when dir . Ng > 0.
    """
    for i in range(prim.shape[0]):
        if prim[i] >= 0:
            tri_out[i] = prim[i]
            t_out[i] = tfar[i]
            u_out[i] = u[i]
            v_out[i] = v[i]
            back_out[i] = d[i, 0] * ng[i, 0] + d[i, 1] * ng[i, 1] + d[i, 2] * ng[i, 2] > 0
        else:
            tri_out[i] = -1
            t_out[i] = np.inf
            u_out[i] = 0.0
            v_out[i] = 0.0
            back_out[i] = False


def _per_ray(x, n: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {a.shape}")
    return a


class EmbreeRayCaster:
    """Closest-hit and occlusion queries on a static triangle soup with Embree.

    Parameters
    ----------
    triangles : (T, 3, 3) array_like of float
        World-space vertex positions (metres), triangle-major: ``triangles[i, j]`` is vertex j
        of triangle i. Stored as float32. Winding defines the front face (counter-clockwise,
        glTF). T = 0 is allowed (every ray misses).
    threads : int
        Python threads, each running embreex on its own chunks of rays. Results do not
        depend on it.
    chunk_size : int
        Rays per embreex call. Results do not depend on it.
    robust : bool
        Embree's ``RTC_SCENE_FLAG_ROBUST`` (full arithmetic accuracy in traversal); costs
        about 15% of throughput on zdm2.

    Attributes
    ----------
    triangles : (T, 3, 3) float32
    scale : float
        max(bounding-box diagonal, largest absolute coordinate), metres; sets the step
        of :meth:`inside_parity`.
    diagonal : float
        The bounding box's diagonal, metres: the scene's size, whatever its distance from the
        origin (offsets meant to scale with the scene use it; 1.0 without triangles).
    quantum : float
        float32 spacing at the largest absolute coordinate, metres: how finely the stored
        triangles (and float32 ray origins) can place a point anywhere in the scene.
    """

    def __init__(self, triangles, *, threads: int = DEFAULT_THREADS, chunk_size: int = DEFAULT_CHUNK_RAYS,
                 robust: bool = True):
        tri = np.ascontiguousarray(triangles, dtype=np.float32)
        if tri.ndim != 3 or tri.shape[1:] != (3, 3):
            raise ValueError(f"EmbreeRayCaster: triangles must have shape (T, 3, 3), got {tri.shape}")
        if not np.all(np.isfinite(tri)):
            raise ValueError("EmbreeRayCaster: triangles must be finite")
        self.threads = self._check_positive(threads, "threads")
        self.chunk_size = self._check_positive(chunk_size, "chunk_size")
        self.triangles = tri
        if tri.shape[0]:
            lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
            reach = np.maximum(-lo, hi).max()           # the largest absolute coordinate (float32)
            self.diagonal = float(max(np.linalg.norm(hi.astype(np.float64) - lo), 1e-30))
            self.scale = float(max(self.diagonal, reach))
            self.quantum = float(np.spacing(reach))
        else:
            self.scale = self.diagonal = 1.0
            self.quantum = float(np.spacing(np.float32(1.0)))
        self._scene = None
        self._pool: ThreadPoolExecutor | None = None
        if tri.shape[0]:
            rtcore_scene, TriangleMesh = _import_embreex()
            self._scene = rtcore_scene.EmbreeScene(robust=bool(robust))
            self._mesh = TriangleMesh(self._scene, tri)  # flat build: primID == triangle index
            # Commit (build the BVH) now, single-threaded: run() commits lazily and is not
            # safe to do so from two threads at once.
            self._scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32),
                            dists=np.ones(1, np.float32), query="OCCLUDED")

    @staticmethod
    def _check_positive(x, name: str) -> int:
        if int(x) != x or int(x) < 1:
            raise ValueError(f"EmbreeRayCaster: {name} must be a positive integer, got {x!r}")
        return int(x)

    def __repr__(self) -> str:
        return f"EmbreeRayCaster(triangles={self.triangles.shape[0]}, threads={self.threads})"

    # ------------------------------------------------------------------ validation
    def _rays(self, origins, dirs, tnear, tfar):
        """Validated float32 rays with the interval moved to [0, tfar - tnear] (embreex has tnear = 0)."""
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(dirs, dtype=np.float32)
        if o.ndim != 2 or o.shape[1] != 3:
            raise ValueError(f"origins must have shape (N, 3), got {o.shape}")
        if d.shape != o.shape:
            raise ValueError(f"dirs must have the shape of origins {o.shape}, got {d.shape}")
        n = o.shape[0]
        if np.ndim(tnear) == 0 and np.ndim(tfar) == 0:  # one interval for all rays: no per-ray float64 arrays
            tn, tf = np.float64(tnear), np.float64(tfar)
            if not np.isfinite(tn) or tn < 0:
                raise ValueError("tnear must be finite and >= 0")
            if np.isnan(tf) or tf < tn:
                raise ValueError("tfar must be >= tnear (inf allowed)")
            if tn > 0:
                o = np.ascontiguousarray(np.asarray(origins, np.float64) + tn * np.asarray(dirs, np.float64),
                                         dtype=np.float32)
            return o, d, tn, np.full(n, tf - tn, np.float32)
        if np.ndim(tnear) == 0 and float(tnear) == 0.0:   # per-ray tfar from 0: no float64 round trip
            tf = np.asarray(tfar)
            if tf.shape != (n,):
                raise ValueError(f"tfar must be a scalar or have shape ({n},), got {tf.shape}")
            tf = np.ascontiguousarray(tf, np.float32)   # (tf - 0) rounded once, as below
            if _any_nan_or_negative(tf):
                raise ValueError("tfar must be >= tnear (inf allowed)")
            return o, d, np.float64(0.0), tf
        tn = _per_ray(tnear, n, "tnear")
        tf = _per_ray(tfar, n, "tfar")
        # finite / non-zero checks of origins and dirs run per chunk in the worker threads (_check_chunk)
        if not np.isfinite(tn).all() or (tn < 0).any():
            raise ValueError("tnear must be finite and >= 0")
        if np.isnan(tf).any() or (tf < tn).any():
            raise ValueError("tfar must be >= tnear (inf allowed)")
        if (tn > 0).any():  # start the ray at tnear instead (in float64, rounded once)
            o = np.ascontiguousarray(np.asarray(origins, np.float64) + tn[:, None] * np.asarray(dirs, np.float64),
                                     dtype=np.float32)
        return o, d, tn, (tf - tn).astype(np.float32)

    @staticmethod
    def _check_chunk(o: np.ndarray, d: np.ndarray) -> None:
        """Validate one chunk of rays (in the worker thread: numpy releases the GIL on big arrays)."""
        bad = _bad_rays(o, d)   # one pass, without the GIL
        if bad == 1:
            raise ValueError("origins and dirs must be finite")
        if bad == 2:
            raise ValueError("dirs must be non-zero")

    def _map_chunks(self, fn, n: int):
        bounds = [(s, min(n, s + self.chunk_size)) for s in range(0, n, self.chunk_size)]
        if self.threads == 1 or len(bounds) <= 1:
            for b in bounds:
                fn(*b)
            return
        if self._pool is None:   # kept for the caster's life: starting threads per query cost 3 ms a call
            self._pool = ThreadPoolExecutor(max_workers=self.threads, thread_name_prefix="kiln-embree")
        for f in [self._pool.submit(fn, *b) for b in bounds]:
            f.result()  # re-raise errors from workers

    # ------------------------------------------------------------------ queries
    def intersect(self, origins, dirs, tnear=0.0, tfar=np.inf) -> Hits:
        """Closest hit of each ray with t in [tnear, tfar], both sides of every triangle.

        Parameters
        ----------
        origins : (N, 3) array_like of float
            Ray origins, world space, metres.
        dirs : (N, 3) array_like of float
            Ray directions, non-zero; t is measured in units of ``|dir|`` (metres for unit
            vectors). Not normalized here.
        tnear, tfar : float or (N,) array_like
            Ray interval, ``0 <= tnear <= tfar``; tfar may be inf.

        Returns
        -------
        Hits
            See :class:`workers.raycast.Hits`; ``t`` is measured from ``origins``.
        """
        o, d, tn, tf = self._rays(origins, dirs, tnear, tfar)
        n = o.shape[0]
        t = np.full(n, np.inf, dtype=np.float32)
        tri = np.full(n, -1, dtype=np.int32)
        u = np.zeros(n, dtype=np.float32)
        v = np.zeros(n, dtype=np.float32)
        back = np.zeros(n, dtype=bool)
        if self._scene is None or n == 0:
            return Hits(t=t, tri=tri, u=u, v=v, backface=back)

        def work(s: int, e: int) -> None:
            self._check_chunk(o[s:e], d[s:e])
            res = self._scene.run(o[s:e], d[s:e], dists=tf[s:e].copy(), output=1)  # run overwrites dists
            _store_hits(res["primID"], res["tfar"], res["u"], res["v"], res["Ng"], d[s:e],
                        tri[s:e], t[s:e], u[s:e], v[s:e], back[s:e])

        self._map_chunks(work, n)
        if np.any(tn > 0):
            t += tn.astype(np.float32)  # back to the caller's origin (inf stays inf)
        return Hits(t=t, tri=tri, u=u, v=v, backface=back)

    def occluded(self, origins, dirs, tfar=np.inf, tnear=0.0) -> np.ndarray:
        """Whether anything is hit with t in [tnear, tfar] (shadow / visibility rays).

        Parameters as :meth:`intersect`. Agrees with ``intersect(...).t <= tfar`` except for
        hits within float rounding of tfar.

        Returns
        -------
        occluded : (N,) bool
        """
        o, d, tn, tf = self._rays(origins, dirs, tnear, tfar)
        n = o.shape[0]
        out = np.zeros(n, dtype=bool)
        if self._scene is None or n == 0:
            return out

        def work(s: int, e: int) -> None:
            self._check_chunk(o[s:e], d[s:e])
            res = self._scene.run(o[s:e], d[s:e], dists=tf[s:e].copy(), query="OCCLUDED")
            out[s:e] = res == 0  # embreex 4.4: 0 = occluded, -1 = free

        self._map_chunks(work, n)
        return out

    def inside_parity(self, points, n_dirs: int = 3, rule: str = "parity") -> np.ndarray:
        """Whether points lie inside closed geometry, by a majority vote over fixed directions.

        From each point, one ray is cast along each of ``n_dirs`` fixed directions (a
        spherical Fibonacci set under a fixed generic rotation, so no direction is parallel to
        axis-aligned walls). Each ray votes "inside" by the rule:

        - ``"parity"`` (default): the ray crosses the surface an odd number of times (Jordan
          curve test; independent of winding). Crossings are counted by re-casting from just
          past each hit (step ``1e-5 * scale``), up to 256 per ray.
        - ``"backface"``: the first surface the ray hits is seen from its back side (needs
          consistently outward-facing, counter-clockwise geometry; one cast per ray; this is
          the per-ray test DDGI's backface fraction is built from, DDGI-P §4.1, §6.1).

        A point is inside when more than half of the rays vote inside (use an odd
        ``n_dirs``). Points on a surface, open meshes and coplanar duplicate triangles give
        undefined votes; the majority absorbs a wrong vote from a ray grazing an edge.

        Parameters
        ----------
        points : (N, 3) array_like of float
            World space, metres.
        n_dirs : int
            Rays per point, >= 1.
        rule : {"parity", "backface"}

        Returns
        -------
        inside : (N,) bool
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"inside_parity: points must have shape (N, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("inside_parity: points must be finite")
        if int(n_dirs) != n_dirs or n_dirs < 1:
            raise ValueError(f"inside_parity: n_dirs must be a positive integer, got {n_dirs!r}")
        if rule not in ("parity", "backface"):
            raise ValueError(f"inside_parity: rule must be 'parity' or 'backface', got {rule!r}")
        n, k = p.shape[0], int(n_dirs)
        if self._scene is None or n == 0:
            return np.zeros(n, dtype=bool)
        dirs = rotated_directions(k, _PARITY_ROTATION)
        o = np.repeat(p, k, axis=0)  # ray i*k + j: point i, direction j
        d = np.tile(dirs.astype(np.float64), (n, 1))
        if rule == "backface":
            votes = self.intersect(o, d).backface
        else:
            votes = self._odd_crossings(o, d)
        return votes.reshape(n, k).sum(axis=1) * 2 > k

    def _odd_crossings(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        step = PARITY_STEP * self.scale
        count = np.zeros(o.shape[0], dtype=np.int64)
        active = np.arange(o.shape[0])
        tnear = np.zeros(o.shape[0])
        for _ in range(PARITY_MAX_CROSSINGS):
            if active.size == 0:
                break
            h = self.intersect(o[active], d[active], tnear=tnear[active])
            hit = h.hit
            active = active[hit]
            count[active] += 1
            tnear[active] = h.t[hit].astype(np.float64) + step  # continue just past this surface
        return (count % 2) == 1
