"""Lightmap texels to surface points (workers/kernels/texels.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.kernels.test_pathtrace import _material, _scene
from workers.kernels.shading import surface_at_hits
from workers.kernels.texels import texel_surfaces


def test_texel_surfaces_quad():
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    tx = texel_surfaces(uv, 8, 4)
    assert len(tx["rows"]) == 32          # every texel centre lies in exactly one of the two triangles
    # map UV to positions x = u, z = v on a quad and check the barycentric interpolation
    tris = np.concatenate([uv, np.zeros((2, 3, 1))], axis=2)[:, :, [0, 2, 1]]
    s = _scene(tris, [_material(0.5)])
    p = surface_at_hits(s, tx["tri"], tx["u"], tx["v"])["position"]
    np.testing.assert_allclose(p[:, 0], (tx["cols"] + 0.5) / 8, atol=1e-6)
    np.testing.assert_allclose(p[:, 2], (tx["rows"] + 0.5) / 4, atol=1e-6)


def test_texel_surfaces_first_triangle_wins_and_ids_map():
    """Overlapping footprints: the first triangle in order owns the texel; ``triangle_ids`` renames rows."""
    tri = [[0, 0], [1, 0], [0, 1]]
    uv = np.array([tri, tri], float)
    tx = texel_surfaces(uv, 4, 4, triangle_ids=[7, 9])
    assert len(tx["rows"]) == 10 and set(tx["tri"].tolist()) == {7}   # 4+3+2+1 centres below the diagonal
    np.testing.assert_allclose(tx["u"], (tx["cols"] + 0.5) / 4)        # x = u·v1 + v·v2 with v1 = (1, 0)
    np.testing.assert_allclose(tx["v"], (tx["rows"] + 0.5) / 4)


def test_texel_surfaces_validation():
    with pytest.raises(ValueError, match="uv must be"):
        texel_surfaces(np.zeros((2, 3, 3)), 4, 4)
