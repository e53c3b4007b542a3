"""Indirect irradiance at shading points from the probes' irradiance maps: the gather step of a bounce.

DDGI-I §3.4.1: each hit reads the 8 probes of its cage, weighted (DDGI-P §2.2, :mod:`workers.kernels.ddgi`).
Two ways to evaluate the same sampler, both callables ``gather(maps) -> (H, C)`` for the bounce integrator
(:func:`workers.kernels.bounce.integrate`), ``maps`` (P, n+2, n+2, C) float32 bordered octahedral irradiance
with C = 3·k (k configurations, RGB interleaved):

- :class:`SamplerGather`: :func:`~workers.kernels.ddgi.sample_irradiance`'s weights computed once
  (:func:`sampler_weights`: they depend on geometry, probes, depth and visibility, not on the maps), then each
  bounce only blends the maps with them (:func:`apply_sampler_weights`), on SAMPLE_THREADS threads, every
  configuration of a batch in one pass (the light stage). It equals the sampler to float32 rounding of the
  normalized weights (about 1e-7 relative), at about 48 bytes a point. With ``read="sh"`` (the light stage's and
  PRT's default, ``light.gather``) the same weights blend each cage probe's clamped L2 SH irradiance at the
  point's normal instead of its map (:func:`apply_sampler_weights_sh`; +36 bytes a point);
- :class:`MatrixGather`: the sampler as a sparse matrix (:func:`ddgi_weights`, built once), one sparse product
  for every configuration of a batch (PRT's dataset). It equals the sampler to float32 rounding.

Consumers: stages/light, kernels/prt_dataset. Inverse: none.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numba import njit

from workers.kernels.chunks import map_chunks
from workers.kernels.ddgi import point_weights, cage_probes, sample_irradiance, sampler_inputs
from workers.kernels.sh import sh_irradiance_basis

__all__ = ["SamplerGather", "MatrixGather", "ddgi_weights", "SamplerWeights", "sampler_weights",
           "apply_sampler_weights", "apply_sampler_weights_sh", "SAMPLE_THREADS"]

SAMPLE_THREADS = 2
"""Threads for the probe sampler (its numba kernel releases the GIL)."""

BASIS_CHUNK = 1 << 18
"""Points per chunk of the SH gather's per-point basis (float64 temporaries of 9 columns: 19 MB a chunk)."""


class SamplerWeights(NamedTuple):
    """The DDGI sampler's weights at N points (:func:`sampler_weights`), for any maps of the grid.

    ``base`` (N,) int32: the cage's base probe (corner c at ``base + (c & 1)·steps[0] + (c >> 1 & 1)·steps[1] +
    (c >> 2 & 1)·steps[2]``); ``weight`` (N, 8) float32: corner c's weight over the weights' sum (0: OFF, occluded,
    or a row the sampler returns 0 for); ``texel`` (N,) int32: the bilinear tap's top-left texel ``row·(n+2) + col``
    of the normal's direction in a bordered map; ``frac`` (N, 2) float32: its (row, col) fractions; ``steps`` (3,)
    int64: the flat-index step per axis (0 on a one-probe axis, where the sampler clamps)."""

    base: np.ndarray
    weight: np.ndarray
    texel: np.ndarray
    frac: np.ndarray
    steps: np.ndarray


@njit(cache=True, nogil=True)
def _weights_kernel(points, normals, views, counts, origin, spacing, layers, bias, probe_pos, states, depth, visible,
                    t, base, weight, texel, frac):
    w8 = np.empty(8, np.float64)
    for i in range(points.shape[0]):
        ok, q0, ir0, ic0, ifr, ifc = point_weights(i, points, normals, views, counts, origin, spacing, layers, bias,
                                                     probe_pos, states, depth, visible, t - 2, w8)
        wsum = 0.0
        for c in range(8):
            wsum += w8[c]
        for c in range(8):
            weight[i, c] = w8[c] / wsum if ok and wsum > 0.0 else 0.0
        base[i] = q0
        texel[i] = ir0 * t + ic0
        frac[i, 0] = ifr
        frac[i, 1] = ifc


@njit(cache=True, nogil=True)
def _apply_kernel(base, weight, texel, frac, steps, maps, out):
    t = maps.shape[1]
    C = maps.shape[3]
    acc = np.empty(C, np.float64)
    for i in range(base.shape[0]):
        r0 = texel[i] // t
        c0 = texel[i] - r0 * t
        fr = float(frac[i, 0])
        fc = float(frac[i, 1])
        w00, w01 = (1.0 - fr) * (1.0 - fc), (1.0 - fr) * fc      # the bilinear tap's four texel weights
        w10, w11 = fr * (1.0 - fc), fr * fc
        for ch in range(C):
            acc[ch] = 0.0
        for c in range(8):
            w = float(weight[i, c])
            if w == 0.0:
                continue
            q = base[i] + (c & 1) * steps[0] + ((c >> 1) & 1) * steps[1] + ((c >> 2) & 1) * steps[2]
            m00, m01 = maps[q, r0, c0], maps[q, r0, c0 + 1]
            m10, m11 = maps[q, r0 + 1, c0], maps[q, r0 + 1, c0 + 1]
            for ch in range(C):
                acc[ch] += w * (w00 * m00[ch] + w01 * m01[ch] + w10 * m10[ch] + w11 * m11[ch])
        for ch in range(C):
            out[i, ch] = acc[ch]


@njit(cache=True, nogil=True)
def _apply_sh_kernel(base, weight, basis, steps, sh, out):
    C = sh.shape[2]
    K = basis.shape[1]
    for i in range(base.shape[0]):
        for ch in range(C):
            acc = 0.0
            for c in range(8):
                w = float(weight[i, c])
                if w == 0.0:
                    continue
                q = base[i] + (c & 1) * steps[0] + ((c >> 1) & 1) * steps[1] + ((c >> 2) & 1) * steps[2]
                e = 0.0
                for k in range(K):
                    e += float(basis[i, k]) * float(sh[q, k, ch])
                if e > 0.0:                     # a probe's L2 irradiance, clamped where it rings below 0
                    acc += w * e
            out[i, ch] = acc


@njit(cache=True, nogil=True)
def _apply_sh_kernel3(base, weight, basis, steps, sh, out):
    """:func:`_apply_sh_kernel` for C = 3 (RGB): the three channels in one pass over each cage probe's K × 3 row
    (about twice as fast; the same sums in the same order, so the same floats)."""
    K = basis.shape[1]
    for i in range(base.shape[0]):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for c in range(8):
            w = float(weight[i, c])
            if w == 0.0:
                continue
            q = base[i] + (c & 1) * steps[0] + ((c >> 1) & 1) * steps[1] + ((c >> 2) & 1) * steps[2]
            e0 = 0.0
            e1 = 0.0
            e2 = 0.0
            for k in range(K):
                b = float(basis[i, k])
                e0 += b * float(sh[q, k, 0])
                e1 += b * float(sh[q, k, 1])
                e2 += b * float(sh[q, k, 2])
            if e0 > 0.0:                        # each channel clamped where the probe's L2 rings below 0
                a0 += w * e0
            if e1 > 0.0:
                a1 += w * e1
            if e2 > 0.0:
                a2 += w * e2
        out[i, 0] = a0
        out[i, 1] = a1
        out[i, 2] = a2


def sampler_weights(points, normals, views, grid: dict, positions, states, depth, n: int, bias: float,
                    visible=None) -> SamplerWeights:
    """What :func:`workers.kernels.ddgi.sample_irradiance` weighs at each point, computed once (DDGI-P §2.2:
    ``E = Σ_i w_i E_i(n) / Σ_i w_i``, the weights independent of E), on SAMPLE_THREADS threads.

    points, normals, views : (N, 3) (world space, metres; unit normal; unit direction toward the viewer); grid :
    ``counts``, ``origin``, ``spacing``; positions : (P, 3) relocated probes; states : (P,); depth : (P, m+2, m+2, 2)
    depth moments with border; n : interior texels of the irradiance maps; bias : DDGI-P eq 2's B; visible :
    (N, 8) ray-traced cage visibility or None. The same arithmetic as the sampler (the shared
    :func:`workers.kernels.ddgi.point_weights`), the normalized weights rounded to float32.
    """
    pts, nrm, view, cnt, org, spc, lay, b, pos, st, dep, vis = sampler_inputs(
        points, normals, views, grid["counts"], grid["origin"], grid["spacing"], positions, states, depth, bias,
        visible, grid.get("layers"))
    dep = np.ascontiguousarray(dep, np.float32 if dep.dtype == np.float32 else np.float64)
    N = pts.shape[0]
    if cnt.prod() >= 2 ** 31:
        raise ValueError(f"sampler_weights: {int(cnt.prod())} probes do not fit int32 indices")
    out = SamplerWeights(np.empty(N, np.int32), np.empty((N, 8), np.float32), np.empty(N, np.int32),
                         np.empty((N, 2), np.float32),
                         np.array([1 if cnt[0] > 1 else 0, cnt[0] if cnt[1] > 1 else 0,
                                   cnt[0] * cnt[1] if cnt[2] > 1 else 0], np.int64))

    _on_threads(N, lambda a, e: _weights_kernel(pts[a:e], nrm[a:e], view[a:e], cnt, org, spc, lay, b, pos, st, dep,
                                                vis[a:e] if vis.shape[0] else vis, n + 2, out.base[a:e],
                                                out.weight[a:e], out.texel[a:e], out.frac[a:e]))
    return out


def _on_threads(N: int, run) -> None:
    """``run(a, e)`` over SAMPLE_THREADS contiguous row ranges [a, e) of N rows, on as many threads
    (:func:`workers.kernels.chunks.map_chunks` with one chunk a thread)."""
    map_chunks(run, N, -(-N // SAMPLE_THREADS), SAMPLE_THREADS)


def apply_sampler_weights(weights: SamplerWeights, maps: np.ndarray) -> np.ndarray:
    """(N, C) float32: ``Σ_c weight_c · bilinear(maps[probe_c], normal)`` with maps (P, n+2, n+2, C) float32 (any C:
    every configuration of a batch at once), on SAMPLE_THREADS threads; float64 sums, as the sampler."""
    maps = np.ascontiguousarray(maps, np.float32)
    w = weights
    out = np.empty((w.base.shape[0], maps.shape[3]), np.float32)
    _on_threads(w.base.shape[0], lambda a, e: _apply_kernel(w.base[a:e], w.weight[a:e], w.texel[a:e], w.frac[a:e],
                                                           w.steps, maps, out[a:e]))
    return out


def apply_sampler_weights_sh(weights: SamplerWeights, basis: np.ndarray, sh: np.ndarray) -> np.ndarray:
    """(N, C) float32: ``Σ_c weight_c · max(0, Σ_k basis_k · sh[probe_c, k])``: the sampler's weights over each cage
    probe's SH irradiance at the point's normal. basis : (N, K) float32, ``Â_l · Y_k(n)`` at the normal
    (:func:`workers.kernels.sh.sh_irradiance_basis`); sh : (P, K, C) float32 radiance SH (any C); on SAMPLE_THREADS
    threads."""
    sh = np.ascontiguousarray(sh, np.float32)
    w = weights
    out = np.empty((w.base.shape[0], sh.shape[2]), np.float32)
    kernel = _apply_sh_kernel3 if sh.shape[2] == 3 else _apply_sh_kernel
    _on_threads(w.base.shape[0], lambda a, e: kernel(w.base[a:e], w.weight[a:e], basis[a:e], w.steps, sh, out[a:e]))
    return out


class SamplerGather:
    """``gather(maps[, sh]) -> (H, C) float32``: DDGI irradiance (:func:`sample_irradiance`) at the points, from
    weights computed once (:func:`sampler_weights`; the points, normals and views are not kept).

    points, normals, views : (H, 3) float32 (world space, metres; unit normal; unit direction toward the
    viewer); grid : ``counts``, ``origin``, ``spacing``; positions : (P, 3) relocated probes; states : (P,);
    depth : (P, m+2, m+2, 2) depth moments with border; bias : DDGI-P eq 2's B; visible : (H, 8) uint8
    ray-traced cage visibility (:func:`workers.kernels.probe_hits.probe_visibility`) or None; n : interior texels
    of the maps to come (None: the first call's; the inputs are kept until then, and dropped after).

    ``read``: what each cage probe reports at the point's normal. ``"octahedral"``: its irradiance map, bilinear
    (the sampler as the runtime reads it). ``"sh"``: its L2 radiance SH evaluated as irradiance
    (:func:`apply_sampler_weights_sh`; ``reads_sh`` True: the bounce integrator passes the SH it projects each
    bounce, (P, 9, C)); the same weights. The light stage's gather (``light.gather``, docs/architecture.md): an
    8-texel map's bilinear read of a normal at an angle to the map's axes reads the dim side of a small bright
    source high, and in a room lit through a door the bounces multiply it; SH irradiance does not depend on the
    direction's place on a map.
    """

    def __init__(self, points, normals, views, grid: dict, positions, states, depth, bias: float, visible=None,
                 n: int | None = None, read: str = "octahedral"):
        if read not in ("octahedral", "sh"):
            raise ValueError(f"SamplerGather: read must be 'octahedral' or 'sh', got {read!r}")
        self._inputs = (points, normals, views, grid, positions, states, depth)
        self.bias, self.visible, self.n, self.weights = bias, visible, None, None
        self.reads_sh, self.basis = read == "sh", None
        if n is not None:
            self._build(int(n))

    def _build(self, n: int) -> None:
        if self.reads_sh:                   # (H, 9), 36 bytes a point; in chunks on two threads (numpy frees the GIL)
            nrm = self._inputs[1]
            self.basis = np.empty((nrm.shape[0], 9), np.float32)

            def chunk(a: int, e: int) -> None:
                self.basis[a:e] = sh_irradiance_basis(nrm[a:e])

            map_chunks(chunk, nrm.shape[0], BASIS_CHUNK)
        self.weights = sampler_weights(*self._inputs, n, self.bias, self.visible)
        self.n, self._inputs, self.visible = n, None, None

    def __call__(self, maps: np.ndarray, sh: np.ndarray | None = None) -> np.ndarray:
        if self.weights is None:
            self._build(maps.shape[1] - 2)
        elif maps.shape[1] != self.n + 2:
            raise ValueError(f"SamplerGather: built for ({self.n}+2)² maps, got {maps.shape}")
        if self.reads_sh:
            if sh is None or sh.shape[1] != self.basis.shape[1]:
                raise ValueError("SamplerGather(read='sh'): needs the probes' (P, 9, C) SH")
            return apply_sampler_weights_sh(self.weights, self.basis, sh)
        return apply_sampler_weights(self.weights, maps)


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
                                 visible=visible, layers=grid.get("layers"))

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
    _, cage = cage_probes(pts, nrm, view, counts, origin, spacing, bias,   # (N, 8) as the sampler picks them
                          layers=grid.get("layers"))
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
