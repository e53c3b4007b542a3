"""Reference samplers of the runtime shading modes (DESIGN "Runtime shading"; MD eq 1-3).

The Python twin of what the GLSL in ``proto/glsl`` does with the baked volumes, fetch for fetch:
every volume is read by :func:`trilinear`, which is a ``sampler3D`` with ``LINEAR`` filtering and
``CLAMP_TO_EDGE`` wrapping (texel space, texel centres at integer + 0.5; ``R8G8B8A8_UNORM`` bytes read
as byte / 255). Irradiance is the SH of :mod:`workers.kernels.sh` (three.js order, clamped-cosine
convolution): ``E(n) = Σ_k Â_l L_k Y_k(n)`` per colour channel.

SH order (docs/architecture.md "Runtime SH evaluation")
-------------------------------------------------------
The runtime default is **L2** wherever the bake has the L2 volumes (``sh_l2``, ``cluster_sh_l2_{k}``: the three.js
LightProbeGrid layout, :func:`workers.kernels.sh.sh_l2_atlas`, read by :func:`sh_l2_sample`), evaluated linearly
(RH01 eq 7-8, :func:`workers.kernels.sh.sh_irradiance_l2`); measured on an open lit floor it is within a few % of
Cycles on all 6 axis normals where the non-linear L1 reads the sides 15-25% low. Bakes without them (light.sh_order
= 1, older bundles) are shaded with L1 as below. :func:`irradiance` picks the order (``sh_order=None``: L2 when
present); the mode functions take the L2 volumes as keyword arguments.

Addressing (proto/bundle.md §5)
-------------------------------
* Probe volumes ``(nz, ny, nx, C)`` (``sh_l1_*``, ``cluster_sh_*``, ``cluster_weights_*``):
  ``uvw = ((p − origin) / spacing + 0.5) / counts`` (:func:`probe_uvw`) — probe centres at texel
  centres, so inside the grid box trilinear filtering is ``Σ_i φ_i(p) V_i`` with φ the trilinear
  weights of the cage (MD §3.1.1), and outside it clamps to the border probes.
* Refined-grid volumes ``(Z, Y, X, C)`` (``masks_*``, ``theta_*``, ``dont_care``):
  ``uvw = (p − origin) / (spacing · (counts − 1))`` over the grid box (:func:`field_uvw`), so the
  texel centres are the samples ``origin + spacing·((x, y, z) + 0.5)/S``.
* An axis with one probe (spacing 0, counts 1): the probe volume has one texel there and the field is
  constant along it (its S samples all lie in the probe plane), so that coordinate is set to 0.5
  (the GLSL must guard the division the same way).

Modes (each ``(points (N, 3), normals (N, 3)) -> irradiance (N, 3) float64``, linear RGB)
------------------------------------------------------------------------------------------
With L1 volumes, "E = SH·n" below is the **non-linear L1 reconstruction**
(:func:`workers.kernels.sh.sh_irradiance_l1_nonlinear`,
Hazel 2017; ``proto/glsl/sh.glsl`` ``shIrradianceL1``): the same mean as the linear ``Σ Â_l L_lm Y_lm(n)`` but never
negative (the linear one rings below zero on the far side of a probe lit through a doorway). It is
homogeneous of degree 1, so scaling (normalization, masks) commutes with it, but it is not additive:
``linear=True`` selects the linear evaluation, which MD §3.2's exact equivalence below needs.
``leaking`` (MD eq 1)
    SH = trilinear(``sh_l1_{r,g,b}``) at the point; E = SH·n. L2: :func:`leaking_l2`, SH = the 7 sub-volumes of
    ``sh_l2`` read trilinearly at the point's clamped probe texel (:func:`probe_texel`, ``gi_grid.glsl``
    ``giPaddedStackedUVW``).
``visibility_weighted`` (MD eq 2, normalized as RTXGI; L2 with ``sh_l2=``: P_c the probes' 9 coefficients)
    ``Σ_c θ_c(x) φ_c(x) P_c / Σ_c θ_c(x) φ_c(x)`` over the 8 corner probes c of the point's cell
    (:func:`workers.kernels.grid.cell_coords`: base cell clamped to the grid, α clamped to [0, 1]),
    P_c fetched unfiltered (texelFetch) from ``sh_l1_*``; 0 where the denominator is 0.
    **How θ_c(x) is read**: channel c of ``theta_0123`` / ``theta_4567`` is "corner c *of the
    sample's own cell*", so filtering across a cell face would blend the visibility of different
    probes. The field is read trilinearly with the texel coordinate clamped to the S³ block of x's
    cell (``[base·S, base·S + S − 1]`` per axis): every one of the 8 taps belongs to x's cell, it is
    smooth inside the cell, and at a refined-grid sample it returns that sample's θ exactly.
    (GLSL: ``t = clamp((p − origin)/spacing·S − 0.5, base·S, base·S + S − 1)``, then
    ``texture(theta, (t + 0.5) / dims)``.) OFF probes need no test: their θ is 0 (and P is 0).
``mask`` (MD eq 3)
    ``Σ_k m_k(x') · (SH of trilinear(cluster_sh_k)(x))·n`` with m = trilinear(``masks_0123`` /
    ``masks_4567``) (hardware trilinear: masks are per cluster, not per corner, which is the point of MD)
    read at the **mask lookup point** ``x'`` (:func:`mask_values`): x moved ``offset`` refined samples (per
    axis) along n + v (v: the unit direction to the viewer, when given), with the texel coordinate clamped
    to x's own cell's S³ samples (θ's rule above; :func:`workers.kernels.compress.mask_lookup_texel`), blended
    with the read at x itself by their overlap (:func:`workers.kernels.compress.lookup_blend`: the offset read
    where it shares at least half its clusters with x's, x's own where it does not — an offset that crossed a
    surface the receiver faces).
    Why the offset: refined samples inside a wall see no probe, so their masks are don't-care, filled from
    both sides; a surface point's trilinear footprint half inside a thin wall would read them and weight
    the clusters of the far side by up to ½ (light through the wall). One refined sample
    along the normal (:data:`MASK_OFFSET_SAMPLES`, like DDGI-P eq 2's self-shadow bias) puts the footprint
    in front of the wall; the view term moves it towards the camera's side, away from a neighbouring wall
    at a corner (which the normal alone does not). Why the own cell: a channel is free (canonical 0,
    :func:`workers.kernels.mask_fit.canonicalize`) in a cell where its cluster has no probe; filtered across a
    face it would change that cluster's weight in the neighbour, where it is present. ``offset = 0`` reads
    at x.
    L2 (``cluster_sh_l2=``): E_k from ``cluster_sh_l2_{k}`` as :func:`leaking_l2` reads ``sh_l2``.
``mask_normalized`` (ours, DESIGN stage 4)
    The ``mask`` sum divided by ``Σ_k m_k(x') · w_k(x)`` with ``w_k`` = channel k of trilinear
    (``cluster_weights_0123`` / ``_4567``) = ``Σ_i φ_i g_i^k``; 0 where that is 0.

MD §3.2 in these terms (linear SH evaluation): with K = 8, the parity colouring (eq 4) and masks from θ
(no filter, no light-aware fit), ``mask_normalized`` equals ``visibility_weighted`` and ``mask`` equals eq 2
unnormalized at every care refined-grid sample and anywhere inside the box of one cell's sample
centres, to float64 rounding: the mask bytes are the θ bytes, so no 1/255 quantization enters. Both
read the point's own cell's samples, so this holds within half a sample of a cell face too.

Consumers: tests (MD §3.2 invariant, leak tests), stages/evaluate (reference for the GLSL modes).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from proto import gi_modes
from proto.gi_modes import MASK_OFFSET_SAMPLES
from workers.kernels.compress import lookup_blend, mask_lookups
from workers.kernels.grid import cage_indices, cell_coords, check_layers, grid_coord
from workers.kernels.sh import SH_L2_TEXELS, sh_irradiance, sh_irradiance_l1_nonlinear, sh_irradiance_l2

__all__ = ["MODES", "Grid", "trilinear", "texel_fetch", "probe_uvw", "field_uvw", "field_samples_per_cell",
           "leaking", "leaking_l2", "visibility_weighted", "mask", "mask_normalized", "irradiance", "mask_values",
           "probe_texel", "sh_l2_sample", "has_l2"]

MODES = ("leaking", "visibility_weighted", "mask", "mask_normalized")
# MASK_OFFSET_SAMPLES (proto/gi_modes.json, one source with the viewer): the runtime default of the mask lookup's
# offset, refined samples (per axis) along n + v


class Grid:
    """The probe grid: ``counts (3,) int (nx, ny, nz)``, ``origin (3,)``, ``spacing (3,)`` metres (0 on a
    one-probe axis), ``layers`` (None, or per axis the layer coordinates of a rectilinear grid:
    :mod:`workers.kernels.grid`). Build from the place stage's stats with ``Grid(**{k: stats[k] for k in ...})`` or
    :meth:`of`."""

    def __init__(self, counts, origin, spacing, layers=None):
        self.counts = np.asarray(counts, np.int64).reshape(3)
        self.origin = np.asarray(origin, np.float64).reshape(3)
        self.spacing = np.asarray(spacing, np.float64).reshape(3)
        if (self.counts < 1).any():
            raise ValueError(f"counts must be >= 1, got {self.counts.tolist()}")
        self.layers = check_layers(layers, self.counts)

    @classmethod
    def of(cls, grid) -> "Grid":
        """A Grid from a Grid or a mapping with counts, origin, spacing and optional layers (place stats, manifest
        grid)."""
        if isinstance(grid, Grid):
            return grid
        return cls(grid["counts"], grid["origin"], grid["spacing"], grid.get("layers"))

    def coord(self, points) -> np.ndarray:
        """(N, 3) continuous probe index of world points (:func:`workers.kernels.grid.grid_coord`; 0 on dead
        axes)."""
        return np.where(self.live, grid_coord(points, self.counts, self.origin, self.spacing, self.layers), 0.0)

    @property
    def live(self) -> np.ndarray:
        """(3,) bool: axes with more than one probe and a positive spacing."""
        return (self.counts > 1) & (self.spacing > 0)


def _points(points, name="points") -> np.ndarray:
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {p.shape}")
    return p


def _as_float(volume) -> np.ndarray:
    v = np.asarray(volume)
    if v.dtype == np.uint8:
        return v.astype(np.float64) / 255.0  # UNORM8
    return v.astype(np.float64)


def trilinear(volume, uvw) -> np.ndarray:
    """Sample a 3D texture like GLSL ``texture()`` with LINEAR filtering and CLAMP_TO_EDGE.

    Parameters
    ----------
    volume : (D, H, W) or (D, H, W, C) array
        Texel (x, y, z) at ``volume[z, y, x]``; uint8 is read as UNORM (byte / 255).
    uvw : (N, 3) float
        Normalized coordinates (u → x/W, v → y/H, w → z/D); texel centres at ``(i + 0.5) / size``.

    Returns
    -------
    (N, C) float64 (C = 1 for a 3-axis volume).

    Texel space: ``t = uvw·size − 0.5``, ``i0 = floor(t)``, ``f = t − i0``; both taps ``i0`` and
    ``i0 + 1`` clamped to ``[0, size − 1]`` (so past the border centre the edge texel is returned).
    """
    v = np.asarray(volume)          # taps converted one by one (below): the same numbers as _as_float(volume)
    if v.ndim == 3:
        v = v[..., None]
    if v.ndim != 4:
        raise ValueError(f"volume must be (D, H, W[, C]), got {np.shape(volume)}")
    unorm = v.dtype == np.uint8
    uvw = _points(uvw, "uvw")
    size = np.array([v.shape[2], v.shape[1], v.shape[0]], np.int64)  # (W, H, D) = (x, y, z)
    t = uvw * size - 0.5
    i0 = np.floor(t)
    f = t - i0
    i0 = i0.astype(np.int64)
    lo = np.clip(i0, 0, size - 1)
    hi = np.clip(i0 + 1, 0, size - 1)
    out = np.zeros((uvw.shape[0], v.shape[3]))
    for c in range(8):
        bx, by, bz = c & 1, (c >> 1) & 1, (c >> 2) & 1
        wx = f[:, 0] if bx else 1.0 - f[:, 0]
        wy = f[:, 1] if by else 1.0 - f[:, 1]
        wz = f[:, 2] if bz else 1.0 - f[:, 2]
        x = hi[:, 0] if bx else lo[:, 0]
        y = hi[:, 1] if by else lo[:, 1]
        z = hi[:, 2] if bz else lo[:, 2]
        tap = v[z, y, x].astype(np.float64)
        out += (wx * wy * wz)[:, None] * (tap / 255.0 if unorm else tap)   # UNORM8: byte / 255
    return out


def texel_fetch(volume, ijk) -> np.ndarray:
    """GLSL ``texelFetch``: texels at integer (x, y, z) = ijk (N, 3) → (N, C) float64 (uint8 as UNORM)."""
    v = _as_float(volume)
    if v.ndim == 3:
        v = v[..., None]
    ijk = np.asarray(ijk, np.int64)
    return v[ijk[:, 2], ijk[:, 1], ijk[:, 0]]


def probe_uvw(points, grid) -> np.ndarray:
    """uvw of world points in a probe volume: ``((p − origin)/spacing + 0.5)/counts`` (0.5 on one-probe axes)."""
    g = Grid.of(grid)
    p = _points(points)
    uvw = (g.coord(p) + 0.5) / g.counts
    return np.where(g.live, uvw, 0.5)


def probe_texel(points, grid) -> np.ndarray:
    """(N, 3) texel coordinate of world points in a probe volume, clamped to the border texel centres
    (``gi_grid.glsl`` ``giProbeTexel``): ``clamp((p − origin)/spacing + 0.5, 0.5, counts − 0.5)``, 0.5 on one-probe
    axes. With LINEAR filtering this reads like CLAMP_TO_EDGE and never leaves the volume (stacked volumes)."""
    g = Grid.of(grid)
    p = _points(points)
    t = g.coord(p) + 0.5
    return np.clip(t, 0.5, g.counts - 0.5)


def sh_l2_sample(atlas, points, grid) -> np.ndarray:
    """(N, 9, 3) L2 radiance SH at world points from an L2 volume in the three.js LightProbeGrid layout
    (``sh_l2``, ``cluster_sh_l2_{k}``; :func:`workers.kernels.sh.sh_l2_atlas`): 7 trilinear fetches, sub-volume t
    at z texel ``tz + 1 + t·(nz + 2)`` (``gi_grid.glsl`` ``giPaddedStackedUVW``)."""
    g = Grid.of(grid)
    a = np.asarray(atlas)
    nx, ny, nz = (int(c) for c in g.counts)
    want = (SH_L2_TEXELS * (nz + 2), ny, nx, 4)
    if a.shape != want:
        raise ValueError(f"an L2 volume of this grid must have shape {want}, got {a.shape}")
    t = probe_texel(points, g)
    slices = nz + 2.0
    parts = []
    for sub in range(SH_L2_TEXELS):
        uvw = np.stack([t[:, 0] / nx, t[:, 1] / ny, (t[:, 2] + 1.0 + sub * slices) / (slices * SH_L2_TEXELS)], -1)
        parts.append(trilinear(a, uvw))                                            # (N, 4)
    flat = np.concatenate(parts, axis=1)[:, :27]                                   # c0.rgb, c1.rgb, ...
    return flat.reshape(-1, 9, 3)


def field_uvw(points, grid) -> np.ndarray:
    """uvw of world points in a refined-grid volume: ``(p − origin)/(spacing·(counts − 1))`` (0.5 on
    one-probe axes)."""
    g = Grid.of(grid)
    p = _points(points)
    cells = np.maximum(g.counts - 1, 1)
    return np.where(g.live, g.coord(p) / cells, 0.5)


def field_samples_per_cell(field_volume, grid) -> int:
    """S of a refined-grid volume (Z, Y, X, ...) of this grid (checks the shape)."""
    g = Grid.of(grid)
    cells = np.maximum(g.counts - 1, 1)
    shape = np.asarray(field_volume).shape
    S = shape[2] // int(cells[0])
    if S < 1 or tuple(shape[:3]) != (int(cells[2]) * S, int(cells[1]) * S, int(cells[0]) * S):
        raise ValueError(f"field volume shape {shape[:3]} does not fit a grid of {g.counts.tolist()} probes")
    return S


def _irr(sh_rgb: np.ndarray, normals: np.ndarray, linear: bool = False) -> np.ndarray:
    """(N, 4, 3) L1 radiance SH and (N, 3) normals → (N, 3) irradiance: the non-linear L1 reconstruction
    (:func:`workers.kernels.sh.sh_irradiance_l1_nonlinear`, the GLSL default), or the linear one."""
    return sh_irradiance(sh_rgb, normals) if linear else sh_irradiance_l1_nonlinear(sh_rgb, normals)


def _stack_rgb(parts) -> np.ndarray:
    """[(N, 4) r, (N, 4) g, (N, 4) b] → (N, 4, 3)."""
    return np.stack(parts, axis=-1)


def _probe_check(vol, grid: Grid, name: str):
    shape = np.shape(vol)
    want = (int(grid.counts[2]), int(grid.counts[1]), int(grid.counts[0]))
    if tuple(shape[:3]) != want:
        raise ValueError(f"{name} must be a (nz, ny, nx, ...) = {want} probe volume, got {shape}")


def leaking(points, normals, sh_r, sh_g, sh_b, grid, *, linear: bool = False) -> np.ndarray:
    """MD eq 1: trilinear SH volume. sh_* (nz, ny, nx, 4) float (L0, L1y, L1z, L1x of one channel)."""
    g = Grid.of(grid)
    for v, n in ((sh_r, "sh_r"), (sh_g, "sh_g"), (sh_b, "sh_b")):
        _probe_check(v, g, n)
    uvw = probe_uvw(points, g)
    sh = _stack_rgb([trilinear(v, uvw) for v in (sh_r, sh_g, sh_b)])
    return _irr(sh, _points(normals, "normals"), linear)


def leaking_l2(points, normals, sh_l2, grid) -> np.ndarray:
    """MD eq 1 with L2 SH: E = the linear L2 evaluation (RH01 eq 7-8) of :func:`sh_l2_sample` of ``sh_l2``
    (7·(nz + 2), ny, nx, 4) at the points. Not clamped (the GLSL clamps at 0)."""
    sh = sh_l2_sample(sh_l2, points, grid)
    return sh_irradiance_l2(sh, _points(normals, "normals"))


def _theta_in_cell(theta_0123, theta_4567, points, g: Grid, base) -> np.ndarray:
    """(N, 8) θ_c(x) read trilinearly with the texel coordinate clamped to x's cell block (module doc)."""
    S = field_samples_per_cell(theta_0123, g)
    dims = np.array([theta_0123.shape[2], theta_0123.shape[1], theta_0123.shape[0]], np.float64)
    t = np.where(g.live, g.coord(points) * S - 0.5, 0.0)
    lo = base * S
    tc = np.clip(t, lo, lo + S - 1)
    uvw = (tc + 0.5) / dims
    return np.concatenate([trilinear(theta_0123, uvw), trilinear(theta_4567, uvw)], axis=1)


def visibility_weighted(points, normals, sh_r, sh_g, sh_b, theta_0123, theta_4567, grid, *,
                        normalize: bool = True, linear: bool = False, sh_l2=None) -> np.ndarray:
    """MD eq 2: ``Σ θ_c φ_c P_c / Σ θ_c φ_c`` over the cell's 8 corners (0 where the sum is 0).

    ``normalize=False`` gives eq 2 as written, ``Σ θ_c φ_c P_c`` (what ``mask`` reproduces with K = 8
    and the parity colouring). theta_* : (Z, Y, X, 4) uint8 refined-grid volumes. ``sh_l2`` (the ``sh_l2``
    volume): P_c are the probes' 9 coefficients and E the linear L2 evaluation (sh_r/g/b are then not read).
    """
    g = Grid.of(grid)
    p = _points(points)
    if sh_l2 is None:
        for v, n in ((sh_r, "sh_r"), (sh_g, "sh_g"), (sh_b, "sh_b")):
            _probe_check(v, g, n)
    base, alpha = cell_coords(p, g.counts, g.origin, g.spacing, g.layers)
    theta = _theta_in_cell(np.asarray(theta_0123), np.asarray(theta_4567), p, g, base)  # (N, 8)
    cage = cage_indices(base, g.counts)                                                 # (N, 8) flat
    if sh_l2 is not None:
        from workers.kernels.sh import sh_l2_from_atlas

        coeffs = sh_l2_from_atlas(sh_l2).astype(np.float64).reshape(-1, 9, 3)            # texelFetch per probe
        sh_all = [coeffs[..., c] for c in range(3)]
    else:
        sh_all = [np.asarray(v, np.float64).reshape(-1, 4) for v in (sh_r, sh_g, sh_b)]
    num = np.zeros((p.shape[0], sh_all[0].shape[1], 3))
    den = np.zeros(p.shape[0])
    for c in range(8):
        off = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
        phi = np.prod(np.where(off, alpha, 1.0 - alpha), axis=1)    # φ_c(x)
        w = theta[:, c] * phi                                          # θ_c(x) φ_c(x)
        P = _stack_rgb([s[cage[:, c]] for s in sh_all])               # texelFetch of probe c
        num += w[:, None, None] * P
        den += w
    if normalize:
        ok = den > 0
        num[ok] /= den[ok, None, None]
        num[~ok] = 0.0
    if sh_l2 is not None:
        return sh_irradiance_l2(num, _points(normals, "normals"))
    return _irr(num, _points(normals, "normals"), linear)


def mask_values(masks, points, normals, grid, samples: float = 0.0, views=None) -> np.ndarray:
    """(N, C) the refined-grid mask volumes ``masks`` (list of (Z, Y, X, 4) uint8) read as the runtime reads
    them for surface points with unit ``normals`` (and unit directions to the viewer ``views``, optional):
    ``samples`` refined samples along d = n + v (d = n without views), the texel coordinate clamped to p's
    own cell's samples (:func:`workers.kernels.compress.mask_lookup_texel`), trilinear, blended with the read
    at p by :func:`workers.kernels.compress.lookup_blend` over all channels. Channels of all volumes
    concatenated, as bytes / 255."""
    g = Grid.of(grid)
    p = _points(points)
    d = _points(normals, "normals")
    if views is not None:
        d = d + _points(views, "views")
    S = field_samples_per_cell(masks[0], g)
    ts, _ = mask_lookups(p, g.counts, g.origin, g.spacing, S, d, samples, np.float64, layers=g.layers)
    reads = []
    for t in ts:
        reads.append(np.concatenate([trilinear(v, (t + 0.5) / np.array([v.shape[2], v.shape[1], v.shape[0]],
                                                                         np.float64)) for v in masks], axis=1))
    return lookup_blend(reads)


def _mask_terms(points, normals, masks, cluster_sh, grid, cluster_weights=None, offset: float = 0.0,
                linear: bool = False, views=None, cluster_sh_l2=None):
    g = Grid.of(grid)
    p = _points(points)
    n = _points(normals, "normals")
    K = len(cluster_sh) if cluster_sh_l2 is None else len(cluster_sh_l2)
    if K < 1:
        raise ValueError("cluster_sh must hold at least one cluster")
    m = mask_values(masks, p, n, g, offset, views)[:, :K]                    # (N, K)
    if m.shape[1] < K:
        raise ValueError(f"masks hold {m.shape[1]} channels for {K} clusters")
    uvw = probe_uvw(p, g)
    e = np.zeros((p.shape[0], 3))
    if cluster_sh_l2 is not None:
        for k, atlas in enumerate(cluster_sh_l2):                                 # L2: 7 fetches per cluster
            e += m[:, k:k + 1] * sh_irradiance_l2(sh_l2_sample(atlas, p, g), n)
    else:
        for k, (r, gg, b) in enumerate(cluster_sh):
            for v in (r, gg, b):
                _probe_check(v, g, f"cluster_sh[{k}]")
            sh = _stack_rgb([trilinear(v, uvw) for v in (r, gg, b)])
            e += m[:, k:k + 1] * _irr(sh, n, linear)
    den = None
    if cluster_weights is not None:
        w = np.concatenate([trilinear(v, uvw) for v in cluster_weights], axis=1)[:, :K]
        den = (m * w).sum(axis=1)
    return e, den


def mask(points, normals, masks, cluster_sh, grid, offset: float = 0.0, *, linear: bool = False,
         views=None, cluster_sh_l2=None) -> np.ndarray:
    """MD eq 3: ``Σ_k m_k(x') · E(trilinear(cluster_sh_k)(x), n)``, x' the mask lookup point
    (:func:`mask_values`: ``offset`` refined samples along n + v, v = ``views`` or 0; 0 = at x).

    masks : list of (Z, Y, X, 4) uint8 volumes (``masks_0123``[, ``masks_4567``]);
    cluster_sh : list of K ``(r, g, b)`` tuples of (nz, ny, nx, 4) float volumes (L1);
    cluster_sh_l2 : None, or a list of K L2 volumes ``cluster_sh_l2_{k}`` (7·(nz + 2), ny, nx, 4): then E_k is their
    linear L2 evaluation and ``cluster_sh`` is not read (may be None).
    """
    return _mask_terms(points, normals, masks, cluster_sh, grid, offset=offset, linear=linear, views=views,
                       cluster_sh_l2=cluster_sh_l2)[0]


def mask_normalized(points, normals, masks, cluster_sh, cluster_weights, grid, offset: float = 0.0, *,
                    linear: bool = False, views=None, cluster_sh_l2=None) -> np.ndarray:
    """``mask`` divided by ``Σ_k m_k(x') w_k(x)`` (0 where that is 0); cluster_weights : list of
    (nz, ny, nx, 4) float volumes (``cluster_weights_0123``[, ``_4567``]); ``cluster_sh_l2`` as :func:`mask`."""
    e, den = _mask_terms(points, normals, masks, cluster_sh, grid, cluster_weights, offset=offset, linear=linear,
                         views=views, cluster_sh_l2=cluster_sh_l2)
    out = np.zeros_like(e)
    ok = den > 0
    out[ok] = e[ok] / den[ok, None]
    return out


def has_l2(mode: str, arrays: Mapping) -> bool:
    """Whether the bake's arrays hold the L2 volumes ``mode`` reads (``sh_l2``; ``cluster_sh_l2_{k}`` for every
    cluster of the mask modes): the mode's ``l2_needs`` in ``proto/gi_modes.json`` (visibility_weighted reads
    leaking's volumes)."""
    if mode not in MODES:
        return False
    return gi_modes.has_l2("leaking" if mode == "visibility_weighted" else mode, arrays)


def irradiance(mode: str, arrays: Mapping, grid, points, normals,
               mask_offset_samples: float = MASK_OFFSET_SAMPLES, linear: bool = False, views=None,
               sh_order: int | None = None) -> np.ndarray:
    """Shade with ``mode`` (one of :data:`MODES`) from baked artifacts addressed by name.

    arrays : mapping artifact name → array (a dict, or the pipeline's LazyArtifacts merged), using
    ``sh_l1_{r,g,b}``; ``theta_0123``, ``theta_4567``; ``masks_0123``[, ``masks_4567``],
    ``cluster_sh_{k}_{r,g,b}``, ``cluster_weights_0123``[, ``_4567``] (K = number of cluster_sh_k_r); the L2
    volumes ``sh_l2``, ``cluster_sh_l2_{k}`` when the bake has them.
    The mask modes read the masks ``mask_offset_samples`` refined samples along n + v (``views``: unit
    directions to the viewer, (N, 3); without them along n) — the runtime default, as the GLSL renders them
    (0 = at the point). ``sh_order``: None (the runtime default) = L2 where the bake has the L2 volumes
    (:func:`has_l2`: ``sh_l2``, ``cluster_sh_l2_{k}``), else L1; 1 or 2 to choose (2 needs them).
    ``visibility_weighted`` (no GLSL mode) follows ``sh_l2`` like leaking. ``linear``: with L1, the linear
    evaluation instead of the non-linear default.
    """
    if sh_order not in (None, 1, 2):
        raise ValueError(f"sh_order must be None, 1 or 2, got {sh_order!r}")
    l2 = has_l2(mode, arrays) if sh_order is None else sh_order == 2
    if l2 and mode in MODES and not has_l2(mode, arrays):
        raise ValueError(f"sh_order=2: the bake has no L2 volumes for mode {mode!r} (light.sh_order = 1?)")
    if mode == "leaking":
        if l2:
            return leaking_l2(points, normals, arrays["sh_l2"], grid)
        return leaking(points, normals, arrays["sh_l1_r"], arrays["sh_l1_g"], arrays["sh_l1_b"], grid, linear=linear)
    if mode == "visibility_weighted":
        l1 = (None, None, None) if l2 else (arrays["sh_l1_r"], arrays["sh_l1_g"], arrays["sh_l1_b"])
        return visibility_weighted(points, normals, *l1, arrays["theta_0123"], arrays["theta_4567"], grid,
                                   linear=linear, sh_l2=arrays["sh_l2"] if l2 else None)
    if mode in ("mask", "mask_normalized"):
        K = 0
        while f"cluster_sh_{K}_r" in arrays:
            K += 1
        cl2 = [arrays[f"cluster_sh_l2_{k}"] for k in range(K)] if l2 else None
        cl = None if l2 else [tuple(arrays[f"cluster_sh_{k}_{c}"] for c in "rgb") for k in range(K)]
        masks = [arrays["masks_0123"]] + ([arrays["masks_4567"]] if K > 4 else [])
        off = float(mask_offset_samples)
        if mode == "mask":
            return mask(points, normals, masks, cl, grid, off, linear=linear, views=views, cluster_sh_l2=cl2)
        wts = [arrays["cluster_weights_0123"]] + ([arrays["cluster_weights_4567"]] if K > 4 else [])
        return mask_normalized(points, normals, masks, cl, wts, grid, off, linear=linear, views=views,
                               cluster_sh_l2=cl2)
    raise ValueError(f"unknown mode {mode!r}; valid: {', '.join(MODES)}")
