"""DDGI irradiance queries: the 8-probe, visibility-weighted blend (DDGI-P §2.2, §4.1; DDGI-I §3.4.1).

This is the Python reference of the ``ddgi`` runtime mode (DESIGN.md "Runtime shading"; the GLSL in
``proto/glsl`` must match it) and what the light stage (DESIGN.md stage 2) uses for the indirect
term at probe-ray hits.

For a shading point x with unit normal n and unit view direction ω_o (from x toward the viewer;
for a probe ray's hit, minus the ray direction), :func:`sample_irradiance` returns::

    E(x, n) = Σ_i w_i · E_i(n) / Σ_i w_i        over the non-OFF probes i of the cage

where ``E_i(n)`` is probe i's irradiance map sampled bilinearly (with its octahedral border) in the
direction n. The weights follow RTXGI's ``DDGIGetVolumeIrradiance`` (``rtxgi-sdk/shaders/ddgi/
Irradiance.hlsl``, the DDGI reference implementation), step by step:

1. self-shadow bias (DDGI-P §4.1 eq 2): ``x_b = x + (0.2·n + 0.8·ω_o) · (0.75·D) · B``, D the minimum
   axial probe spacing (over axes with spacing > 0), B = ``self_shadow_bias`` (0.3 by default);
2. the cage: base cell and trilinear fractions α of ``x_b`` on the *un-relocated* grid
   (:func:`workers.kernels.grid.cell_coords`), corners in :func:`~workers.kernels.grid.cage_indices`
   order (corner c has offset ``(c & 1, c >> 1 & 1, c >> 2 & 1)``); OFF probes are skipped;
3. per probe at its relocated position p_i:

   - wrap-shading backface weight: ``w = ((dot(normalize(p_i - x), n) + 1) / 2)² + 0.2``
     (from the *unbiased* point, as RTXGI);
   - Chebyshev visibility (variance shadow map test): depth moments ``(μ, μ₂)`` sampled bilinearly
     in the direction ``x_b - p_i`` (probe -> biased point); with ``r = |p_i - x_b|``, if ``r > μ``:
     ``σ² = |μ² - μ₂|``, ``c = (σ² / (σ² + (r - μ)²))³``, else ``c = 1``; ``w *= max(0.05, c)``;
   - ``w = max(1e-6, w)``; log-perception crush: if ``w < 0.2``: ``w *= w² / 0.2²``;
   - trilinear last: ``w *= Π_axes max(0.001, lerp(1 - α, α, offset))``.

Differences from RTXGI, by choice:

- We blend *linear* irradiance as stored in the maps. RTXGI stores gamma-encoded irradiance, blends
  ``pow(E, γ/2)`` (a gamma-2 "sRGB-like" blend), squares the result and multiplies it by 2π (its maps
  hold a differently normalized quantity). Here the result is in the maps' own units with no scale
  factor: uniform maps give back exactly that value.
- The cage of points outside the grid uses :func:`grid.cell_coords`'s clamping (base cell in
  [0, n - 2], α clamped to [0, 1]); RTXGI clamps the base probe to [0, n - 1]. Inside the grid they
  agree.
- No volume rotation, scrolling or multi-volume blending (one static axis-aligned volume).
- Degenerate inputs: a point exactly at a probe uses ``dot = 0`` for the wrap term and ``c = 1``;
  rows whose point, normal or view direction is non-finite, or whose normal is zero, return 0.

Octahedral conventions are :mod:`workers.kernels.octahedral`'s (+Z fold, maps indexed
``[row = v, col = u]``, 1-texel border); :func:`octahedral_bilinear` is a compiled, per-row-probe
version of :func:`workers.kernels.octahedral.bilinear_sample` with identical arithmetic.

Consumers: stages/light (indirect at ray hits), stages/evaluate (reference for the ``ddgi`` GLSL
mode). Inverse: none.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from proto.gi_modes import BIAS_SPACING_FRACTION, SELF_SHADOW_BIAS
from workers.kernels.grid import OFF, check_layers, layers_table

__all__ = ["sample_irradiance", "cage_probes", "octahedral_bilinear", "bias_scale", "NORMAL_BIAS", "VIEW_BIAS"]

NORMAL_BIAS = 0.2  # weight of n in the self-shadow bias direction (DDGI-P eq 2)
VIEW_BIAS = 0.8  # weight of ω_o (DDGI-P eq 2)
_WRAP_OFFSET = 0.2  # wrap shading floor (RTXGI)
_CHEBYSHEV_FLOOR = 0.05  # weight *= max(0.05, chebyshev) (RTXGI)
_MIN_WEIGHT = 1e-6  # weight = max(1e-6, weight) (RTXGI)
_CRUSH_THRESHOLD = 0.2  # log-perception crush below this weight (RTXGI)
_TRILINEAR_FLOOR = 0.001  # max(0.001, lerp) per axis (RTXGI)


# ------------------------------------------------------------------------------------ octahedral
@njit(cache=True, inline="always")
def _oct_texel(dx, dy, dz, n):
    """Bilinear footprint of direction (dx, dy, dz) in a bordered n x n map.

    Same arithmetic as ``octahedral.oct_encode`` + ``octahedral._bilinear_sample`` (float64):
    returns (row0, col0, frac_row, frac_col) with row0, col0 in [0, n] (bordered indices).
    """
    l1 = abs(dx) + abs(dy) + abs(dz)
    px = dx / l1
    py = dy / l1
    if dz < 0.0:  # lower hemisphere: fold the corners out (Cigolle et al. 2014)
        ux = (1.0 - abs(py)) * (1.0 if px >= 0.0 else -1.0)
        uy = (1.0 - abs(px)) * (1.0 if py >= 0.0 else -1.0)
    else:
        ux = px
        uy = py
    half_n = 0.5 * n
    sx = (ux + 1.0) * half_n - 0.5 + 1.0  # continuous texel index in the bordered map
    sy = (uy + 1.0) * half_n - 0.5 + 1.0
    cx = math.floor(sx)
    cy = math.floor(sy)
    cx = min(max(cx, 0.0), float(n))
    cy = min(max(cy, 0.0), float(n))
    return int(cy), int(cx), sy - cy, sx - cx


@njit(cache=True, nogil=True)
def _octahedral_bilinear_kernel(maps, probe, dirs, out):
    n = maps.shape[1] - 2
    C = maps.shape[3]
    for i in range(dirs.shape[0]):
        p = probe[i]
        r0, c0, fr, fc = _oct_texel(float(dirs[i, 0]), float(dirs[i, 1]), float(dirs[i, 2]), n)
        for ch in range(C):
            top = float(maps[p, r0, c0, ch]) * (1.0 - fc) + float(maps[p, r0, c0 + 1, ch]) * fc
            bottom = float(maps[p, r0 + 1, c0, ch]) * (1.0 - fc) + float(maps[p, r0 + 1, c0 + 1, ch]) * fc
            out[i, ch] = top * (1.0 - fr) + bottom * fr


def octahedral_bilinear(maps_with_border, probe, dirs) -> np.ndarray:
    """Bilinear lookup of bordered octahedral maps, one (probe, direction) pair per row.

    Row i equals ``octahedral.bilinear_sample(maps_with_border[probe[i]], dirs[i])`` exactly (same
    float64 arithmetic, compiled with numba).

    Parameters
    ----------
    maps_with_border : (P, n + 2, n + 2, C) float
        Per-probe maps from :func:`workers.kernels.octahedral.add_border`.
    probe : (N,) int
        Probe index per row, in [0, P).
    dirs : (N, 3) float
        Query directions, world space, finite and non-zero (need not be unit).

    Returns
    -------
    values : (N, C) float64 (float32 for float32 maps, rounded once at the end)
    """
    m = np.asarray(maps_with_border)
    if m.ndim != 4 or m.shape[1] != m.shape[2] or m.shape[1] < 3:
        raise ValueError(f"octahedral_bilinear: maps must have shape (P, n + 2, n + 2, C) with n >= 1, got {m.shape}")
    if not np.issubdtype(m.dtype, np.floating):
        m = m.astype(np.float64)
    m = np.ascontiguousarray(m)
    p = np.ascontiguousarray(np.asarray(probe).astype(np.int64, copy=False).ravel())
    d = np.ascontiguousarray(np.asarray(dirs, dtype=np.float64))
    if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] != p.shape[0]:
        raise ValueError(f"octahedral_bilinear: dirs must be ({p.shape[0]}, 3), got {d.shape}")
    if p.size and (p.min() < 0 or p.max() >= m.shape[0]):
        raise ValueError(f"octahedral_bilinear: probe indices must lie in [0, {m.shape[0]})")
    l1 = np.abs(d).sum(axis=1)
    if np.any(~np.isfinite(l1) | (l1 == 0)):
        raise ValueError("octahedral_bilinear: dirs must be finite and non-zero")
    out = np.empty((d.shape[0], m.shape[3]), np.float64)
    _octahedral_bilinear_kernel(m, p, d, out)
    return out.astype(m.dtype) if m.dtype != np.float64 else out


# ------------------------------------------------------------------------------------ the sampler
def bias_scale(spacing, self_shadow_bias: float = SELF_SHADOW_BIAS) -> float:
    """The scalar ``0.75 · D · B`` of DDGI-P eq 2 (metres): D = min spacing over axes with spacing > 0; 0.75 and B's
    default are ``proto/gi_modes.json``'s (one source with the viewer)."""
    s = np.asarray(spacing, np.float64)
    pos = s[s > 0]
    d = float(pos.min()) if pos.size else 0.0
    return BIAS_SPACING_FRACTION * d * float(self_shadow_bias)  # DDGI-P eq 2


@njit(cache=True, nogil=True)
def grid_index(x, a, counts, origin, spacing, layers):
    """Continuous probe index of coordinate x along axis a (:func:`workers.kernels.grid.grid_coord`): uniform when
    ``layers`` (3, W) is empty (W = 0), else the rectilinear layer coordinate (binary search of row a)."""
    n = counts[a]
    if layers.shape[1] == 0:
        return (x - origin[a]) / spacing[a] if spacing[a] > 0.0 else 0.0
    if n < 2:
        return 0.0
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if layers[a, mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo + (x - layers[a, lo]) / (layers[a, lo + 1] - layers[a, lo])


@njit(cache=True, nogil=True)
def point_weights(i, points, normals, views, counts, origin, spacing, layers, bias, probe_pos, states, depth, visible,
                   n_irr, w8):
    """The DDGI weights of point i's 8 cage corners (module doc steps 1-3), unnormalized, into ``w8`` (8,) float64:
    0 for a skipped corner (OFF, or not ``visible``), > 0 otherwise. Returns ``(ok, q0, ir0, ic0, ifr, ifc)``:
    ``ok`` False for a row with non-finite inputs or a zero normal; ``q0`` the cage's base probe (corner c is
    ``min(base + offset(c), counts - 1)`` per axis); the irradiance footprint of the normal (:func:`_oct_texel`)."""
    x0 = float(points[i, 0])
    x1 = float(points[i, 1])
    x2 = float(points[i, 2])
    n0 = float(normals[i, 0])
    n1 = float(normals[i, 1])
    n2 = float(normals[i, 2])
    v0 = float(views[i, 0])
    v1 = float(views[i, 1])
    v2 = float(views[i, 2])
    nx = counts[0]
    ny = counts[1]
    n_dep = depth.shape[1] - 2
    # self-shadow bias, DDGI-P eq 2: x_b = x + (n·0.2 + ω_o·0.8)·(0.75·D)·B
    bp0 = x0 + (n0 * NORMAL_BIAS + v0 * VIEW_BIAS) * bias
    bp1 = x1 + (n1 * NORMAL_BIAS + v1 * VIEW_BIAS) * bias
    bp2 = x2 + (n2 * NORMAL_BIAS + v2 * VIEW_BIAS) * bias
    nl1 = abs(n0) + abs(n1) + abs(n2)
    if not (math.isfinite(bp0) and math.isfinite(bp1) and math.isfinite(bp2) and math.isfinite(nl1) and nl1 > 0.0):
        return False, 0, 0, 0, 0.0, 0.0
    # cage of the biased point on the un-relocated grid (grid.cell_coords)
    base0 = base1 = base2 = 0
    al0 = al1 = al2 = 0.0
    for a in range(3):
        bpa = bp0 if a == 0 else (bp1 if a == 1 else bp2)
        g = grid_index(bpa, a, counts, origin, spacing, layers)
        hi = max(counts[a] - 2, 0)
        b = min(max(math.floor(g), 0.0), float(hi))
        al = min(max(g - b, 0.0), 1.0)
        al = al if counts[a] > 1 else 0.0
        if a == 0:
            base0, al0 = int(b), al
        elif a == 1:
            base1, al1 = int(b), al
        else:
            base2, al2 = int(b), al
    # irradiance footprint in the direction of the normal (same for all 8 probes)
    ir0, ic0, ifr, ifc = _oct_texel(n0, n1, n2, n_irr)
    for c in range(8):
        w8[c] = 0.0
        o0 = c & 1
        o1 = (c >> 1) & 1
        o2 = (c >> 2) & 1
        gi = min(base0 + o0, counts[0] - 1)
        gj = min(base1 + o1, counts[1] - 1)
        gk = min(base2 + o2, counts[2] - 1)
        q = gi + nx * (gj + ny * gk)
        if states[q] == OFF:  # never used (a numba compile-time constant)
            continue
        if visible.shape[0] and visible[i, c] == 0:  # ray-traced visibility: the probe is occluded
            continue
        p0 = probe_pos[q, 0]
        p1 = probe_pos[q, 1]
        p2 = probe_pos[q, 2]
        # smooth backface weight, wrap shading (DDGI-I §3.4.1), from the unbiased point (RTXGI)
        t0 = p0 - x0
        t1 = p1 - x1
        t2 = p2 - x2
        dl = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        cosw = (t0 * n0 + t1 * n1 + t2 * n2) / dl if dl > 0.0 else 0.0
        wrap = (cosw + 1.0) * 0.5
        w = wrap * wrap + _WRAP_OFFSET
        # Chebyshev moment visibility (DDGI-I §3.4.1; DDGI-P §2.2), probe -> biased point (DDGI-P §4.1)
        b0 = bp0 - p0
        b1 = bp1 - p1
        b2 = bp2 - p2
        r = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        cheb = 1.0
        if r > 0.0:
            dr0, dc0, dfr, dfc = _oct_texel(b0, b1, b2, n_dep)
            top = float(depth[q, dr0, dc0, 0]) * (1.0 - dfc) + float(depth[q, dr0, dc0 + 1, 0]) * dfc
            bot = float(depth[q, dr0 + 1, dc0, 0]) * (1.0 - dfc) + float(depth[q, dr0 + 1, dc0 + 1, 0]) * dfc
            mean = top * (1.0 - dfr) + bot * dfr
            top = float(depth[q, dr0, dc0, 1]) * (1.0 - dfc) + float(depth[q, dr0, dc0 + 1, 1]) * dfc
            bot = float(depth[q, dr0 + 1, dc0, 1]) * (1.0 - dfc) + float(depth[q, dr0 + 1, dc0 + 1, 1]) * dfc
            mean2 = top * (1.0 - dfr) + bot * dfr
            if r > mean:  # occluded side of the mean: one-sided Chebyshev bound, cubed
                variance = abs(mean * mean - mean2)
                dv = r - mean
                cheb = variance / (variance + dv * dv)
                cheb = cheb * cheb * cheb
        w *= max(_CHEBYSHEV_FLOOR, cheb)
        w = max(_MIN_WEIGHT, w)
        if w < _CRUSH_THRESHOLD:  # log perception weight (DDGI-I §3.4.1): crush, continuous at the threshold
            w *= w * w * (1.0 / (_CRUSH_THRESHOLD * _CRUSH_THRESHOLD))
        # trilinear weight last (DDGI-I §3.4.1; RTXGI's order)
        tw = max(_TRILINEAR_FLOOR, al0 if o0 == 1 else 1.0 - al0)
        tw *= max(_TRILINEAR_FLOOR, al1 if o1 == 1 else 1.0 - al1)
        tw *= max(_TRILINEAR_FLOOR, al2 if o2 == 1 else 1.0 - al2)
        w8[c] = w * tw                      # > 0: at least 1e-6 crushed (2.5e-17) times 1e-9
    return True, base0 + nx * (base1 + ny * base2), ir0, ic0, ifr, ifc


@njit(cache=True, nogil=True)
def _sample_irradiance_kernel(points, normals, views, counts, origin, spacing, layers, bias, probe_pos, states, irr,
                              depth, visible, out):
    n_irr = irr.shape[1] - 2
    nx = counts[0]
    ny = counts[1]
    w8 = np.empty(8, np.float64)
    acc = np.empty(3, np.float64)
    for i in range(points.shape[0]):
        ok, q0, ir0, ic0, ifr, ifc = point_weights(i, points, normals, views, counts, origin, spacing, layers, bias,
                                                     probe_pos, states, depth, visible, n_irr, w8)
        acc[0] = 0.0
        acc[1] = 0.0
        acc[2] = 0.0
        wsum = 0.0
        for c in range(8 if ok else 0):
            w = w8[c]
            if w == 0.0:  # OFF or occluded
                continue
            gi = min(q0 % nx + (c & 1), counts[0] - 1)
            gj = min((q0 // nx) % ny + ((c >> 1) & 1), counts[1] - 1)
            gk = min(q0 // (nx * ny) + ((c >> 2) & 1), counts[2] - 1)
            q = gi + nx * (gj + ny * gk)
            for ch in range(3):
                top = float(irr[q, ir0, ic0, ch]) * (1.0 - ifc) + float(irr[q, ir0, ic0 + 1, ch]) * ifc
                bot = float(irr[q, ir0 + 1, ic0, ch]) * (1.0 - ifc) + float(irr[q, ir0 + 1, ic0 + 1, ch]) * ifc
                acc[ch] += w * (top * (1.0 - ifr) + bot * ifr)
            wsum += w
        if wsum > 0.0:
            out[i, 0] = acc[0] / wsum
            out[i, 1] = acc[1] / wsum
            out[i, 2] = acc[2] / wsum
        else:  # every cage probe is OFF, or the row's inputs are not finite
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0


def _float_rows(a, name: str, n: int | None = None) -> np.ndarray:
    a = np.asarray(a)
    if not np.issubdtype(a.dtype, np.floating) or a.dtype.itemsize < 4:
        a = a.astype(np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and a.shape[0] != n):
        raise ValueError(f"sample_irradiance: {name} must have shape ({'N' if n is None else n}, 3), got {a.shape}")
    return a


def sample_irradiance(points, normals, view_dirs, counts, origin, spacing, probe_positions, states, irradiance,
                      depth, self_shadow_bias: float = SELF_SHADOW_BIAS, visible=None, layers=None) -> np.ndarray:
    """DDGI probe irradiance at surface points (DDGI-P §2.2 probe query, eq 2 bias; see module doc).

    Parameters
    ----------
    points : (N, 3) float
        Shading points, world space, metres.
    normals : (N, 3) float
        Unit surface normals (the irradiance lookup direction and the wrap-shading normal).
    view_dirs : (N, 3) float
        Unit directions from each point toward the viewer (ω_o of DDGI-P eq 2); for a probe ray's
        hit, ``-ray_dir``.
    counts : (3,) int
        Probe counts (nx, ny, nz) of the grid (:mod:`workers.kernels.grid`).
    origin, spacing : (3,) float
        Grid origin and spacing, metres; un-relocated probe (i, j, k) at ``origin + spacing·(i, j, k)``.
    probe_positions : (P, 3) float
        Relocated probe positions, world space, flattened order ``p = i + nx·(j + ny·k)``.
    states : (P,) uint8
        Probe states (grid.OFF / ACTIVE / SLEEPING); OFF probes never contribute.
    irradiance : (P, n + 2, n + 2, 3) float
        Bordered octahedral irradiance maps (linear; any units, returned as is).
    depth : (P, m + 2, m + 2, 2) float
        Bordered octahedral depth moments: mean distance (m) and mean squared distance (m²).
    self_shadow_bias : float
        B of DDGI-P eq 2 (0.3 by default, the paper's value).
    visible : (N, 8) bool or uint8, optional
        Ray-traced visibility of each cage corner from the biased point (:func:`cage_probes` gives the
        corners' probes): a corner with 0 is skipped like an OFF probe. The offline light stage uses
        it on top of the Chebyshev test, which alone lets light leak through thin walls when the
        visible side's probes have small trilinear weights (normalization amplifies the 5% floor).
    layers : None, or per axis the layer coordinates of a rectilinear grid (:mod:`workers.kernels.grid`): the
        cage and trilinear weights come from the layer coordinate of the biased point.

    Returns
    -------
    E : (N, 3) float32
        Weighted mean of the cage probes' irradiance, in the maps' units; 0 where all 8 cage probes
        are OFF or the row's inputs are non-finite.

    Notes
    -----
    One numba loop over points (``parallel=False``, ``nogil=True``, so callers may thread over chunks);
    float64 arithmetic. Specialized for float32 or float64 inputs (points/normals/views share one
    dtype, the two map arrays another); the compiled code is cached on disk.
    """
    pts, nrm, view, cnt, org, spc, lay, bias, pos, st, dep, vis = sampler_inputs(
        points, normals, view_dirs, counts, origin, spacing, probe_positions, states, depth, self_shadow_bias, visible,
        layers)
    P, n = pos.shape[0], pts.shape[0]
    irr = np.asarray(irradiance)
    if irr.ndim != 4 or irr.shape[0] != P or irr.shape[1] != irr.shape[2] or irr.shape[1] < 3 or irr.shape[3] != 3:
        raise ValueError(f"sample_irradiance: irradiance must be ({P}, n + 2, n + 2, 3), got {irr.shape}")
    mdt = np.float32 if irr.dtype == np.float32 and dep.dtype == np.float32 else np.float64
    irr = np.ascontiguousarray(irr, dtype=mdt)
    dep = np.ascontiguousarray(dep, dtype=mdt)
    out = np.empty((n, 3), np.float32)
    if n:
        _sample_irradiance_kernel(pts, nrm, view, cnt, org, spc, lay, bias, pos, st, irr, dep, vis, out)
    return out


def sampler_inputs(points, normals, view_dirs, counts, origin, spacing, probe_positions, states, depth,
                   self_shadow_bias, visible, layers=None):
    """:func:`sample_irradiance`'s inputs checked and laid out for its kernels (also
    :func:`workers.kernels.gather.sampler_weights`'): ``(points, normals, views, counts, origin, spacing, layers
    ((3, max(counts)) float64 table of a rectilinear grid, :func:`workers.kernels.grid.layers_table`; (3, 0) for a
    uniform one), bias
    (0.75·D·B, DDGI-P eq 2), positions (P, 3) float64, states (P,) uint8, depth (checked, not cast), visible
    ((N, 8) uint8, or (0, 8) for None))``. Raises ValueError naming the bad argument."""
    pts = _float_rows(points, "points")
    n = pts.shape[0]
    nrm = _float_rows(normals, "normals", n)
    view = _float_rows(view_dirs, "view_dirs", n)
    fdt = np.float32 if all(a.dtype == np.float32 for a in (pts, nrm, view)) else np.float64
    pts, nrm, view = (np.ascontiguousarray(a, dtype=fdt) for a in (pts, nrm, view))

    cnt = np.asarray(counts, np.int64).ravel()
    org = np.asarray(origin, np.float64).ravel()
    spc = np.asarray(spacing, np.float64).ravel()
    if cnt.shape != (3,) or org.shape != (3,) or spc.shape != (3,) or np.any(cnt < 1) or np.any(spc < 0):
        raise ValueError(
            "sample_irradiance: counts (3 ints >= 1), origin and spacing (3 floats, spacing >= 0) expected")
    if not math.isfinite(float(self_shadow_bias)):
        raise ValueError(f"sample_irradiance: self_shadow_bias must be finite, got {self_shadow_bias}")
    P = int(np.prod(cnt))
    pos = np.ascontiguousarray(probe_positions, np.float64)
    st = np.ascontiguousarray(states, np.uint8).ravel()
    if pos.shape != (P, 3) or st.shape != (P,):
        raise ValueError(f"sample_irradiance: probe_positions must be ({P}, 3) and states ({P},), "
                         f"got {pos.shape}, {st.shape}")
    dep = np.asarray(depth)
    if dep.ndim != 4 or dep.shape[0] != P or dep.shape[1] != dep.shape[2] or dep.shape[1] < 3 or dep.shape[3] != 2:
        raise ValueError(f"sample_irradiance: depth must be ({P}, m + 2, m + 2, 2), got {dep.shape}")
    if visible is None:
        vis = np.zeros((0, 8), np.uint8)
    else:
        vis = np.ascontiguousarray(visible, np.uint8)
        if vis.shape != (n, 8):
            raise ValueError(f"sample_irradiance: visible must be ({n}, 8), got {vis.shape}")
    lay = np.zeros((3, 0), np.float64) if layers is None else layers_table(cnt, org, spc, check_layers(layers, cnt))
    return pts, nrm, view, cnt, org, spc, lay, bias_scale(spc, self_shadow_bias), pos, st, dep, vis


def cage_rays(biased: np.ndarray, cage: np.ndarray, probe_positions: np.ndarray, states: np.ndarray):
    """Visibility rays from biased points to their live cage probes (``cage_probes``' outputs).

    Parameters: biased (N, 3) float64, cage (N, 8) int64, probe_positions (P, 3), states (P,) uint8.

    Returns ``live (N, 8) uint8`` (the probe is not OFF) and the rays of the live probes farther than
    1e-9 m, in (point, corner) order: ``origins (M, 3) float32`` (the biased points), ``dirs (M, 3)
    float32`` (unit, towards the probe), ``tfar (M,) float32`` (the distance less 1e-5 of it, so the
    probe's own surface never occludes it) and ``slot (M,) int64`` (the flat index into ``live``).
    Numba; replaces numpy temporaries of N x 8 x 3 float64 (0.5 s of the light stage at 16x8x16).
    """
    b = np.ascontiguousarray(biased, np.float64)
    c = np.ascontiguousarray(cage, np.int64)
    pos = np.ascontiguousarray(probe_positions, np.float64)
    st = np.ascontiguousarray(states, np.uint8).ravel()
    live = np.empty(c.shape, np.uint8)
    m = _cage_live_kernel(c, pos, st, b, live)
    o = np.empty((m, 3), np.float32)
    d = np.empty((m, 3), np.float32)
    tfar = np.empty(m, np.float32)
    slot = np.empty(m, np.int64)
    _cage_rays_kernel(c, pos, b, live, o, d, tfar, slot)
    return live, o, d, tfar, slot


@njit(cache=True, nogil=True)
def _cage_dist(pos, p, b, i):
    dx = pos[p, 0] - b[i, 0]
    dy = pos[p, 1] - b[i, 1]
    dz = pos[p, 2] - b[i, 2]
    return dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, nogil=True)
def _cage_live_kernel(cage, pos, states, b, live):
    m = 0
    for i in range(cage.shape[0]):
        for k in range(8):
            p = cage[i, k]
            live[i, k] = states[p] != OFF
            if live[i, k] and _cage_dist(pos, p, b, i)[3] > 1e-9:
                m += 1
    return m


@njit(cache=True, nogil=True)
def _cage_rays_kernel(cage, pos, b, live, o, d, tfar, slot):
    m = 0
    for i in range(cage.shape[0]):
        for k in range(8):
            if not live[i, k]:
                continue
            dx, dy, dz, dist = _cage_dist(pos, cage[i, k], b, i)
            if dist <= 1e-9:
                continue
            o[m, 0] = b[i, 0]
            o[m, 1] = b[i, 1]
            o[m, 2] = b[i, 2]
            d[m, 0] = dx / dist
            d[m, 1] = dy / dist
            d[m, 2] = dz / dist
            tfar[m] = dist * (1 - 1e-5)
            slot[m] = i * 8 + k
            m += 1


@njit(cache=True, nogil=True)
def _cage_kernel(points, normals, views, counts, origin, spacing, layers, bias, biased, cage):
    nx = counts[0]
    ny = counts[1]
    for i in range(points.shape[0]):
        for a in range(3):  # the same arithmetic as _sample_irradiance_kernel
            bp = float(points[i, a]) + (float(normals[i, a]) * NORMAL_BIAS + float(views[i, a]) * VIEW_BIAS) * bias
            biased[i, a] = bp
        base0 = base1 = base2 = 0
        for a in range(3):
            g = grid_index(biased[i, a], a, counts, origin, spacing, layers)
            hi = max(counts[a] - 2, 0)
            b = int(min(max(math.floor(g), 0.0), float(hi))) if math.isfinite(g) else 0
            if a == 0:
                base0 = b
            elif a == 1:
                base1 = b
            else:
                base2 = b
        for c in range(8):
            gi = min(base0 + (c & 1), counts[0] - 1)
            gj = min(base1 + ((c >> 1) & 1), counts[1] - 1)
            gk = min(base2 + ((c >> 2) & 1), counts[2] - 1)
            cage[i, c] = gi + nx * (gj + ny * gk)


def cage_probes(points, normals, view_dirs, counts, origin, spacing, self_shadow_bias: float = SELF_SHADOW_BIAS,
                layers=None):
    """The biased points and their 8 cage probes exactly as :func:`sample_irradiance` picks them.

    Returns ``biased (N, 3) float64`` (x + eq-2 bias) and ``cage (N, 8) int64`` flattened probe indices
    (corner c has offset (c & 1, c >> 1 & 1, c >> 2 & 1)); use them to trace visibility rays.
    """
    pts = np.ascontiguousarray(_float_rows(points, "points"), np.float64)
    n = pts.shape[0]
    nrm = np.ascontiguousarray(_float_rows(normals, "normals", n), np.float64)
    view = np.ascontiguousarray(_float_rows(view_dirs, "view_dirs", n), np.float64)
    cnt = np.asarray(counts, np.int64).ravel()
    spc = np.asarray(spacing, np.float64).ravel()
    biased = np.empty((n, 3), np.float64)
    cage = np.empty((n, 8), np.int64)
    if n:
        lay = np.zeros((3, 0), np.float64) if layers is None else layers_table(cnt, origin, spc,
                                                                               check_layers(layers, cnt))
        _cage_kernel(pts, nrm, view, cnt, np.asarray(origin, np.float64).ravel(), spc, lay,
                     bias_scale(spc, self_shadow_bias), biased, cage)
    return biased, cage
