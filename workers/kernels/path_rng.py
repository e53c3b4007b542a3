"""Counter-based random numbers and cosine-distributed directions for the path tracer (numba).

The uniform numbers of path p at vertex k are a hash (splitmix64, Steele et al. 2014) of
(seed, p, k, dimension), so an estimate depends only on the seed, the settings and the path's id — never on
chunking, thread count or the other paths. Dimensions used by :mod:`workers.kernels.pathtrace`: 0, 1 the
cosine direction, 2 Russian roulette; by :mod:`workers.kernels.emitters`: 3 the emitter, 4, 5 the point on it; by
:mod:`workers.kernels.light_spots`: 15 (path = virtual light, vertex = probe). A vertex has 16 dimensions.

Stratified first directions (:func:`stratified_uniforms`, :func:`first_cosine_directions`): a point's ``spp``
paths form G independent sets (path j in set ``j mod G``); set g's i-th path takes the i-th point of the Sobol
(0, 2)-sequence (van der Corput and Sobol's second dimension), Owen-scrambled (nested uniform scrambling, Owen
1995; each bit flipped by a hash of the bits above it, the key of (seed, point, g, pair, dimension): Burley 2020,
"Practical Hash-based Owen Scrambling") plus a uniform below 2⁻³². So each path's pair is uniform on [0, 1)² (the
estimate stays unbiased), the sets are independent (their means give an unbiased standard error), and within a
set the pairs form a (0, m, 2)-net — one point in every elementary box of area 2⁻ᵐ — for 2ᵐ paths, a union of
such nets otherwise. Further pairs (the emitter sample at the shading point: pair 1 the point on the triangle,
pair 2's first coordinate the pick) are padded (Kollig & Keller 2002): the same kind of net, scrambled with
their own keys, its indices shuffled by a hash-keyed permutation (:func:`_shuffle`), so each pair is
stratified and the pairs independent.

Cosine directions (pdf ``cos θ / π``): Malley's method, a uniform point on the unit disc lifted to the
hemisphere, in the orthonormal basis of Duff et al. 2017 about the normal. Consumers:
:mod:`workers.kernels.pathtrace`, :mod:`workers.kernels.emitters`. Inverse: none.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["uniforms", "cosine_directions", "stratified_uniforms", "first_cosine_directions"]


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
def _cosine_dir(nx, ny, nz, u1, u2):
    """The cosine-distributed direction of the uniforms (u1, u2) about the unit normal (nx, ny, nz):
    ``(dx, dy, dz, cos θ)``.

    Malley's method (a uniform point on the disc, r = √u1, φ = 2π u2, lifted to z = √(1 − u1)) in the
    orthonormal basis of Duff et al. 2017, "Building an Orthonormal Basis, Revisited" (t1, t2, n)."""
    s = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (s + nz)
    b = nx * ny * a
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    x = r * math.cos(phi)
    y = r * math.sin(phi)
    z = math.sqrt(max(0.0, 1.0 - u1))
    # x·t1 + y·t2 + z·n with t1 = (1 + s nx² a, s b, −s nx), t2 = (b, s + ny² a, −ny)
    return (x * (1.0 + s * nx * nx * a) + y * b + z * nx,
            x * (s * b) + y * (s + ny * ny * a) + z * ny,
            x * (-s * nx) + y * (-ny) + z * nz, z)


@numba.njit(cache=True, inline="always")
def _cosine_sample(nx, ny, nz, seed, path, vertex):
    """One cosine-distributed direction (:func:`_cosine_dir`) from dimensions 0, 1 of path ``path`` at ``vertex``."""
    return _cosine_dir(nx, ny, nz, _uniform(seed, path, vertex, 0), _uniform(seed, path, vertex, 1))


# ------------------------------------------------------------------ stratified first directions
@numba.njit(cache=True, inline="always")
def _owen_scramble(x, key):
    """Nested uniform (Owen 1995) scramble of the 32-bit fraction ``x`` (uint64 < 2³²): bit b (from the top) is
    flipped by a hash of ``key`` and the node of the binary tree the bits above it reach (heap index
    ``2^b | prefix``), so every point of a scrambled net is uniform on [0, 1) and the net stays a net."""
    out = np.uint64(0)
    for b in range(32):
        shift = np.uint64(31 - b)
        node = (x >> (shift + np.uint64(1))) | (np.uint64(1) << np.uint64(b))
        flip = _mix64(key ^ _mix64(node * np.uint64(0xD1B54A32D192ED03))) & np.uint64(1)
        out |= (((x >> shift) & np.uint64(1)) ^ flip) << shift
    return out


@numba.njit(cache=True, inline="always")
def _sobol2(i):
    """The first two dimensions of the Sobol (0, 2)-sequence at index i, as 32-bit fractions: van der Corput
    (the bits of i reversed) and the second dimension (direction numbers v₁ = 2³¹, v_k = v_(k−1) ⊕ v_(k−1)/2,
    i.e. m = 1, 3, 5, 15, … — Joe & Kuo's first entry)."""
    x = np.uint64(0)
    y = np.uint64(0)
    v = np.uint64(1) << np.uint64(31)
    b = np.uint64(1) << np.uint64(31)
    k = np.uint64(i)
    while k:
        if k & np.uint64(1):
            x |= b
            y ^= v
        k >>= np.uint64(1)
        b >>= np.uint64(1)
        v ^= v >> np.uint64(1)
    return x, y


@numba.njit(cache=True, inline="always")
def _shuffle(i, n, key):
    """A random permutation of 0 … n − 1 keyed by ``key``, at i: the index's bits (m of them, 2^m ≥ n)
    Owen-scrambled — a bijection of 0 … 2^m − 1 — walked along its cycle until it lands below n (Black &
    Rogaway 2002, cycle walking), so a bijection of 0 … n − 1."""
    m = 0
    while (1 << m) < n:
        m += 1
    if m == 0:
        return i
    shift = np.uint64(32 - m)
    x = np.uint64(i)
    while True:
        x = _owen_scramble(x << shift, key) >> shift
        if x < np.uint64(n):
            return np.int64(x)


@numba.njit(cache=True, inline="always")
def _stratified_pair(seed, point, sample, spp, replicates, pair):
    """The uniforms (u1, u2) of a point's path ``sample`` (0 … spp − 1) for the dimension pair ``pair``: replicate
    ``g = sample mod G`` (G = ``replicates``), index ``i = sample div G`` in it; the i-th point of the Sobol
    (0, 2)-sequence, Owen-scrambled by a key of (seed, point, g, pair, dimension) — each replicate an independent
    randomized net, each point of it uniform on [0, 1)². Pair 0 (the first direction) takes the nets in order;
    the other pairs (padding, Kollig & Keller 2002) through a random permutation of the replicate's n_g indices,
    so that pairs are stratified each and independent of each other."""
    g = sample % replicates
    i = sample // replicates
    key = _mix64(_mix64(seed * np.uint64(0x9E3779B97F4A7C15) + np.uint64(0x5851F42D4C957F2D))
                 + _mix64(np.uint64(point)) + np.uint64(g) * np.uint64(0x632BE59BD9B4E019)
                 + np.uint64(pair) * np.uint64(0xDB4F0B9175AE2165))
    if pair > 0:
        i = _shuffle(i, (spp - g + replicates - 1) // replicates, _mix64(key + np.uint64(5)))
    x, y = _sobol2(i)
    sx = _owen_scramble(x, _mix64(key + np.uint64(1)))
    sy = _owen_scramble(y, _mix64(key + np.uint64(2)))
    # the scrambled net's coordinates are uniform on the 2⁻³² grid; a uniform below it makes them uniform on [0, 1)
    j = np.uint64(sample) * np.uint64(2)
    ux = (np.float64(sx) + np.float64(_mix64(key + j + np.uint64(6)) >> np.uint64(11)) * (1.0 / 9007199254740992.0)) \
        * (1.0 / 4294967296.0)
    uy = (np.float64(sy) + np.float64(_mix64(key + j + np.uint64(7)) >> np.uint64(11)) * (1.0 / 9007199254740992.0)) \
        * (1.0 / 4294967296.0)
    return min(ux, 0.9999999999999999), min(uy, 0.9999999999999999)


@numba.njit(cache=True, nogil=True)
def _stratified_kernel(seed, points, samples, spp, replicates, pair, out):
    for i in range(points.shape[0]):
        u1, u2 = _stratified_pair(seed, points[i], samples[i], spp, replicates, pair)
        out[i, 0] = u1
        out[i, 1] = u2


@numba.njit(cache=True, nogil=True)
def _first_cosine_kernel(normals, seed, points, samples, spp, replicates, out, cos_out):
    for i in range(points.shape[0]):
        u1, u2 = _stratified_pair(seed, points[i], samples[i], spp, replicates, 0)
        dx, dy, dz, z = _cosine_dir(normals[i, 0], normals[i, 1], normals[i, 2], u1, u2)
        out[i, 0] = dx
        out[i, 1] = dy
        out[i, 2] = dz
        cos_out[i] = z


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



def _check_first(points, samples, spp: int, replicates: int):
    q = np.ascontiguousarray(points, np.uint64)
    j = np.ascontiguousarray(samples, np.int64)
    if q.shape != j.shape or q.ndim != 1:
        raise ValueError(f"stratified samples: points {q.shape} and samples {j.shape} must be the same (N,)")
    if int(replicates) < 1 or (j.size and (j.min() < 0 or j.max() >= int(spp))):
        raise ValueError(f"stratified samples: need replicates >= 1 and 0 <= samples < spp = {spp}")
    return q, j


def stratified_uniforms(seed: int, points, samples, spp: int, replicates: int, pair: int = 0) -> np.ndarray:
    """(N, 2) float64 uniforms of dimension pair ``pair`` of path ``samples[i]`` (0 … spp − 1) of point
    ``points[i]`` (uint64): ``replicates`` independent Owen-scrambled Sobol nets per point and pair (module doc),
    sample j in net ``j mod replicates``; pair 0 the first direction, 1 and 2 the first emitter sample. Deterministic
    per (seed, point, sample, spp, replicates, pair)."""
    q, j = _check_first(points, samples, spp, replicates)
    out = np.empty((q.shape[0], 2), np.float64)
    _stratified_kernel(np.uint64(seed), q, j, int(spp), int(replicates), int(pair), out)
    return out


def first_cosine_directions(normals, seed: int, points, samples, spp: int, replicates: int):
    """``(dirs (N, 3), cos θ (N,))``: cosine-distributed unit directions about the unit ``normals`` (pdf cos θ / π)
    from :func:`stratified_uniforms` — the first direction of each path (pathtrace module doc, "Stratified first
    directions")."""
    q, j = _check_first(points, samples, spp, replicates)
    n = np.ascontiguousarray(normals, np.float64)
    if n.shape != (q.shape[0], 3):
        raise ValueError(f"first_cosine_directions: normals {n.shape} do not match {q.shape[0]} paths")
    out = np.empty((q.shape[0], 3), np.float64)
    cos = np.empty(q.shape[0], np.float64)
    _first_cosine_kernel(n, np.uint64(seed), q, j, int(spp), int(replicates), out, cos)
    return out, cos
