"""PRT's lightmap target (workers/kernels/lightmap.py): chart layout, rasterization, dilation, texels."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import lightmap as k

UNIT_SQUARE = np.array([[[0, 0, 0], [1, 0, 0], [1, 0, 1]], [[0, 0, 0], [1, 0, 1], [0, 0, 1]]], np.float64)


def test_chart_layout_uniform_density_and_no_overlap():
    # two charts with the same UV square but different world sizes, and a triangle without a chart
    big = UNIT_SQUARE * 2.0
    small = UNIT_SQUARE * 0.5 + [3, 0, 0]
    tris = np.concatenate([big, small, UNIT_SQUARE[:1] + [9, 0, 0]])
    uv = np.tile(np.array([[0, 0], [1, 0], [1, 1]], np.float64), (5, 1, 1))
    uv[1] = uv[3] = [[0, 0], [1, 1], [0, 1]]
    chart = np.array([0, 0, 5, 5, -1])
    atlas, rho = k.chart_layout(tris, uv, chart, 64, padding=2)
    assert rho > 0 and np.all(atlas[4] == 0)
    assert np.all(atlas[:4] >= 0) and np.all(atlas[:4] <= 1)
    box = lambda s: (atlas[s].reshape(-1, 2).min(0), atlas[s].reshape(-1, 2).max(0))  # noqa: E731
    (a0, a1), (b0, b1) = box(slice(0, 2)), box(slice(2, 4))
    assert np.any(a1 < b0) or np.any(b1 < a0)          # disjoint boxes
    assert np.allclose((a1 - a0) / (b1 - b0), 4.0, rtol=0.05)   # same texels per metre: 2 m vs 0.5 m
    tri_map, bary = k.rasterize(atlas, 64)
    covered = tri_map >= 0
    assert set(np.unique(tri_map[covered])) == {0, 1, 2, 3}
    # texel centres map back into their triangle: barycentric reconstruction of the atlas uv
    r, c = np.nonzero(covered)
    t = tri_map[r, c]
    b = np.stack([1 - bary[r, c, 0] - bary[r, c, 1], bary[r, c, 0], bary[r, c, 1]], 1)
    uvc = np.einsum("nk,nkd->nd", b, atlas[t].astype(np.float64)) * 64
    assert np.allclose(uvc, np.stack([c + 0.5, r + 0.5], 1), atol=1e-3)


def test_dilate_is_linear_and_fills_neighbours():
    mask = np.zeros((8, 8), bool)
    mask[3:5, 3:5] = True
    rng = np.random.default_rng(0)
    a, b = rng.random((8, 8)), rng.random((8, 8))
    da, m = k.dilate(a * mask, mask, 2)
    db, _ = k.dilate(b * mask, mask, 2)
    dab, _ = k.dilate((2 * a + 3 * b) * mask, mask, 2)
    assert np.allclose(dab, 2 * da + 3 * db, atol=1e-6)
    assert m[1:7, 1:7].all() and not m[0].any()
    assert np.allclose(da[mask], a[mask])
    assert np.isclose(da[2, 2], a[3, 3])                 # a corner neighbour sees one filled texel


def test_lightmap_texels_from_texcoord1():
    from workers.scene import NormalizedScene

    tris = (UNIT_SQUARE * 2.0).astype(np.float32)                     # a 2 m x 2 m square at y = 0
    uv1 = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    mat = {"name": "m", "base_color": [1, 1, 1, 1], "base_color_texture": None, "emissive": [0, 0, 0],
           "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 1.0}
    scene = NormalizedScene(triangles=tris, normals=np.tile(np.float32([0, -1, 0]), (2, 3, 1)),
                            uv0=np.zeros((2, 3, 2), np.float32), material=np.zeros(2, np.int32), materials=[mat],
                            uv1=uv1, uv1_chart=np.zeros(2, np.int32))
    lm = k.lightmap_texels(scene, 16)
    assert lm["source"] == "texcoord1" and lm["warnings"] == [] and lm["uv"].shape == (2, 3, 2)
    cov = lm["covered"]
    L = int(cov.sum())
    assert lm["position"].shape == (L, 3) and lm["normal"].shape == (L, 3) and 64 < L <= 256
    assert np.allclose(lm["position"][:, 1], 0) and np.all((lm["position"] >= -1e-5) & (lm["position"] <= 2 + 1e-5))
    assert lm["texels_per_metre"] == pytest.approx((16 - 4) / 2, rel=0.1)   # 16 texels less 2 x 2 padding over 2 m
    assert np.array_equal(lm["tri"] >= 0, cov)


def test_lightmap_texels_unwrap_with_xatlas_without_texcoord1():
    pytest.importorskip("xatlas")
    from workers.scene import NormalizedScene

    tris = (UNIT_SQUARE * 2.0).astype(np.float32)
    mat = {"name": "m", "base_color": [1, 1, 1, 1], "base_color_texture": None, "emissive": [0, 0, 0],
           "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 1.0}
    scene = NormalizedScene(triangles=tris, normals=np.tile(np.float32([0, -1, 0]), (2, 3, 1)),
                            uv0=np.zeros((2, 3, 2), np.float32), material=np.zeros(2, np.int32), materials=[mat])
    lm = k.lightmap_texels(scene, 16)
    assert lm["source"] == "xatlas" and lm["covered"].sum() > 32 and lm["texels_per_metre"] > 0
    assert np.all(lm["uv"] >= 0) and np.all(lm["uv"] <= 1)
