"""The reference at G-buffer pixels and points (workers/kernels/reference.py), closed forms."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from workers.kernels.reference import exitant_radiance


def test_exitant_radiance_is_emission_plus_albedo_over_pi_times_irradiance():
    gb = SimpleNamespace(emission=np.full((2, 2, 3), 0.5, np.float32), albedo=np.full((2, 2, 3), 0.25, np.float32),
                         shaded=np.array([[True, False], [True, True]]))
    e_dir, e_ind = np.full((2, 2, 3), 2.0), np.full((2, 2, 3), 1.0)
    out = exitant_radiance(gb, e_dir, e_ind)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0, 0], 0.5 + 0.25 / math.pi * 3.0, rtol=1e-6)
    np.testing.assert_array_equal(out[0, 1], 0.0)                      # not shaded (a back face, no geometry)


def _far_triangle():
    from tests.kernels.test_pathtrace import _material, _scene

    return _scene([[[0, -1000, 0], [0.001, -1000, 0], [0, -1000, 0.001]]], [_material(0.5)])


def test_irradiance_at_points_open_sky_is_pi_l_exactly():
    """Every path misses: E_indirect = π·L per path, so the estimate is exact with standard error 0; the direct
    light is :func:`direct_irradiance`'s; one batch per ``batch_points`` points."""
    from workers.kernels.reference import irradiance_at_points
    from workers.kernels.shading import direct_irradiance
    from workers.raycast import RayCaster

    s = _far_triangle()
    pts = np.array([[0, 0, 0], [1, 2, 3], [5, 0, 0.0]])
    nrm = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    light = [{"type": "point", "position": [0, 3, 0], "intensity": 9.0, "color": [1, 1, 1], "range": None}]
    seen = []
    e_dir, e_ind, err, stats = irradiance_at_points(s, pts, nrm, nrm, light, sky=(0.5, 1.0, 2.0), spp=16, bounces=2,
                                                    eps=1e-4, batch_points=2, report=seen.append)
    np.testing.assert_allclose(e_ind, np.tile(math.pi * np.array([0.5, 1.0, 2.0]), (3, 1)), rtol=1e-6)
    np.testing.assert_allclose(err, 0.0, atol=1e-12)                   # (rounding of a variance of equal terms)
    np.testing.assert_allclose(e_dir, direct_irradiance(pts, nrm, light, RayCaster(s.triangles), 1e-4))
    assert e_dir[0, 0] == pytest.approx(1.0)                          # 9 cd at 3 m, facing it: 9/9 lux
    assert stats["batches"] == 2 and stats["rays"] > 0 and seen[-1] == 1.0


def test_irradiance_at_points_of_nothing():
    from workers.kernels.reference import irradiance_at_points

    seen = []
    e_dir, e_ind, err, stats = irradiance_at_points(_far_triangle(), np.zeros((0, 3)), np.zeros((0, 3)),
                                                    np.zeros((0, 3)), report=seen.append)
    assert e_dir.shape == e_ind.shape == err.shape == (0, 3) and stats == {} and seen == [1.0]


def test_refine_dark_pools_more_paths_where_the_reference_is_dark():
    """Points at most DARK_FRACTION of the mean luminance get dark_spp - spp more paths, pooled by path count."""
    from workers.kernels.reference import DARK_FRACTION, refine_dark

    e = np.array([[1.0] * 3, [1.0] * 3, [0.05] * 3, [0.001] * 3])       # mean 0.51: 2 and 3 are dark
    s = np.full((4, 3), 0.04)
    asked = []

    def trace(idx, n):
        asked.append((idx.tolist(), n))
        return np.full((len(idx), 3), 0.02), np.full((len(idx), 3), 0.01)

    e2, s2, idx = refine_dark(trace, e, s, 64, 1024)
    assert 0.05 <= DARK_FRACTION * 0.51 and asked == [([2, 3], 960)] and idx.tolist() == [2, 3]
    np.testing.assert_allclose(e2[2], (64 * 0.05 + 960 * 0.02) / 1024)
    np.testing.assert_allclose(e2[3], (64 * 0.001 + 960 * 0.02) / 1024)
    np.testing.assert_allclose(s2[3], np.sqrt((64 * 0.04) ** 2 + (960 * 0.01) ** 2) / 1024)
    np.testing.assert_array_equal(e2[:2], e[:2])
    # nothing more when dark_spp <= spp, or nothing is dark
    assert refine_dark(trace, e, s, 64, 64)[2].size == 0 and len(asked) == 1
    assert refine_dark(trace, np.ones((3, 3)), s[:3], 64, 1024)[2].size == 0 and len(asked) == 1
