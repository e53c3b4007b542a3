"""The probe grid's conventions, shared by every stage and sampler (numpy only).

Grid: ``counts = (nx, ny, nz)`` probes, probe (i, j, k) at ``origin + spacing * (i, j, k)`` before
relocation (world space, metres) — or, on a **rectilinear** grid, at ``(layers[0][i], layers[1][j], layers[2][k])``:
``layers`` (None for a uniform grid) holds per axis the strictly increasing layer coordinates (``counts[a]`` of them,
``layers[a][0] = origin[a]``, ``spacing[a]`` their mean gap). The continuous grid index of a point
(:func:`grid_coord`) is then piecewise linear between layers, and trilinear interpolation at that index is the
rectilinear grid's trilinear interpolation: every sampler reads a rectilinear grid through the index alone
(``proto/glsl/probe_grid.glsl`` ``giGridIndex``). Arrays of probes are flattened in C order from (nz, ny, nx), so
probe (i, j, k) has index ``p = i + nx * (j + ny * k)`` and ``volume.reshape(-1, ...)[p]`` is it.

Probe states (DDGI-P §6, offline subset): ``OFF`` (still inside geometry after relocation: never
used), ``ACTIVE`` (a surface within one cell: it shades surfaces), ``SLEEPING`` (nothing near).

Atlases (proto/bundle.md): per-probe octahedral maps with borders, (P, n, n, C), are packed into a
2D texture of (ny * n) rows and (nz * nx * n) columns; probe (i, j, k)'s tile starts at row
``j * n`` and column ``(k * nx + i) * n``.
"""
from __future__ import annotations

import math

import numpy as np

OFF, ACTIVE, SLEEPING = 0, 1, 2
STATE_NAMES = {OFF: "off", ACTIVE: "active", SLEEPING: "sleeping"}


def probe_count(counts) -> int:
    nx, ny, nz = (int(c) for c in counts)
    return nx * ny * nz


def probe_grid_indices(counts) -> np.ndarray:
    """(P, 3) int64 grid indices (i, j, k) of every probe, in flattened order."""
    nx, ny, nz = (int(c) for c in counts)
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    return np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)


def check_layers(layers, counts, origin=None):
    """``layers`` as a list of 3 float64 arrays (None stays None), checked: ``counts[a]`` strictly increasing values
    per axis (and the first equal to ``origin[a]`` within 1e-9 relative, when given)."""
    if layers is None:
        return None
    if len(layers) != 3:
        raise ValueError(f"layers must hold 3 axes, got {len(layers)}")
    out = []
    for a in range(3):
        la = np.asarray(layers[a], np.float64).reshape(-1)
        if la.size != int(counts[a]):
            raise ValueError(f"layers along {'xyz'[a]}: {la.size} values for {int(counts[a])} probes")
        if la.size > 1 and not (np.diff(la) > 0).all():
            raise ValueError(f"layers along {'xyz'[a]} must be strictly increasing")
        if origin is not None and la.size and abs(la[0] - float(origin[a])) > 1e-9 * max(1.0, abs(la[0])):
            raise ValueError(f"layers along {'xyz'[a]} must start at the origin ({la[0]} != {float(origin[a])})")
        out.append(la)
    return out


def layers_of(counts, origin, spacing, layers=None) -> list[np.ndarray]:
    """Per axis the (counts[a],) float64 layer coordinates: ``layers`` when given, else ``origin + spacing·i``."""
    if layers is not None:
        return [np.asarray(layers[a], np.float64).reshape(-1) for a in range(3)]
    return [float(origin[a]) + float(spacing[a]) * np.arange(int(counts[a]), dtype=np.float64) for a in range(3)]


def layers_table(counts, origin, spacing, layers=None) -> np.ndarray:
    """(3, max(counts)) float64 layer coordinates, each row padded with its last value (the numba kernels' and the
    ``uGridLayers`` texture's layout: texel (i, a) = layer i of axis a)."""
    ls = layers_of(counts, origin, spacing, layers)
    w = max(1, max(int(c) for c in counts))
    out = np.zeros((3, w), np.float64)
    for a in range(3):
        out[a, :ls[a].size] = ls[a]
        out[a, ls[a].size:] = ls[a][-1] if ls[a].size else 0.0
    return out


def axis_coord(x, layer) -> np.ndarray:
    """Continuous layer index of coordinates ``x`` (any shape) along one axis with layers ``layer`` (n,) increasing:
    ``i + (x − L_i)/(L_{i+1} − L_i)`` for the i ∈ [0, n − 2] with L_i ≤ x < L_{i+1} (the end cells extrapolate
    linearly, unclamped); 0 when n < 2. ``probe_grid.glsl`` ``giLayerCoord``."""
    x = np.asarray(x, np.float64)
    L = np.asarray(layer, np.float64)
    if L.size < 2:
        return np.zeros_like(x)
    i = np.clip(np.searchsorted(L, x, side="right") - 1, 0, L.size - 2)
    return i + (x - L[i]) / (L[i + 1] - L[i])


def axis_position(g, layer) -> np.ndarray:
    """Inverse of :func:`axis_coord`: the coordinate at continuous layer index ``g`` (piecewise linear, the end
    cells extrapolated)."""
    g = np.asarray(g, np.float64)
    L = np.asarray(layer, np.float64)
    if L.size < 2:
        return np.full_like(g, L[0] if L.size else 0.0)
    i = np.clip(np.floor(g).astype(np.int64), 0, L.size - 2)
    return L[i] + (g - i) * (L[i + 1] - L[i])


def grid_coord(points, counts, origin, spacing, layers=None) -> np.ndarray:
    """(N, 3) float64 continuous probe index of world points, unclamped: ``(p − origin)/spacing`` (uniform) or the
    layer coordinate per axis (rectilinear; :func:`axis_coord`); 0 on an axis with spacing 0 (uniform) or one
    probe (rectilinear)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    counts = np.asarray(counts, np.int64)
    spacing = np.asarray(spacing, np.float64)
    if layers is None:
        safe = np.where(spacing > 0, spacing, 1.0)
        g = (p - np.asarray(origin, np.float64)) / safe
        return np.where(spacing > 0, g, 0.0)
    return np.stack([axis_coord(p[:, a], layers[a]) if counts[a] > 1 else np.zeros(p.shape[0]) for a in range(3)],
                    axis=1)


def grid_point(g, counts, origin, spacing, layers=None) -> np.ndarray:
    """(N, 3) world points at continuous probe indices ``g`` (N, 3): the inverse of :func:`grid_coord`."""
    g = np.asarray(g, np.float64).reshape(-1, 3)
    if layers is None:
        return np.asarray(origin, np.float64) + g * np.asarray(spacing, np.float64)
    return np.stack([axis_position(g[:, a], layers[a]) for a in range(3)], axis=1)


def base_positions(counts, origin, spacing, layers=None) -> np.ndarray:
    """(P, 3) float64 un-relocated probe positions, world space (``layers``: a rectilinear grid, module doc)."""
    ijk = probe_grid_indices(counts)
    if layers is None:
        return np.asarray(origin, np.float64) + ijk * np.asarray(spacing, np.float64)
    ls = layers_of(counts, origin, spacing, layers)
    return np.stack([ls[a][ijk[:, a]] for a in range(3)], axis=1)


def cell_coords(points, counts, origin, spacing, layers=None) -> tuple[np.ndarray, np.ndarray]:
    """Base cell (the cage's min corner) and trilinear fractions of world points.

    points : (N, 3) world space. Returns ``base (N, 3) int64`` clamped to [0, n - 2] (0 on an axis
    with one probe) and ``alpha (N, 3) float64`` in [0, 1] (0 on a one-probe axis). Points outside the
    grid clamp to its border cells (as a clamped texture would). ``layers``: a rectilinear grid (module doc).
    """
    counts = np.asarray(counts, np.int64)
    g = grid_coord(points, counts, origin, spacing, layers)
    hi = np.maximum(counts - 2, 0)
    base = np.clip(np.floor(g), 0, hi).astype(np.int64)
    alpha = np.clip(g - base, 0.0, 1.0)
    alpha = np.where(counts > 1, alpha, 0.0)
    return base, alpha


def cage_indices(base, counts) -> np.ndarray:
    """(N, 8) flattened indices of the 8 cage probes; corner c has offset (c & 1, c >> 1 & 1, c >> 2 & 1)."""
    counts = np.asarray(counts, np.int64)
    nx, ny, _ = counts
    out = np.empty((base.shape[0], 8), np.int64)
    for c in range(8):
        off = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
        ijk = np.minimum(base + off, counts - 1)
        out[:, c] = ijk[:, 0] + nx * (ijk[:, 1] + ny * ijk[:, 2])
    return out


def pack_atlas(maps: np.ndarray, counts) -> np.ndarray:
    """(P, n, n, C) per-probe maps -> (ny * n, nz * nx * n, C) atlas (see module doc)."""
    nx, ny, nz = (int(c) for c in counts)
    P, n, m, C = maps.shape
    assert P == nx * ny * nz and n == m
    a = maps.reshape(nz, ny, nx, n, n, C).transpose(1, 3, 0, 2, 4, 5)  # (ny, n, nz, nx, n, C)
    return np.ascontiguousarray(a.reshape(ny * n, nz * nx * n, C))


def unpack_atlas(atlas: np.ndarray, counts, n: int) -> np.ndarray:
    """Inverse of :func:`pack_atlas`."""
    nx, ny, nz = (int(c) for c in counts)
    C = atlas.shape[-1]
    a = atlas.reshape(ny, n, nz, nx, n, C).transpose(2, 0, 3, 1, 4, 5)  # (nz, ny, nx, n, n, C)
    return np.ascontiguousarray(a.reshape(nx * ny * nz, n, n, C))


def grid_layout(bounds, section) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Counts (3,) int64, origin (3,) float64 and spacing (3,) float64 (metres) of a regular probe grid.

    bounds : (2, 3) world-space box (min, max), metres, used unless ``section.box`` (``.min``, ``.max``) is set.
    ``section`` (:class:`proto.models.PlaceSection`): the box is padded by ``padding`` × its extent on each side;
    ``counts`` puts the outermost probes on the faces of the padded box; else ``spacing`` uses
    ``ceil(extent / spacing) + 1`` probes per axis, centred on it. An axis with zero extent (or one probe) gets
    spacing 0 and its probes in the box's middle plane.
    """
    lo, hi = (np.asarray(section.box.min), np.asarray(section.box.max)) if section.box else (bounds[0], bounds[1])
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    pad = (hi - lo) * section.padding
    lo, hi = lo - pad, hi + pad
    extent = hi - lo
    if section.counts is not None:
        counts = np.asarray(section.counts, np.int64)
        spacing = np.where(counts > 1, extent / np.maximum(counts - 1, 1), 0.0)
        origin = np.where(counts > 1, lo, (lo + hi) / 2)
    else:
        s = float(section.spacing)
        counts = np.array([math.ceil(e / s - 1e-9) + 1 if e > 0 else 1 for e in extent], np.int64)
        spacing = np.where(counts > 1, s, 0.0)
        origin = (lo + hi) / 2 - spacing * (counts - 1) / 2
    return counts, origin, spacing


def grid_positions(counts, origin, spacing, layers=None) -> np.ndarray:
    """(nz, ny, nx, 3) float32 world positions of the grid, metres: :func:`base_positions` as a volume (x fastest)."""
    nx, ny, nz = (int(c) for c in counts)
    return base_positions(counts, origin, spacing, layers).reshape(nz, ny, nx, 3).astype(np.float32)


def dilate_off(values: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, int]:
    """Give OFF probes the values of their live neighbours (Unity Adaptive Probe Volumes' "dilation").

    values : (nz, ny, nx, ...) float, a per-probe quantity (e.g. SH coefficients); off : (nz, ny, nx) bool. Layer
    by layer over the 6-neighbours, every OFF probe next to a filled one takes the mean of its filled neighbours
    (live probes, or OFF probes of an earlier layer), like texture padding. OFF probes in a region of the grid
    without any live probe keep their value. Returns (a new array, number of probes filled).

    Why: a probe inside a solid deeper than the relocation can move it (DDGI-P §5: 0.45 spacing; the rescue: its 8
    cells, :func:`workers.kernels.relocation.rescue`) is OFF; its value
    is 0, and the modes that interpolate a volume trilinearly without visibility (leaking SH, three.js's
    LightProbeGrid) would blend that 0 into every cell it is a corner of, darkening the surfaces of the solid.
    Modes that know the state (DDGI, mask, normalized mask) give OFF probes weight 0 and never read these values.
    """
    v = np.array(values, dtype=np.float64 if values.dtype.kind != "f" else values.dtype, copy=True)
    off = np.asarray(off, bool).reshape(v.shape[:3])
    filled = ~off
    if filled.all() or not filled.any():
        return v, 0
    extra = (1,) * (v.ndim - 3)
    n_filled = 0
    while True:
        acc = np.zeros_like(v, dtype=np.float64)
        cnt = np.zeros(v.shape[:3], np.int64)
        for axis in range(3):
            for step in (1, -1):
                src = np.roll(filled, step, axis=axis)
                val = np.roll(v, step, axis=axis)
                edge = [slice(None)] * 3                 # np.roll wraps: drop what came round the edge
                edge[axis] = slice(0, 1) if step == 1 else slice(-1, None)
                src[tuple(edge)] = False
                acc += np.where(src.reshape(src.shape + extra), val, 0.0)
                cnt += src
        new = ~filled & (cnt > 0)
        if not new.any():
            break
        v[new] = (acc[new] / cnt[new].reshape((-1,) + extra)).astype(v.dtype)
        filled |= new
        n_filled += int(new.sum())
    return v, n_filled
