"""Counter-based random numbers and cosine-distributed directions for the path tracer (numba).

The uniform numbers of path p at vertex k are a hash (splitmix64, Steele et al. 2014) of
(seed, p, k, dimension), so an estimate depends only on the seed, the settings and the path's id — never on
chunking, thread count or the other paths. Dimensions used by :mod:`workers.kernels.pathtrace`: 0, 1 the
cosine direction, 2 Russian roulette; by :mod:`workers.kernels.emitters`: 3 the emitter, 4, 5 the point on it.

Cosine directions (pdf ``cos θ / π``): Malley's method, a uniform point on the unit disc lifted to the
hemisphere, in the orthonormal basis of Duff et al. 2017 about the normal. Consumers:
:mod:`workers.kernels.pathtrace`, :mod:`workers.kernels.emitters`. Inverse: none.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["uniforms", "cosine_directions"]


@numba.njit(cache=True, inline="always")
def _mix64(z):
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def _uniform(seed, path, vertex, dim):
    h = _mix64(seed * np.uint64(0x9E3779B97F4A7C15) + _mix64(path))
    h = _mix64(h + np.uint64(vertex) * np.uint64(16) + np.uint64(dim))
    return np.float64(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)  # [0, 1), 53 bits


@numba.njit(cache=True, nogil=True)
def _uniforms_kernel(seed, paths, vertex, dim, out):
    for i in range(paths.shape[0]):
        out[i] = _uniform(seed, paths[i], vertex, dim)


@numba.njit(cache=True, inline="always")
def _cosine_sample(nx, ny, nz, seed, path, vertex):
    """One cosine-distributed direction about the unit normal (nx, ny, nz): ``(dx, dy, dz, cos θ)``.

    Malley's method (a uniform point on the disc, r = √u1, φ = 2π u2, lifted to z = √(1 − u1)) in the
    orthonormal basis of Duff et al. 2017, "Building an Orthonormal Basis, Revisited" (t1, t2, n)."""
    s = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (s + nz)
    b = nx * ny * a
    u1 = _uniform(seed, path, vertex, 0)
    u2 = _uniform(seed, path, vertex, 1)
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    x = r * math.cos(phi)
    y = r * math.sin(phi)
    z = math.sqrt(max(0.0, 1.0 - u1))
    # x·t1 + y·t2 + z·n with t1 = (1 + s nx² a, s b, −s nx), t2 = (b, s + ny² a, −ny)
    return (x * (1.0 + s * nx * nx * a) + y * b + z * nx,
            x * (s * b) + y * (s + ny * ny * a) + z * ny,
            x * (-s * nx) + y * (-ny) + z * nz, z)


@numba.njit(cache=True, nogil=True)
def _cosine_kernel(normals, seed, paths, vertex, out):
    for i in range(paths.shape[0]):
        dx, dy, dz, _ = _cosine_sample(normals[i, 0], normals[i, 1], normals[i, 2], seed, paths[i], vertex)
        out[i, 0] = dx
        out[i, 1] = dy
        out[i, 2] = dz


def uniforms(seed: int, paths, vertex: int, dim: int) -> np.ndarray:
    """(N,) float64 uniforms in [0, 1) for path ids ``paths`` (uint64) at ``vertex`` and ``dim``."""
    p = np.ascontiguousarray(paths, np.uint64)
    out = np.empty(p.shape[0], np.float64)
    _uniforms_kernel(np.uint64(seed), p, int(vertex), int(dim), out)
    return out


def cosine_directions(normals, seed: int, paths, vertex: int) -> np.ndarray:
    """(N, 3) float64 unit directions, cosine-distributed about the unit ``normals`` (pdf cos θ / π).

    Deterministic per (seed, path id, vertex); uses dimensions 0 and 1 of :func:`uniforms`.
    """
    n = np.ascontiguousarray(normals, np.float64)
    p = np.ascontiguousarray(paths, np.uint64)
    if n.shape != (p.shape[0], 3):
        raise ValueError(f"cosine_directions: normals {n.shape} do not match {p.shape[0]} paths")
    out = np.empty((p.shape[0], 3), np.float64)
    _cosine_kernel(n, np.uint64(seed), p, int(vertex), out)
    return out

