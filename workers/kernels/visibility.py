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
offset on a one-probe axis clamps to that probe), ``rays`` occlusion rays go from the sample
(rounded to float32, the caster's precision) towards the probe's *relocated* position. With
``rays = 1`` the single ray goes to the exact probe position whatever the jitter. With
``rays > 1`` every ray (ray 0 included) goes to the probe position plus an offset uniform in a
ball of radius ``jitter · min(spacing)`` (min over axes with more than one probe): row
``splitmix64(seed, g, corner, ray) >> 52`` of a table of 4096 such offsets, itself hashed from the
seed. So the result of a sample never depends on how the field is split into slabs or chunks,
nor on the thread count. A ray is blocked when the scene has a hit (either side of any triangle)
with ``t ≤ |target − sample| − ε``, ``ε = max(1e-4·caster.diagonal, 16·caster.quantum)`` (the scene's size, not
its distance from the origin: ``caster.scale`` counted that too, and two-rooms moved 2 km read normalized mask GI
0.74 of its reference with ε 20x larger); a ray with that length ≤ 0 (the sample is at
the target) is unblocked. ``θ = unblocked / rays`` (MD eq 2's θ_i(x)), stored as
``uint8 round(255·θ)`` (exact integer rounding). OFF probes (:data:`workers.kernels.grid.OFF`)
get θ = 0.

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
does (DDGI-P §4.1); double-sided surfaces have no inside. It costs no extra rays (only ray 0 of
each corner is an ``intersect`` instead of an ``occluded``). On zdm2-sauerbraten (16x8x16 grid
over the bounds, S = 8, probes OFF where ``inside_parity`` says so, not relocated) it agrees with
``caster.inside_parity(n_dirs=5)`` on 99.8% of the samples of interior cells and on 95.3% of all
samples: the rest are samples of the border cells whose 8 rays are all unblocked while 4 of the
probes are OFF (probes lying exactly on the scene's bounding planes, which relocation moves):
4 : 4, a tie, kept. Calling a sample inside when it is not is rarer (0.05%).

Work layout
-----------
A slab's samples are processed in chunks of at most ``CHUNK_RAYS`` rays: numba kernels (no GIL,
split over ``caster.threads`` Python threads) write contiguous float32 origins / unit directions
/ tfar arrays, one ``caster.intersect`` (ray 0 of every corner) and one ``caster.occluded``
(the other rays, none towards OFF probes) per chunk, then a numba kernel reduces the hits.

Consumers: stages/visibility (per-slab jobs and the join), stages/masks (eq 5-6).
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext

import numba
import numpy as np

from workers.kernels.grid import OFF, axis_position

__all__ = ["field_shape", "sample_positions", "theta_slab", "slab_ranges", "join_slabs", "TFAR_EPS"]

TFAR_EPS = 1e-4  # rays stop this far (x caster.diagonal) before their target (dimensionless)
TFAR_QUANTA = 16  # ... and at least this many float32 spacings at the scene's largest coordinate (caster.quantum)
CHUNK_RAYS = 1 << 21  # rays built and cast per batch inside theta_slab; bounds memory (~70 MB)
BALL_BITS = 12  # the jitter offsets come from a table of 2^BALL_BITS points uniform in the ball
BALL_SIZE = 1 << BALL_BITS

_U = np.uint64
_GAMMA = _U(0x9E3779B97F4A7C15)
_M1 = _U(0xBF58476D1CE4E5B9)
_M2 = _U(0x94D049BB133111EB)
_SEED_SALT = _U(0x5EED0F7157AB1E5)
_S30, _S27, _S31, _S11 = _U(30), _U(27), _U(31), _U(11)
_BALL_SHIFT = _U(64 - BALL_BITS)
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


def sample_positions(counts, origin, spacing, S, z_range, layers=None) -> np.ndarray:
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
    coordinate is ``origin`` (the probe plane). ``layers``: a rectilinear grid (:mod:`workers.kernels.grid`): the
    same refined index, at the world position :func:`workers.kernels.grid.axis_position` gives it (S samples per
    cell whatever the cell's size).
    """
    S = _check_s(S)
    Z, Y, X = field_shape(counts, S)
    z0, z1 = _check_range(z_range, Z)
    g0, n = z0 * Y * X, (z1 - z0) * Y * X
    out = np.empty((n, 3), np.float64)
    _positions_kernel(g0, n, *_Grid(counts, origin, spacing, S, layers).args, out)
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
@numba.njit(cache=True)
def _mix(x):
    """splitmix64 finalizer (uint64 -> uint64)."""
    x = (x ^ (x >> _S30)) * _M1
    x = (x ^ (x >> _S27)) * _M2
    return x ^ (x >> _S31)


class _Grid:
    """The refined grid as the kernels take it (``args``): per-axis sample coordinates and cells.

    ``args = (X, Y, counts (3,) int64, px (X,), py (Y,), pz (Z,) float64 metres, cx (X,), cy (Y,),
    cz (Z,) int64 cells)``: sample (x, y, z) is at ``(px[x], py[y], pz[z])`` in cell
    ``(cx[x], cy[y], cz[z])``.
    """

    def __init__(self, counts, origin, spacing, S, layers=None):
        S = _check_s(S)
        self.shape = Z, Y, X = field_shape(counts, S)
        counts = np.asarray(counts, np.int64).reshape(3).copy()
        origin = np.asarray(origin, np.float64).reshape(3)
        spacing = np.asarray(spacing, np.float64).reshape(3)
        pos, cell = [], []
        for axis, n in enumerate((X, Y, Z)):
            f = np.arange(n, dtype=np.int64)
            c = f // S
            if counts[axis] == 1:  # one-probe axis: one cell of zero extent, samples in the probe plane
                pos.append(np.full(n, origin[axis]))
                cell.append(np.zeros(n, np.int64))
            else:
                g = c + (f - c * S + 0.5) / S
                pos.append(origin[axis] + spacing[axis] * g if layers is None else axis_position(g, layers[axis]))
                cell.append(c)
        self.args = (X, Y, counts, *pos, *cell)


@numba.njit(cache=True)
def _coords(g, X, Y):
    """Field coordinates (x, y, z) of global sample g = x + X·(y + Y·z)."""
    return g % X, (g // X) % Y, g // (X * Y)


@numba.njit(cache=True)
def _advance(x, y, z, X, Y):
    """The coordinates of sample g + 1 given those of g (C order, x fastest)."""
    x += 1
    if x == X:
        x = 0
        y += 1
        if y == Y:
            y = 0
            z += 1
    return x, y, z


@numba.njit(cache=True)
def _corner(ci, cj, ck, c, counts):
    """Flattened index of corner c (offset (c & 1, c >> 1 & 1, c >> 2 & 1), clamped) of cell (ci, cj, ck)."""
    i = min(ci + (c & 1), counts[0] - 1)
    j = min(cj + ((c >> 1) & 1), counts[1] - 1)
    k = min(ck + ((c >> 2) & 1), counts[2] - 1)
    return i + counts[0] * (j + counts[1] * k)


@numba.njit(cache=True, nogil=True)
def _positions_kernel(g0, n, X, Y, counts, px, py, pz, cx, cy, cz, out):
    x, y, z = _coords(g0, X, Y)
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2] = px[x], py[y], pz[z]
        x, y, z = _advance(x, y, z, X, Y)


@numba.njit(cache=True, nogil=True)
def _secondary_counts(i0, i1, g0, X, Y, counts, px, py, pz, cx, cy, cz, off, rays, nsec):
    """nsec[i] = (rays − 1) · (number of non-OFF corners of sample g0 + i's cell)."""
    x, y, z = _coords(g0 + i0, X, Y)
    for i in range(i0, i1):
        m = 0
        for c in range(8):
            if not off[_corner(cx[x], cy[y], cz[z], c, counts)]:
                m += rays - 1
        nsec[i] = m
        x, y, z = _advance(x, y, z, X, Y)


@numba.njit(cache=True)
def _ball_kernel(key, radius, out):
    """out (M, 3): points uniform in the ball of ``radius`` around 0, point m from hashes of (key, m)."""
    for m in range(out.shape[0]):
        ctr = _U(m) * _U(3)
        u0 = float(_mix(key + (ctr + _U(1)) * _GAMMA) >> _S11) * _INV53
        u1 = float(_mix(key + (ctr + _U(2)) * _GAMMA) >> _S11) * _INV53
        u2 = float(_mix(key + (ctr + _U(3)) * _GAMMA) >> _S11) * _INV53
        cz = 2.0 * u0 - 1.0  # uniform direction (Archimedes) at a radius ∝ ∛u (uniform volume)
        sz = math.sqrt(max(0.0, 1.0 - cz * cz))
        phi = 2.0 * math.pi * u1
        rr = radius * u2 ** (1.0 / 3.0)
        out[m, 0], out[m, 1], out[m, 2] = rr * sz * math.cos(phi), rr * sz * math.sin(phi), rr * cz


def _ball(key, radius: float, rays: int) -> np.ndarray:
    """The jitter offsets table (BALL_SIZE, 3) float64, metres; empty when there is no jitter."""
    if rays == 1 or radius <= 0.0:
        return np.zeros((0, 3), np.float64)
    out = np.empty((BALL_SIZE, 3), np.float64)
    _ball_kernel(key, float(radius), out)
    return out


@numba.njit(cache=True)
def _ball_index(key, g, c, r, rays):
    """Row of the jitter table for ray r of corner c of sample g: the top bits of a splitmix64 hash."""
    h = _mix(key ^ ((((_U(g) * _U(8) + _U(c)) * _U(rays) + _U(r)) + _U(1)) * _GAMMA))
    return np.int64(h >> _BALL_SHIFT)


@numba.njit(cache=True)
def _segment(sx, sy, sz, tx, ty, tz, eps):
    """Unit direction and tfar = distance − eps of the ray from (sx, sy, sz) to (tx, ty, tz).

    A degenerate ray (tfar <= 0: the sample sits at the target, nothing can block) gives
    direction +z and tfar 0; it must be counted unblocked whatever the caster says.
    """
    dx, dy, dz = tx - sx, ty - sy, tz - sz
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    tf = dist - eps
    if tf <= 0.0:
        return 0.0, 0.0, 1.0, 0.0
    inv = 1.0 / dist
    return dx * inv, dy * inv, dz * inv, tf


@numba.njit(cache=True, nogil=True)
def _build_rays(i0, i1, g0, X, Y, counts, px, py, pz, cx, cy, cz, probes, off, soff, rays, ball, key, eps,
                po, pd, pt, pdeg, so, sd, st, sdeg, cage_off):
    """Fill the ray buffers of chunk samples i0 .. i1 − 1 (global index g0 + i); runs without the GIL.

    Primary rays (ray 0 of every corner, cast with ``intersect``): ray ``i·8 + c``. Secondary
    rays (rays 1 .. rays − 1 of non-OFF corners, cast with ``occluded``): sample i's start at
    ``soff[i]``, corner-major. probes (P, 3) f64 relocated positions, off (P,) bool. pdeg / sdeg
    flag degenerate (unblocked by definition) rays; cage_off (n, 8) gets the corners' OFF flags.
    Every sample writes only its own rays, so any split of [0, n) over threads gives the same
    buffers.
    """
    jit = ball.shape[0] > 0
    x, y, z = _coords(g0 + i0, X, Y)
    for i in range(i0, i1):
        g = g0 + i
        sx, sy, sz = px[x], py[y], pz[z]
        ox, oy, oz = np.float32(sx), np.float32(sy), np.float32(sz)
        k = soff[i]
        for c in range(8):
            p = _corner(cx[x], cy[y], cz[z], c, counts)
            is_off = off[p]
            cage_off[i, c] = is_off
            for r in range(rays if not is_off else 1):
                tx, ty, tz = probes[p, 0], probes[p, 1], probes[p, 2]
                if jit:  # a point uniform in the jitter ball, chosen by a hash of (seed, g, c, r)
                    b = _ball_index(key, g, c, r, rays)
                    tx += ball[b, 0]
                    ty += ball[b, 1]
                    tz += ball[b, 2]
                ux, uy, uz, tf = _segment(sx, sy, sz, tx, ty, tz, eps)
                if r == 0:
                    j = i * 8 + c
                    po[j, 0], po[j, 1], po[j, 2] = ox, oy, oz
                    pd[j, 0], pd[j, 1], pd[j, 2] = ux, uy, uz
                    pt[j] = tf
                    pdeg[j] = tf <= 0.0
                else:
                    so[k, 0], so[k, 1], so[k, 2] = ox, oy, oz
                    sd[k, 0], sd[k, 1], sd[k, 2] = ux, uy, uz
                    st[k] = tf
                    sdeg[k] = tf <= 0.0
                    k += 1
        x, y, z = _advance(x, y, z, X, Y)


@numba.njit(cache=True, nogil=True)
def _reduce(i0, i1, rays, cage_off, soff, pdeg, ptri, pback, double_sided, sdeg, socc, theta, dont_care):
    """θ (n, 8) uint8 = round(255 · unblocked / rays) (0 for OFF), and the inside vote (module doc).

    ptri / pback: the primary rays' hit triangle (−1 on a miss) and back-face flag;
    double_sided (T,) bool; socc: the secondary rays' occlusion.
    """
    for i in range(i0, i1):
        vin, vout = 0, 0
        k = soff[i]
        for c in range(8):
            j = i * 8 + c
            free = pdeg[j] or ptri[j] < 0
            if free:
                if cage_off[i, c]:
                    vin += 1
                else:
                    vout += 1
            elif pback[j] and not double_sided[ptri[j]]:
                vin += 1                            # a single-sided back face seen first: inside (DDGI-P §4.1)
            else:
                vout += 1
            if cage_off[i, c]:
                theta[i, c] = 0
                continue
            vis = 1 if free else 0
            for r in range(1, rays):
                if sdeg[k] or not socc[k]:
                    vis += 1
                k += 1
            theta[i, c] = (vis * 510 + rays) // (2 * rays)  # MD eq 2's θ_i(x) = vis / rays, as round(255 θ), exact
        dont_care[i] = vin > vout                   # inside: weight 0 in MD eq 5-6 (a tie keeps the sample)


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
    """Validated inputs: (S, counts, probes (P, 3) f64, off (P,) bool, rays, jitter table, key, eps)."""
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
    key = _U(_mix(_U(int(seed) & 0xFFFFFFFFFFFFFFFF) ^ _SEED_SALT))  # numba returns a Python int
    eps = max(TFAR_EPS * float(caster.diagonal), TFAR_QUANTA * float(caster.quantum))
    return S, counts, probes, st == OFF, rays, _ball(key, radius, rays), key, eps


class _Buffers:
    """Ray buffers for chunks of up to ``n`` samples, reused across chunks (secondary grown on demand)."""

    def __init__(self, n: int, rays: int):
        m = n * 8
        self.po, self.pd = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
        self.pt, self.pdeg = np.empty(m, np.float32), np.empty(m, bool)
        self.cage_off = np.empty((n, 8), bool)
        self.nsec, self.soff = np.zeros(n, np.int64), np.zeros(n, np.int64)
        self.secondary(0)

    def secondary(self, ms: int):
        if not hasattr(self, "st") or self.st.shape[0] < ms:
            self.so, self.sd = np.empty((ms, 3), np.float32), np.empty((ms, 3), np.float32)
            self.st, self.sdeg = np.empty(ms, np.float32), np.empty(ms, bool)


def _split(pool, fn, n: int, *args) -> None:
    """Run the GIL-free kernel ``fn(i0, i1, *args)`` over [0, n), one contiguous part per thread.

    pool : ``(ThreadPoolExecutor, threads)`` or None (run in the calling thread). Each kernel
    writes only the rows of its own part, so the result does not depend on the split.
    """
    if pool is None or n < 1024:
        fn(0, n, *args)
        return
    executor, k = pool
    cuts = [n * t // k for t in range(k + 1)]
    for f in [executor.submit(fn, cuts[t], cuts[t + 1], *args) for t in range(k)]:
        f.result()


def _chunk_rays(buf, g0, n, grid, probes, off, rays, ball, key, eps, pool=None) -> int:
    """Build the rays of samples g0 .. g0 + n − 1 into ``buf`` (8n primary); returns the secondary count."""
    soff = buf.soff[:n]
    ms = 0
    if rays > 1:
        _split(pool, _secondary_counts, n, g0, *grid, off, rays, buf.nsec)
        np.cumsum(buf.nsec[:n], out=soff)
        ms = int(soff[-1]) if n else 0
        soff -= buf.nsec[:n]  # exclusive prefix sum
        buf.secondary(ms)
    _split(pool, _build_rays, n, g0, *grid, probes, off, soff, rays, ball, key, eps,
           buf.po, buf.pd, buf.pt, buf.pdeg, buf.so, buf.sd, buf.st, buf.sdeg, buf.cage_off)
    return ms


def theta_slab(caster, counts, origin, spacing, positions, states, S, z_range, rays=1, jitter=0.05, seed=0,
               double_sided_tris=None, layers=None):
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
    layers : None, or per axis the layer coordinates of a rectilinear grid (:mod:`workers.kernels.grid`).

    Returns
    -------
    theta : (z1 − z0, Y, X, 8) uint8
        ``round(255·θ_c(x))`` for corner c of the sample's cell (MD eq 2's θ_i(x)).
    dont_care : (z1 − z0, Y, X) bool
        Sample inside geometry (module doc): weight 0 in MD eq 5-6. Its θ is still written.
    stats : dict
        ``rays`` (cast), ``primary_rays`` (intersect), ``secondary_rays`` (occluded),
        ``samples``, ``dont_care`` (count), ``build_s``, ``trace_s`` (= ``ray_seconds``: time in the
        caster), ``reduce_s`` (seconds).
    """
    S, counts, probes, off, rays, ball, key, eps = _prepare(caster, counts, origin, spacing, positions, states,
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
    grid = _Grid(counts, origin, spacing, S, layers).args
    buf = _Buffers(min(step, n_all), rays)
    threads = max(1, int(getattr(caster, "threads", 1)))
    with ThreadPoolExecutor(max_workers=threads) if threads > 1 else nullcontext() as executor:
        pool = (executor, threads) if executor is not None else None
        _slab_loop(caster, pool, buf, n_all, step, g0, grid, probes, off, rays, ball, key, eps, ds,
                   theta, dont_care, stats)
    stats["rays"] = stats["primary_rays"] + stats["secondary_rays"]
    stats["ray_seconds"] = stats["trace_s"]
    stats["dont_care"] = int(dont_care.sum())
    return theta.reshape(z1 - z0, Y, X, 8), dont_care.reshape(z1 - z0, Y, X), stats


def _slab_loop(caster, pool, buf, n_all, step, g0, grid, probes, off, rays, ball, key, eps, ds,
               theta, dont_care, stats):
    """Build, cast and reduce the slab's samples chunk by chunk (at most CHUNK_RAYS rays each)."""
    for a in range(0, n_all, step):
        n = min(n_all, a + step) - a
        t0 = time.perf_counter()
        ms = _chunk_rays(buf, g0 + a, n, grid, probes, off, rays, ball, key, eps, pool)
        t1 = time.perf_counter()
        h = caster.intersect(buf.po[: 8 * n], buf.pd[: 8 * n], tfar=buf.pt[: 8 * n])
        socc = caster.occluded(buf.so[:ms], buf.sd[:ms], tfar=buf.st[:ms]) if ms else np.zeros(0, bool)
        t2 = time.perf_counter()
        _split(pool, _reduce, n, rays, buf.cage_off, buf.soff, buf.pdeg, h.tri, h.backface, ds, buf.sdeg, socc,
               theta[a:a + n], dont_care[a:a + n])
        t3 = time.perf_counter()
        stats["primary_rays"] += 8 * n
        stats["secondary_rays"] += ms
        stats["build_s"] += t1 - t0
        stats["trace_s"] += t2 - t1
        stats["reduce_s"] += t3 - t2
