"""Indirect irradiance at shading points from the probes' irradiance maps: the gather step of a bounce.

DDGI-I §3.4.1: each hit reads the 8 probes of its cage, weighted (DDGI-P §2.2, :mod:`workers.kernels.ddgi`).
Two ways to evaluate the same sampler, both callables ``gather(maps) -> (H, C)`` for the bounce integrator
(:func:`workers.kernels.bounce.integrate`), ``maps`` (P, n+2, n+2, C) float32 bordered octahedral irradiance
with C = 3·k (k configurations, RGB interleaved):

- :class:`SamplerGather`: :func:`~workers.kernels.ddgi.sample_irradiance` itself, on SAMPLE_THREADS threads
  (one configuration at a time; the light stage);
- :class:`MatrixGather`: the sampler as a sparse matrix (:func:`ddgi_weights`, built once), one sparse product
  for every configuration of a batch (PRT's dataset). It equals the sampler to float32 rounding.

Consumers: stages/light, kernels/prt_dataset. Inverse: none.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp

from workers.kernels.ddgi import cage_probes, sample_irradiance

__all__ = ["SamplerGather", "MatrixGather", "ddgi_weights", "SAMPLE_THREADS"]

SAMPLE_THREADS = 2
"""Threads for the probe sampler (its numba kernel releases the GIL)."""


class SamplerGather:
    """``gather(maps) -> (H, C) float32``: DDGI irradiance (:func:`sample_irradiance`) at the points.

    points, normals, views : (H, 3) float32 (world space, metres; unit normal; unit direction toward the
    viewer); grid : ``counts``, ``origin``, ``spacing``; positions : (P, 3) relocated probes; states : (P,);
    depth : (P, m+2, m+2, 2) depth moments with border; bias : DDGI-P eq 2's B; visible : (H, 8) uint8
    ray-traced cage visibility (:func:`workers.kernels.probe_hits.probe_visibility`) or None.
    The points are cut into SAMPLE_THREADS contiguous chunks (the same result as one call).
    """

    def __init__(self, points, normals, views, grid: dict, positions, states, depth, bias: float, visible=None):
        self.points, self.normals, self.views = points, normals, views
        self.grid, self.positions, self.states, self.depth = grid, positions, states, depth
        self.bias, self.visible = bias, visible

    def _sample(self, maps: np.ndarray) -> np.ndarray:
        g = self.grid
        n = self.points.shape[0]
        out = np.empty((n, 3), np.float32)
        bounds = np.linspace(0, n, SAMPLE_THREADS + 1).astype(int)

        def work(i):
            a, b = bounds[i], bounds[i + 1]
            out[a:b] = sample_irradiance(self.points[a:b], self.normals[a:b], self.views[a:b], g["counts"],
                                         g["origin"], g["spacing"], self.positions, self.states, maps, self.depth,
                                         self.bias, visible=None if self.visible is None else self.visible[a:b])

        with ThreadPoolExecutor(SAMPLE_THREADS) as pool:
            list(pool.map(work, range(SAMPLE_THREADS)))
        return out

    def __call__(self, maps: np.ndarray) -> np.ndarray:
        k = maps.shape[-1] // 3
        if k == 1:
            return self._sample(maps)
        return np.concatenate([self._sample(np.ascontiguousarray(maps[..., 3 * j:3 * j + 3])) for j in range(k)],
                              axis=1)


class MatrixGather:
    """``gather(maps) -> (H, C)``: ``W @ maps.reshape(P·(n+2)², C)`` with W from :func:`ddgi_weights`."""

    def __init__(self, W: sp.csr_matrix):
        self.W = W

    def __call__(self, maps: np.ndarray) -> np.ndarray:
        return self.W @ maps.reshape(self.W.shape[1], -1)


def ddgi_weights(points, normals, views, grid: dict, positions, states, depth, n: int, bias: float,
                 visible=None) -> sp.csr_matrix:
    """The DDGI sampler as a sparse matrix: ``sample_irradiance(..., maps) == W @ maps.reshape(P·(n+2)², 3)``.

    ``maps`` is (P, n+2, n+2, 3) bordered octahedral irradiance; ``visible`` (N, 8) the ray-traced cage
    visibility (:func:`workers.kernels.probe_hits.probe_visibility`), passed through. The sampler is
    linear in the maps (DDGI-P §2.2: ``E = Σ_i w_i E_i(n) / Σ_i w_i``, weights independent of E) and its
    weights depend only on geometry, probe positions, states, depth and visibility, so they are read back
    from the real sampler (:func:`workers.kernels.ddgi.sample_irradiance`): three calls with maps that are 1
    on the probes of one of the 8 grid-parity classes (the 8 probes of a cage have distinct parities) give
    each cage probe's normalized weight; one call with maps holding their own row and column index gives
    the bilinear footprint (the same for the 8 probes: it depends on the normal only). The cage comes from
    :func:`workers.kernels.ddgi.cage_probes`. Returns (N, P·(n+2)²) float32 CSR with 32 stored entries a
    row (some zero, some repeated: products sum them; 8 bytes an entry, no COO temporaries).
    """
    pts = np.ascontiguousarray(points, np.float32)
    nrm = np.ascontiguousarray(normals, np.float32)
    view = np.ascontiguousarray(views, np.float32)
    N = pts.shape[0]
    counts = np.asarray(grid["counts"], np.int64)
    origin = np.asarray(grid["origin"], np.float64)
    spacing = np.asarray(grid["spacing"], np.float64)
    nx, ny, nz = (int(c) for c in counts)
    P = nx * ny * nz
    t = n + 2
    if N == 0:
        return sp.csr_matrix((0, P * t * t), dtype=np.float32)
    q = np.arange(P)
    gi, gj, gk = q % nx, (q // nx) % ny, q // (nx * ny)
    cls = (gi & 1) | ((gj & 1) << 1) | ((gk & 1) << 2)

    def sample(maps):
        return sample_irradiance(pts, nrm, view, counts, origin, spacing, positions, states, maps, depth, bias,
                                 visible=visible)

    w8 = np.zeros((N, 8), np.float64)
    maps = np.zeros((P, t, t, 3), np.float32)
    for call in range(3):
        maps[:] = 0
        for ch in range(3):
            k = 3 * call + ch
            if k < 8:
                maps[cls == k, :, :, ch] = 1.0
        out = sample(maps)                                  # w_i / Σ w of the cage probe of class k
        for ch in range(3):
            if 3 * call + ch < 8:
                w8[:, 3 * call + ch] = out[:, ch]
    maps[:] = 0
    maps[..., 0] = np.arange(t, dtype=np.float32)[None, :, None]
    maps[..., 1] = np.arange(t, dtype=np.float32)[None, None, :]
    maps[..., 2] = 1.0
    foot = sample(maps).astype(np.float64)                  # the bilinear tap's (row, col) position
    r0 = np.clip(np.floor(foot[:, 0]), 0, n).astype(np.int64)
    c0 = np.clip(np.floor(foot[:, 1]), 0, n).astype(np.int64)
    fr = np.clip(foot[:, 0] - r0, 0.0, 1.0)
    fc = np.clip(foot[:, 1] - c0, 0.0, 1.0)
    _, cage = cage_probes(pts, nrm, view, counts, origin, spacing, bias)    # (N, 8) as the sampler picks them
    # 32 taps per row (8 corners x 4 bilinear texels), built straight into CSR: row i owns entries 32i..32i+31
    cols = np.zeros((N, 8, 4), np.int64 if P * t * t >= 2 ** 31 else np.int32)
    vals = np.zeros((N, 8, 4), np.float32)
    rows = np.arange(N)
    taps = ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc))
    for c in range(8):
        o = (c & 1, (c >> 1) & 1, (c >> 2) & 1)
        if any(o[a] and counts[a] == 1 for a in range(3)):
            continue  # duplicates corner 0 on a 1-probe axis (the sampler clamps; the class sum holds both)
        probe = cage[:, c]
        w = w8[rows, cls[probe]]
        for j, (dr, dc, bw) in enumerate(taps):
            cols[:, c, j] = probe * t * t + (r0 + dr) * t + (c0 + dc)
            vals[:, c, j] = w * bw
    indptr = np.arange(0, 32 * N + 1, 32, dtype=cols.dtype)
    return sp.csr_matrix((vals.reshape(-1), cols.reshape(-1), indptr), shape=(N, P * t * t))
