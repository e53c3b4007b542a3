"""PRT's lightmap target: UV charts packed at a uniform texel density, texels rasterized, images dilated.

PRT §4.1 fits a transfer to any linear target; besides the probes' SH the stage fits lightmap texels
(:func:`lightmap_texels`): TEXCOORD_1 charts where the scene has them (one chart per glTF node), xatlas UVs for
the other triangles (optional dependency, imported at first use), packed by :func:`chart_layout` into one
res x res map, rasterized (:func:`rasterize`), and the basis images grown into empty texels (:func:`dilate`, linear,
so relit maps dilate too).

Consumers: kernels/prt_dataset, stages/prt. Inverse: none.
"""
from __future__ import annotations

import math

import numpy as np

from workers.kernels.prt_scenario import triangle_areas
from workers.kernels.shading import surface_at_hits

__all__ = ["chart_layout", "rasterize", "dilate", "lightmap_texels", "LIGHTMAP_PADDING", "DILATE_TEXELS"]

LIGHTMAP_PADDING = 2
"""Texels of padding around each chart."""
DILATE_TEXELS = 2
"""Dilation passes of the basis images (texels grown around the charts)."""


def _shelf_pack(sizes, res: int):
    """Place (w, h) integer rectangles in a res x res square, tallest first, left to right in shelves.

    Returns (k, 2) offsets (x, y) or None when they do not fit."""
    order = sorted(range(len(sizes)), key=lambda i: (-sizes[i][1], -sizes[i][0], i))
    off = np.zeros((len(sizes), 2), np.int64)
    x = y = shelf = 0
    for i in order:
        w, h = sizes[i]
        if w > res or h > res:
            return None
        if x + w > res:
            x, y, shelf = 0, y + shelf, 0
        if y + h > res:
            return None
        off[i] = (x, y)
        x += w
        shelf = max(shelf, h)
    return off


def chart_layout(triangles, uv, chart, res: int, padding: int = 2):
    """Pack UV charts into one res x res lightmap at a uniform texel density.

    Each chart (triangles sharing a ``chart`` id >= 0, each with its own UV space, e.g. one glTF
    node's TEXCOORD_1) keeps its internal layout; its UV bounding box is scaled by
    √(world area / UV area) so texels cover the same area everywhere, the boxes are shelf-packed with
    ``padding`` texels around each, and the largest density that fits is found by bisection.

    Parameters
    ----------
    triangles : (T, 3, 3) float, metres; uv : (T, 3, 2) float; chart : (T,) int (-1: not in the map).

    Returns
    -------
    atlas_uv : (T, 3, 2) float32 — lightmap UVs (texel (row r, col c) centred at
        ``((c + 0.5)/res, (r + 0.5)/res)``, glTF convention: v runs down the rows); zeros for chart -1
        and for charts with no UV area.
    texels_per_metre : float
    """
    tri = np.asarray(triangles, np.float64)
    uv = np.asarray(uv, np.float64)
    chart = np.asarray(chart)
    out = np.zeros(uv.shape, np.float32)
    wa = triangle_areas(tri)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    ua = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    ids, lo, ext, scale = [], [], [], []
    for c in np.unique(chart[chart >= 0]):
        sel = chart == c
        a_uv, a_w = ua[sel].sum(), wa[sel].sum()
        if not (a_uv > 0 and a_w > 0):
            continue
        pts = uv[sel].reshape(-1, 2)
        ids.append(c)
        lo.append(pts.min(axis=0))
        ext.append(np.maximum(pts.max(axis=0) - pts.min(axis=0), 1e-9))
        scale.append(math.sqrt(a_w / a_uv))                  # metres per UV unit
    if not ids:
        return out, 0.0
    lo, ext, scale = np.array(lo), np.array(ext), np.array(scale)
    metres = ext * scale[:, None]                              # chart box size, metres

    def sizes(rho):
        return [(int(math.ceil(w * rho)) + 2 * padding, int(math.ceil(h * rho)) + 2 * padding) for w, h in metres]

    lo_r, hi_r = 0.0, res / max(float(metres.max()), 1e-12)
    for _ in range(40):                                      # bisection on the texel density
        mid = 0.5 * (lo_r + hi_r)
        if _shelf_pack(sizes(mid), res) is not None:
            lo_r = mid
        else:
            hi_r = mid
    rho = lo_r
    offsets = _shelf_pack(sizes(rho), res)
    if offsets is None or rho <= 0:
        return out, 0.0
    for k, c in enumerate(ids):
        sel = chart == c
        texel = offsets[k] + padding + (uv[sel] - lo[k]) * scale[k] * rho   # texel-space coordinates
        out[sel] = (texel / res).astype(np.float32)
    return out, float(rho)


def rasterize(atlas_uv, res: int):
    """Texels whose centre lies in a triangle's lightmap footprint.

    Parameters
    ----------
    atlas_uv : (T, 3, 2) float, lightmap UVs (see :func:`chart_layout`); all-zero rows are skipped.

    Returns
    -------
    tri : (res, res) int32, the triangle covering each texel centre (row = v, col = u), -1 if none
        (where footprints overlap, the later triangle wins);
    bary : (res, res, 2) float32, its barycentrics (u, v) in the ray-hit convention
        ``x = (1 - u - v)·v0 + u·v1 + v·v2``.
    """
    uvs = np.asarray(atlas_uv, np.float64) * res
    tri_map = np.full((res, res), -1, np.int32)
    bary = np.zeros((res, res, 2), np.float32)
    lo = np.floor(uvs.min(axis=1) - 0.5).astype(np.int64).clip(0, res - 1)
    hi = np.ceil(uvs.max(axis=1) - 0.5).astype(np.int64).clip(0, res - 1)
    live = np.any(uvs != 0, axis=(1, 2))
    for t in np.flatnonzero(live):
        (x0, y0), (x1, y1), (x2, y2) = uvs[t]
        det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if det == 0:
            continue
        cols = np.arange(lo[t, 0], hi[t, 0] + 1)
        rows = np.arange(lo[t, 1], hi[t, 1] + 1)
        px = cols[None, :] + 0.5
        py = rows[:, None] + 0.5
        bu = ((px - x0) * (y2 - y0) - (x2 - x0) * (py - y0)) / det
        bv = ((x1 - x0) * (py - y0) - (px - x0) * (y1 - y0)) / det
        eps = -1e-9
        inside = (bu >= eps) & (bv >= eps) & (bu + bv <= 1 - eps)
        if not inside.any():
            continue
        rr, cc = np.nonzero(inside)
        tri_map[rows[rr], cols[cc]] = t
        bary[rows[rr], cols[cc], 0] = bu[rr, cc]
        bary[rows[rr], cols[cc], 1] = bv[rr, cc]
    return tri_map, bary


def dilate(images, mask, iterations: int = 2):
    """Grow images into empty texels: each pass fills every empty texel with a filled 8-neighbour by the
    mean of its filled neighbours (a linear operation, so it commutes with weighted sums of images —
    dilating the basis dilates every relit lightmap).

    images : (..., H, W) float; mask : (H, W) bool, True where filled. Returns (dilated images, new mask).
    """
    img = np.array(images, np.float32, copy=True)
    m = np.asarray(mask, bool).copy()
    H, W = m.shape
    for _ in range(iterations):
        acc = np.zeros_like(img)
        cnt = np.zeros((H, W), np.float32)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy == 0 and dx == 0:
                    continue
                ys = slice(max(dy, 0), H + min(dy, 0))
                yd = slice(max(-dy, 0), H + min(-dy, 0))
                xs = slice(max(dx, 0), W + min(dx, 0))
                xd = slice(max(-dx, 0), W + min(-dx, 0))
                src = m[ys, xs]
                acc[..., yd, xd] += img[..., ys, xs] * src
                cnt[yd, xd] += src
        grow = ~m & (cnt > 0)
        if not grow.any():
            break
        img[..., grow] = acc[..., grow] / cnt[grow]
        m |= grow
    return img, m


def _xatlas_uv(tris: np.ndarray, res: int) -> np.ndarray | None:
    """(k, 3, 2) UVs in [0, 1] for triangles without TEXCOORD_1 (xatlas, vertices welded by position)."""
    try:
        import xatlas
    except ImportError:
        return None
    verts = tris.reshape(-1, 3)
    uniq, inv = np.unique(verts, axis=0, return_inverse=True)
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(uniq, np.float32), inv.reshape(-1, 3).astype(np.uint32))
    po = xatlas.PackOptions()
    po.padding = LIGHTMAP_PADDING
    po.resolution = int(res)
    atlas.generate(pack_options=po)
    if atlas.atlas_count != 1:
        vm, idx, uvs = xatlas.parametrize(np.ascontiguousarray(uniq, np.float32), inv.reshape(-1, 3).astype(np.uint32))
    else:
        vm, idx, uvs = atlas[0]
    return uvs[idx].astype(np.float32)


def lightmap_texels(scene, res: int) -> dict:
    """Lay out the lightmap and find its texels' surface points.

    scene : NormalizedScene (TEXCOORD_1 charts: :meth:`workers.scene.NormalizedScene.texcoord1`); res : texels
    per side. Returns ``{"uv" (T, 3, 2) float32 lightmap UVs, "tri" (res, res) int32, "covered" (res, res) bool,
    "position" (world space, metres), "normal": (L, 3) float32 of the covered texels in row-major order,
    "source" ("texcoord1", "xatlas" or "texcoord1+xatlas"), "texels_per_metre", "warnings" (list of str)}``.
    """
    T = scene.n_triangles
    warnings = []
    tc = scene.texcoord1()
    if tc is None:
        uv, chart = np.zeros((T, 3, 2), np.float32), np.full(T, -1, np.int64)
    else:
        uv, chart = np.array(tc[0], np.float32), np.array(tc[1], np.int64)
    missing = chart < 0
    source = "texcoord1" if not missing.any() else ("xatlas" if missing.all() else "texcoord1+xatlas")
    if missing.any():
        gen = _xatlas_uv(np.asarray(scene.triangles)[missing], res)
        if gen is None:
            warnings.append(f"xatlas is not installed: {int(missing.sum())} triangles without TEXCOORD_1 "
                            "are left out of the lightmap")
        else:
            uv[missing] = gen
            chart[missing] = int(chart.max(initial=-1)) + 1
    atlas_uv, density = chart_layout(scene.triangles, uv, chart, res, padding=LIGHTMAP_PADDING)
    tri, bary = rasterize(atlas_uv, res)
    covered = tri >= 0
    s = surface_at_hits(scene, tri[covered], bary[covered, 0], bary[covered, 1])
    return {"uv": atlas_uv, "tri": tri, "covered": covered, "position": s["position"], "normal": s["normal"],
            "source": source, "texels_per_metre": density, "warnings": warnings}
