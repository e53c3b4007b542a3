"""Octahedral atlases without their border (issue 17; proto/bundle.md 5.1 "Atlas tiling"): numpy only.

The DDGI atlases (``irradiance``, ``depth_moments``) are read at runtime with a 1-texel border around each probe's
octahedral tile, copied from mirrored interior texels (RTXGI, DDGI-P §7.1 Fig 12a), so that bilinear filtering
across a seam reads the right neighbours. The border holds nothing of its own, so bundles store the interior
tiles only (``meta.stored_border`` = 0) and readers add the border back at load time: :func:`add_border` on one
tile, :func:`atlas_add_border` on a whole atlas. Consumers: :func:`proto.bundle.load_artifact`,
:func:`workers.kernels.octahedral.add_border`; the viewer's ``web/src/math/atlas.js`` ``atlasWithBorder`` does
the same in JavaScript. Inverse: :func:`atlas_strip_border`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["add_border", "atlas_add_border", "atlas_strip_border"]


def add_border(m: np.ndarray) -> np.ndarray:
    """(..., n, n, C) interior texels -> (..., n + 2, n + 2, C) with RTXGI's mirrored border, same dtype.

    Top row ``b[0, c] = m[0, n-1-(c-1)]``, bottom ``b[n+1, c] = m[n-1, n-1-(c-1)]`` (columns flipped), left
    column ``b[r, 0] = m[n-1-(r-1), 0]``, right ``b[r, n+1] = m[n-1-(r-1), n-1]`` (rows flipped), each corner
    from the opposite interior corner (all four are the direction −Z).
    """
    m = np.asarray(m)
    n = m.shape[-3]
    out = np.empty(m.shape[:-3] + (n + 2, n + 2, m.shape[-1]), dtype=m.dtype)
    out[..., 1:-1, 1:-1, :] = m
    out[..., 0, 1:-1, :] = m[..., 0, ::-1, :]  # top edge: first row, columns flipped
    out[..., -1, 1:-1, :] = m[..., -1, ::-1, :]  # bottom edge: last row, columns flipped
    out[..., 1:-1, 0, :] = m[..., ::-1, 0, :]  # left edge: first column, rows flipped
    out[..., 1:-1, -1, :] = m[..., ::-1, -1, :]  # right edge: last column, rows flipped
    out[..., 0, 0, :] = m[..., -1, -1, :]  # corners from the opposite corner
    out[..., 0, -1, :] = m[..., -1, 0, :]
    out[..., -1, 0, :] = m[..., 0, -1, :]
    out[..., -1, -1, :] = m[..., 0, 0, :]
    return out


def _tiles(atlas: np.ndarray, t: int) -> tuple[np.ndarray, int, int]:
    a = np.asarray(atlas)
    if a.ndim == 2:
        a = a[..., None]
    H, W = a.shape[:2]
    if t < 1 or H % t or W % t:
        raise ValueError(f"atlas of {H} x {W} texels is not made of {t} x {t} tiles")
    rows, cols = H // t, W // t
    return a.reshape(rows, t, cols, t, a.shape[-1]).transpose(0, 2, 1, 3, 4), rows, cols


def atlas_add_border(atlas: np.ndarray, texels: int) -> np.ndarray:
    """A (rows·n, cols·n, C) atlas of n × n interior tiles (n = ``texels``) -> (rows·(n+2), cols·(n+2), C) with
    each tile's border (:func:`add_border`); a 2-axis atlas is one channel and stays 2-axis."""
    tiles, rows, cols = _tiles(atlas, int(texels))
    t = int(texels) + 2
    out = add_border(tiles).transpose(0, 2, 1, 3, 4).reshape(rows * t, cols * t, tiles.shape[-1])
    return out[..., 0] if np.ndim(atlas) == 2 else np.ascontiguousarray(out)


def atlas_strip_border(atlas: np.ndarray, texels: int) -> np.ndarray:
    """Inverse of :func:`atlas_add_border`: the interior n × n texels of each (n+2) × (n+2) tile."""
    tiles, rows, cols = _tiles(atlas, int(texels) + 2)
    n = int(texels)
    out = tiles[:, :, 1:-1, 1:-1].transpose(0, 2, 1, 3, 4).reshape(rows * n, cols * n, tiles.shape[-1])
    return out[..., 0] if np.ndim(atlas) == 2 else np.ascontiguousarray(out)
