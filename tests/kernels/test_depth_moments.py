"""Depth moments (workers/kernels/depth_moments.py, DDGI-I §3.5 eq 2, DDGI-P §4.1)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels.depth_moments import BACKFACE_SHORTEN, depth_moments, max_ray_distance
from workers.kernels.sampling import fibonacci_sphere

DIRS = fibonacci_sphere(256).astype(np.float32)


@pytest.mark.parametrize("n, sharpness", [(4, 1.0), (8, 50.0)])
def test_constant_distance_gives_l_and_l_squared_everywhere(n, sharpness):
    """A weighted mean of a constant is that constant: l = 2 m, l² = 4 m² in every texel and border texel."""
    t = np.full((3, DIRS.shape[0]), 2.0, np.float32)
    m = depth_moments(t, np.zeros(t.shape, bool), DIRS, n, sharpness, max_distance=10.0)
    assert m.shape == (3, n + 2, n + 2, 2) and m.dtype == np.float32
    np.testing.assert_allclose(m[..., 0], 2.0, rtol=1e-5)
    np.testing.assert_allclose(m[..., 1], 4.0, rtol=1e-5)


def test_misses_at_max_distance_and_back_faces_shortened():
    R = DIRS.shape[0]
    t = np.stack([np.full(R, np.inf), np.full(R, 5.0), np.full(R, 50.0)]).astype(np.float32)
    back = np.array([[False] * R, [True] * R, [True] * R])
    m = depth_moments(t, back, DIRS, 4, 10.0, max_distance=8.0)
    np.testing.assert_allclose(m[0, ..., 0], 8.0, rtol=1e-5)                       # miss: max_distance
    np.testing.assert_allclose(m[1, ..., 0], 5.0 * BACKFACE_SHORTEN, rtol=1e-5)    # back face: −80%
    np.testing.assert_allclose(m[2, ..., 0], 8.0, rtol=1e-5)                       # 10 m clamped to 8


def test_max_ray_distance():
    # bounds [0, 1]³ joined with the grid box [0, 2] × {0} × {0}: diagonal of [0, 2] × [0, 1] × [0, 1]
    assert max_ray_distance([[0, 0, 0], [1, 1, 1]], [3, 1, 1], [0, 0, 0], [1, 0, 0]) == pytest.approx(math.sqrt(6))
    assert max_ray_distance([[0, 0, 0], [0, 0, 0]], [1, 1, 1], [0, 0, 0], [0, 0, 0]) == 1e-3   # floor
