"""The surface point under each texel centre of a UV atlas (lightmap texels; numba rasterizer).

Consumers: PRT's lightmap targets, tests. Inverse: none.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["texel_surfaces"]


@numba.njit(cache=True)
def _raster_uv(uv, width, height, owner, bu, bv):
    T = uv.shape[0]
    for t in range(T):
        x0, y0 = uv[t, 0, 0] * width, uv[t, 0, 1] * height
        x1, y1 = uv[t, 1, 0] * width, uv[t, 1, 1] * height
        x2, y2 = uv[t, 2, 0] * width, uv[t, 2, 1] * height
        den = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if abs(den) < 1e-20:
            continue
        cmin = max(0, int(math.floor(min(x0, x1, x2) - 0.5)))
        cmax = min(width - 1, int(math.ceil(max(x0, x1, x2) - 0.5)))
        rmin = max(0, int(math.floor(min(y0, y1, y2) - 0.5)))
        rmax = min(height - 1, int(math.ceil(max(y0, y1, y2) - 0.5)))
        for r in range(rmin, rmax + 1):
            py = r + 0.5
            for c in range(cmin, cmax + 1):
                if owner[r, c] >= 0:
                    continue
                px = c + 0.5
                w0 = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / den
                w1 = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / den
                w2 = 1.0 - w0 - w1
                if w0 >= -1e-9 and w1 >= -1e-9 and w2 >= -1e-9:
                    owner[r, c] = t
                    bu[r, c] = w1
                    bv[r, c] = w2


def texel_surfaces(uv, width: int, height: int, triangle_ids=None) -> dict:
    """The surface point under each texel centre of a UV atlas (e.g. UV1 lightmap texels).

    Texel (row r, col c) of a ``height`` x ``width`` map is centred at ``u = (c + 0.5)/width``,
    ``v = (r + 0.5)/height`` (glTF: v = 0 on the first row). Each centre inside a triangle's UV
    footprint gets that triangle (the first one in order where footprints overlap) and its
    barycentrics in the convention of :class:`workers.raycast.Hits` (x = (1-u-v)·v0 + u·v1 + v·v2).

    Parameters
    ----------
    uv : (T, 3, 2) float
        Per-triangle texture coordinates (``scene.uv1`` or a subset).
    triangle_ids : (T,) int, optional
        The scene triangle index of each row of ``uv`` (default 0 … T-1).

    Returns
    -------
    dict with ``rows``, ``cols`` (K,) int64 texel indices, ``tri`` (K,) int64 scene triangles, ``u``,
    ``v`` (K,) float64 barycentrics — feed ``tri, u, v`` to :func:`shading.surface_at_hits`.
    """
    a = np.ascontiguousarray(uv, np.float64)
    if a.ndim != 3 or a.shape[1:] != (3, 2):
        raise ValueError(f"texel_surfaces: uv must be (T, 3, 2), got {a.shape}")
    owner = np.full((int(height), int(width)), -1, np.int64)
    bu = np.zeros(owner.shape)
    bv = np.zeros(owner.shape)
    _raster_uv(a, int(width), int(height), owner, bu, bv)
    rows, cols = np.nonzero(owner >= 0)
    t = owner[rows, cols]
    ids = np.arange(a.shape[0]) if triangle_ids is None else np.asarray(triangle_ids, np.int64)
    return {"rows": rows, "cols": cols, "tri": ids[t], "u": bu[rows, cols], "v": bv[rows, cols]}
