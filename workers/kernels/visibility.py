"""The visibility field θ of Mask Decomposition (MD §3.4 step 1; DESIGN stage 3).

MD §3.1.2 eq 2 reconstructs a probe-GI light field as ``L(x) = Σ_i θ_i(x) φ_i(x) P_i`` with
``θ_i(x) ∈ [0, 1]`` the visibility from the shading point x to probe i; eq 5 and eq 6 compare
masks and probe pairs through the same θ summed over "x discretized by a refined grid". This
module bakes that θ on the refined grid; stage ``visibility`` runs it slab by slab and stage
``masks`` consumes it (eq 5, 6).

Refined grid
------------
The probe grid has ``counts = (nx, ny, nz)`` probes, probe (i, j, k) at
``origin + spacing * (i, j, k)`` before relocation (see :mod:`workers.kernels.grid`). It has
``max(n - 1, 1)`` cells per axis: an axis with one probe is treated as one cell of zero extent,
whose samples lie in the probe plane. Each cell holds ``S³`` samples; sample (a, b, c) in
[0, S)³ of cell (ci, cj, ck) sits at::

    origin + spacing * ((ci, cj, ck) + ((a, b, c) + 0.5) / S)        (world space, metres)

The whole field is a volume of shape ``(Z, Y, X) = (cz·S, cy·S, cx·S)`` (C order, x fastest)
and field sample (x, y, z) belongs to cell (x // S, y // S, z // S): sampled as a 3D texture over
the grid's box, its texel centres are exactly these samples. Global sample index
``g = x + X·(y + Y·z)``.

θ
-
For every sample and each of the 8 corner probes of its cell (corner c has offset
``(c & 1, c >> 1 & 1, c >> 2 & 1)``, the :func:`workers.kernels.grid.cage_indices` convention; an
offset on a one-probe axis clamps to that probe), ``rays`` occlusion rays go from the sample to
targets at the probe's *relocated* position plus a jitter offset uniform in a ball of radius
``jitter · min(spacing)`` (min over axes with more than one probe). The offset is a hash of
``(seed, g, corner, ray)`` (splitmix64), so the result of a sample never depends on how the field
was split into slabs or chunks, nor on the caster's thread count. With ``rays = 1`` the single ray
goes to the exact probe position whatever the jitter. A ray is blocked when the scene has a hit
with ``t ≤ |target − sample| − 1e-4·caster.scale``; a ray whose that length is ≤ 0 (the sample
is at the target) is unblocked. ``θ = unblocked / rays``, stored as ``uint8 round(255·θ)``.
OFF probes (:data:`workers.kernels.grid.OFF`) get θ = 0.

Inside samples ("don't care")
-----------------------------
Samples inside geometry get weight 0 in the sums of MD eq 5-6. The test reuses the rays: the
first ray (ray 0) of each of the 8 corners is cast with ``intersect`` (the other rays with
``occluded``), and each of those 8 rays votes

- *inside*: its first hit (within tfar) is the back face of a single-sided triangle, or it is
  unblocked and its probe is OFF (the sample shares a region with a probe stuck in geometry);
- *outside*: its first hit is a front face or any face of a double-sided triangle, or it is
  unblocked and its probe is not OFF (ACTIVE / SLEEPING probes lie in open space).

The sample is don't-care when inside votes > outside votes (a tie keeps it). This needs
consistently outward-facing (counter-clockwise) single-sided geometry, as DDGI's backface test
does (DDGI-P §4.1); double-sided surfaces have no inside. It costs no extra rays. Measured on
zdm2-sauerbraten (16x8x16 grid, S = 8) it agrees with ``caster.inside_parity`` on most samples;
see tests/kernels/test_visibility.py and the stage's report for the numbers.

Consumers: stages/visibility (per-slab jobs and the join), stages/masks (eq 5-6).
"""
from __future__ import annotations

import math
import time

import numba
import numpy as np

from workers.kernels.grid import OFF

__all__ = ["field_shape", "sample_positions", "theta_slab", "slab_ranges", "join_slabs", "TFAR_EPS"]

TFAR_EPS = 1e-4  # rays stop this far (x caster.scale) before their target (dimensionless)
CHUNK_RAYS = 1 << 21  # rays built and cast per batch inside theta_slab; bounds memory (~70 MB)

_U = np.uint64
_GAMMA = _U(0x9E3779B97F4A7C15)
_M1 = _U(0xBF58476D1CE4E5B9)
_M2 = _U(0x94D049BB133111EB)
_SEED_SALT = _U(0x5EED0F7157AB1E5)
_S30, _S27, _S31, _S11 = _U(30), _U(27), _U(31), _U(11)
_INV53 = 1.0 / float(1 << 53)


# ---------------------------------------------------------------------- geometry of the field
def _cells(counts) -> np.ndarray:
    c = np.asarray(counts, np.int64).reshape(3)
    if (c < 1).any():
        raise ValueError(f"counts must be >= 1 on every axis, got {c.tolist()}")
    return np.maximum(c - 1, 1)


def _check_s(S) -> int:
    if int(S) != S or int(S) < 1:
        raise ValueError(f"samples per cell S must be a positive integer, got {S!r}")
    return int(S)


def field_shape(counts, S) -> tuple[int, int, int]:
    """Shape ``(Z, Y, X)`` of the θ field: ``max(n - 1, 1) · S`` samples per axis.

    counts : (nx, ny, nz) probes; S : samples per cell axis (>= 1).
    """
    S = _check_s(S)
    cx, cy, cz = (int(v) for v in _cells(counts))
    return cz * S, cy * S, cx * S


def sample_positions(counts, origin, spacing, S, z_range) -> np.ndarray:
    """World positions of the field samples in rows ``z ∈ [z0, z1)``.

    Parameters
    ----------
    counts : (3,) int, probes per axis (nx, ny, nz).
    origin, spacing : (3,) float, metres (probe (i, j, k) at ``origin + spacing·(i, j, k)``).
    S : int, samples per cell axis.
    z_range : (z0, z1), field rows, ``0 <= z0 <= z1 <= Z``.

    Returns
    -------
    (n, 3) float64, n = (z1 − z0)·Y·X, in C order of (z, y, x) (x fastest): sample (x, y, z) at
    ``origin + spacing·((x, y, z) // S + ((x, y, z) % S + 0.5) / S)``; on a one-probe axis the
    coordinate is ``origin`` (the probe plane).
    """
    S = _check_s(S)
    Z, Y, X = field_shape(counts, S)
    z0, z1 = _check_range(z_range, Z)
    g0, n = z0 * Y * X, (z1 - z0) * Y * X
    out = np.empty((n, 3), np.float64)
    _positions_kernel(g0, n, *_grid_args(counts, origin, spacing, S), out)
    return out


def _check_range(z_range, Z: int) -> tuple[int, int]:
    z0, z1 = (int(v) for v in z_range)
    if not 0 <= z0 <= z1 <= Z:
        raise ValueError(f"z_range must satisfy 0 <= z0 <= z1 <= Z = {Z}, got {(z0, z1)}")
    return z0, z1


def slab_ranges(Z, S, slabs) -> list[tuple[int, int]]:
    """Split the ``Z`` field rows into ``slabs`` contiguous ``[z0, z1)`` ranges of whole cell layers.

    ``Z`` must be a multiple of ``S``; the ``Z / S`` cell layers are shared out as evenly as
    possible (sizes differ by at most one layer, larger slabs first). Asking for more slabs
    than layers gives one slab per layer (never an empty range).
    """
    S = _check_s(S)
    Z, slabs = int(Z), int(slabs)
    if Z < S or Z % S:
        raise ValueError(f"Z = {Z} must be a positive multiple of S = {S}")
    if slabs < 1:
        raise ValueError(f"slabs must be >= 1, got {slabs}")
    layers = Z // S
    n = min(slabs, layers)
    base, extra = divmod(layers, n)
    out, z = [], 0
    for s in range(n):
        z1 = z + (base + (1 if s < extra else 0)) * S
        out.append((z, z1))
        z = z1
    return out


def join_slabs(parts):
    """Concatenate per-slab ``(theta, dont_care)`` along z, in the order given.

    parts : list of ``(theta (z_s, Y, X, 8) uint8, dont_care (z_s, Y, X) bool)``, consecutive
    slabs of one field (as :func:`slab_ranges` lists them). Returns ``(theta (Z, Y, X, 8) uint8,
    dont_care (Z, Y, X) bool)``.
    """
    parts = list(parts)
    if not parts:
        raise ValueError("join_slabs: no slabs")
    yx = parts[0][0].shape[1:3]
    for th, dc in parts:
        if th.ndim != 4 or th.shape[3] != 8 or th.shape[1:3] != yx or dc.shape != th.shape[:3]:
            raise ValueError(f"join_slabs: mismatched slab shapes {th.shape} / {dc.shape}")
    theta = np.concatenate([np.asarray(p[0], np.uint8) for p in parts], axis=0)
    dont_care = np.concatenate([np.asarray(p[1], bool) for p in parts], axis=0)
    return theta, dont_care


# ---------------------------------------------------------------------- numba kernels
@numba.njit(cache=True, inline="always")
def _mix(x):
    """splitmix64 finalizer (uint64 -> uint64)."""
    x = (x ^ (x >> _S30)) * _M1
    x = (x ^ (x >> _S27)) * _M2
    return x ^ (x >> _S31)


def _grid_args(counts, origin, spacing, S):
    """The grid as the kernels take it: (X, Y, S, counts int64 (3,), origin f64 (3,), spacing f64 (3,))."""
    Z, Y, X = field_shape(counts, S)
    return (X, Y, int(S), np.asarray(counts, np.int64).reshape(3).copy(),
            np.asarray(origin, np.float64).reshape(3).copy(), np.asarray(spacing, np.float64).reshape(3).copy())


@numba.njit(cache=True, inline="always")
def _sample(g, X, Y, S, counts, origin, spacing, out3, cell3):
    """World position (out3) and cell (cell3) of global sample g = x + X·(y + Y·z)."""
    f0 = g % X
    f1 = (g // X) % Y
    f2 = g // (X * Y)
    for a in range(3):
        f = f0 if a == 0 else (f1 if a == 1 else f2)
        c = f // S
        if counts[a] == 1:  # one-probe axis: the probe plane
            out3[a] = origin[a]
            cell3[a] = 0
        else:
            out3[a] = origin[a] + spacing[a] * (c + (f - c * S + 0.5) / S)
            cell3[a] = c


@numba.njit(cache=True)
def _positions_kernel(g0, n, X, Y, S, counts, origin, spacing, out):
    cell3 = np.empty(3, np.int64)
    for i in range(n):
        _sample(g0 + i, X, Y, S, counts, origin, spacing, out[i], cell3)


@numba.njit(cache=True)
def _build_rays(g0, n, X, Y, S, counts, origin, spacing, probes, off, rays, radius, key, eps,
                po, pd, pt, pslot, so, sd, st, sslot, visible, vin, vout, slot_off):
    """Fill the primary (ray 0, intersect) and secondary (rays 1.., occluded) ray buffers.

    Samples g0 .. g0 + n − 1 (global indices); probes (P, 3) f64 relocated positions, off (P,)
    bool. Rays of zero usable length are not cast: they count as unblocked in ``visible`` (and
    vote in vin/vout if primary). Secondary rays to OFF probes are not cast. Fills slot_off
    (n·8,) with whether corner slot i·8 + c is an OFF probe. Returns (n_primary, n_secondary).
    """
    np_, ns = 0, 0
    jit = rays > 1 and radius > 0.0
    nx, ny = counts[0], counts[1]
    pos = np.empty(3, np.float64)
    cell = np.empty(3, np.int64)
    for i in range(n):
        gi = g0 + i
        _sample(gi, X, Y, S, counts, origin, spacing, pos, cell)
        sx, sy, sz = pos[0], pos[1], pos[2]
        ox, oy, oz = np.float32(sx), np.float32(sy), np.float32(sz)
        for c in range(8):
            ci = min(cell[0] + (c & 1), counts[0] - 1)
            cj = min(cell[1] + ((c >> 1) & 1), counts[1] - 1)
            ck = min(cell[2] + ((c >> 2) & 1), counts[2] - 1)
            p = ci + nx * (cj + ny * ck)
            slot = i * 8 + c
            slot_off[slot] = off[p]
            is_off = off[p]
            for r in range(rays):
                if r > 0 and is_off:
                    break
                tx, ty, tz = probes[p, 0], probes[p, 1], probes[p, 2]
                if jit:
                    ctr = (_U(gi) * _U(8) + _U(c)) * _U(rays) + _U(r)
                    h0 = _mix(key + (ctr * _U(3) + _U(1)) * _GAMMA)
                    h1 = _mix(key + (ctr * _U(3) + _U(2)) * _GAMMA)
                    h2 = _mix(key + (ctr * _U(3) + _U(3)) * _GAMMA)
                    u0 = float(h0 >> _S11) * _INV53
                    u1 = float(h1 >> _S11) * _INV53
                    u2 = float(h2 >> _S11) * _INV53
                    cz = 2.0 * u0 - 1.0
                    sz_ = math.sqrt(max(0.0, 1.0 - cz * cz))
                    phi = 2.0 * math.pi * u1
                    rr = radius * u2 ** (1.0 / 3.0)
                    tx += rr * sz_ * math.cos(phi)
                    ty += rr * sz_ * math.sin(phi)
                    tz += rr * cz
                dx, dy, dz = tx - sx, ty - sy, tz - sz
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                tf = d - eps
                if tf <= 0.0:  # the sample sits at the target: nothing can block
                    visible[slot] += 1
                    if r == 0:
                        if is_off:
                            vin[i] += 1
                        else:
                            vout[i] += 1
                    continue
                inv = 1.0 / d
                if r == 0:
                    po[np_, 0], po[np_, 1], po[np_, 2] = ox, oy, oz
                    pd[np_, 0], pd[np_, 1], pd[np_, 2] = dx * inv, dy * inv, dz * inv
                    pt[np_] = tf
                    pslot[np_] = slot
                    np_ += 1
                else:
                    so[ns, 0], so[ns, 1], so[ns, 2] = ox, oy, oz
                    sd[ns, 0], sd[ns, 1], sd[ns, 2] = dx * inv, dy * inv, dz * inv
                    st[ns] = tf
                    sslot[ns] = slot
                    ns += 1
    return np_, ns


@numba.njit(cache=True)
def _reduce(n, rays, pslot, phit, pback, sslot, socc, slot_off, visible, vin, vout, theta, dont_care):
    """Count unblocked rays and inside/outside votes; write θ (n, 8) uint8 and dont_care (n,)."""
    for j in range(pslot.shape[0]):
        s = pslot[j]
        i = s // 8
        if phit[j]:
            if pback[j]:
                vin[i] += 1
            else:
                vout[i] += 1
        else:
            visible[s] += 1
            if slot_off[s]:
                vin[i] += 1
            else:
                vout[i] += 1
    for j in range(sslot.shape[0]):
        if not socc[j]:
            visible[sslot[j]] += 1
    for i in range(n):
        dont_care[i] = vin[i] > vout[i]
        for c in range(8):
            s = i * 8 + c
            if slot_off[s]:
                theta[i, c] = 0
            else:
                theta[i, c] = (visible[s] * 510 + rays) // (2 * rays)  # round(255 · visible / rays)


# ---------------------------------------------------------------------- θ of one slab
def _double_sided_mask(double_sided_tris, n_tris: int) -> np.ndarray:
    if double_sided_tris is None:
        return np.zeros(max(n_tris, 1), bool)
    a = np.asarray(double_sided_tris)
    if a.dtype == bool:
        if a.shape != (n_tris,):
            raise ValueError(f"double_sided_tris: a bool mask must have shape ({n_tris},), got {a.shape}")
        m = a.copy()
    else:
        m = np.zeros(n_tris, bool)
        m[a.astype(np.int64).ravel()] = True
    return m if n_tris else np.zeros(1, bool)


def _prepare(caster, counts, origin, spacing, positions, states, S, rays, jitter, seed):
    S = _check_s(S)
    counts = np.asarray(counts, np.int64).reshape(3)
    P = int(np.prod(counts))
    probes = np.ascontiguousarray(positions, np.float64)
    if probes.shape != (P, 3):
        raise ValueError(f"positions must have shape ({P}, 3), got {probes.shape}")
    st = np.asarray(states).reshape(-1)
    if st.shape != (P,):
        raise ValueError(f"states must have shape ({P},), got {st.shape}")
    rays = int(rays)
    if rays < 1:
        raise ValueError(f"rays must be >= 1, got {rays}")
    jitter = float(jitter)
    if not jitter >= 0:
        raise ValueError(f"jitter must be >= 0, got {jitter}")
    sp = np.asarray(spacing, np.float64).reshape(3)
    live = sp[(counts > 1) & (sp > 0)]
    radius = jitter * float(live.min()) if live.size else 0.0
    key = _mix(_U(int(seed) & 0xFFFFFFFFFFFFFFFF) ^ _SEED_SALT)
    eps = TFAR_EPS * float(caster.scale)
    return S, counts, probes, st == OFF, rays, radius, key, eps


class _Buffers:
    """Ray buffers for up to ``n`` samples of ``rays`` rays per corner, reused across chunks."""

    def __init__(self, n: int, rays: int):
        m, ms = n * 8, n * 8 * (rays - 1)
        self.po, self.pd = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
        self.pt, self.pslot = np.empty(m, np.float32), np.empty(m, np.int64)
        self.so, self.sd = np.empty((ms, 3), np.float32), np.empty((ms, 3), np.float32)
        self.st, self.sslot = np.empty(ms, np.float32), np.empty(ms, np.int64)
        self.visible, self.slot_off = np.empty(m, np.int32), np.empty(m, bool)
        self.vin, self.vout = np.empty(n, np.int32), np.empty(n, np.int32)


def _chunk_rays(buf, g0, n, grid, probes, off, rays, radius, key, eps):
    """Build the rays of samples g0 .. g0 + n − 1 into ``buf``; returns (n_primary, n_secondary)."""
    buf.visible[: n * 8] = 0
    buf.vin[:n] = 0
    buf.vout[:n] = 0
    return _build_rays(g0, n, *grid, probes, off, rays, radius, key, eps,
                       buf.po, buf.pd, buf.pt, buf.pslot, buf.so, buf.sd, buf.st, buf.sslot,
                       buf.visible, buf.vin, buf.vout, buf.slot_off)


def theta_slab(caster, counts, origin, spacing, positions, states, S, z_range, rays=1, jitter=0.05, seed=0,
               double_sided_tris=None):
    """θ and the don't-care mask of the field rows ``z ∈ [z0, z1)`` (MD §3.4 step 1).

    Parameters
    ----------
    caster : workers.raycast.RayCaster
        Built on the scene's triangles ``(T, 3, 3)``; its ``scale`` sets the ray end offset.
    counts : (3,) int
        Probes per axis (nx, ny, nz).
    origin, spacing : (3,) float
        Un-relocated grid: probe (i, j, k) at ``origin + spacing·(i, j, k)``, metres.
    positions : (P, 3) float
        Relocated probe positions, world space, flattened order ``p = i + nx·(j + ny·k)``.
    states : (P,) int
        Probe states (OFF = 0, ACTIVE = 1, SLEEPING = 2); OFF probes get θ = 0.
    S : int
        Samples per cell axis.
    z_range : (z0, z1)
        Field rows to compute, ``0 <= z0 <= z1 <= Z`` (see :func:`field_shape`).
    rays : int
        Occlusion rays per (sample, probe): 1 = binary θ, more = soft (fraction unblocked).
    jitter : float
        Radius of the ball of jittered ray targets around a probe, as a fraction of the smallest
        grid spacing; unused when ``rays = 1``.
    seed : int
        Seed of the jitter hash (the bake's seed).
    double_sided_tris : (T,) bool mask or int indices of triangles, optional
        Triangles of double-sided materials: their back faces do not vote "inside".

    Returns
    -------
    theta : (z1 − z0, Y, X, 8) uint8
        ``round(255·θ_c(x))`` for corner c of the sample's cell (MD eq 2's θ_i(x)).
    dont_care : (z1 − z0, Y, X) bool
        Sample inside geometry (module doc): weight 0 in MD eq 5-6. Its θ is still written.
    stats : dict
        ``rays`` (cast), ``primary_rays`` (intersect), ``secondary_rays`` (occluded),
        ``samples``, ``dont_care`` (count), ``build_s``, ``trace_s``, ``reduce_s`` (seconds).
    """
    S, counts, probes, off, rays, radius, key, eps = _prepare(caster, counts, origin, spacing, positions, states,
                                                               S, rays, jitter, seed)
    Z, Y, X = field_shape(counts, S)
    z0, z1 = _check_range(z_range, Z)
    ds = _double_sided_mask(double_sided_tris, int(caster.triangles.shape[0]))
    n_all = (z1 - z0) * Y * X
    theta = np.zeros((n_all, 8), np.uint8)
    dont_care = np.zeros(n_all, bool)
    stats = dict(rays=0, primary_rays=0, secondary_rays=0, samples=n_all, dont_care=0,
                 build_s=0.0, trace_s=0.0, reduce_s=0.0)
    step = max(1, CHUNK_RAYS // (8 * rays))
    g0 = z0 * Y * X
    grid = _grid_args(counts, origin, spacing, S)
    buf = _Buffers(min(step, n_all), rays)
    for a in range(0, n_all, step):
        n = min(n_all, a + step) - a
        t0 = time.perf_counter()
        k1, k2 = _chunk_rays(buf, g0 + a, n, grid, probes, off, rays, radius, key, eps)
        t1 = time.perf_counter()
        h = caster.intersect(buf.po[:k1], buf.pd[:k1], tfar=buf.pt[:k1])
        phit = h.tri >= 0
        pback = h.backface & ~ds[np.maximum(h.tri, 0)]
        socc = caster.occluded(buf.so[:k2], buf.sd[:k2], tfar=buf.st[:k2]) if k2 else np.zeros(0, bool)
        t2 = time.perf_counter()
        _reduce(n, rays, buf.pslot[:k1], phit, pback, buf.sslot[:k2], socc, buf.slot_off, buf.visible,
                buf.vin, buf.vout, theta[a:a + n], dont_care[a:a + n])
        t3 = time.perf_counter()
        stats["primary_rays"] += int(k1)
        stats["secondary_rays"] += int(k2)
        stats["build_s"] += t1 - t0
        stats["trace_s"] += t2 - t1
        stats["reduce_s"] += t3 - t2
    stats["rays"] = stats["primary_rays"] + stats["secondary_rays"]
    stats["dont_care"] = int(dont_care.sum())
    return theta.reshape(z1 - z0, Y, X, 8), dont_care.reshape(z1 - z0, Y, X), stats
