"""Depth moments (workers/kernels/depth_moments.py, DDGI-I §3.5 eq 2, DDGI-P §4.1)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels.ddgi import NORMAL_BIAS, VIEW_BIAS, bias_scale, sample_irradiance
from workers.kernels.depth_moments import BACKFACE_SHORTEN, clamp_far, depth_moments, max_ray_distance, reach
from workers.kernels.grid import ACTIVE, OFF, base_positions, cage_indices, cell_coords
from workers.kernels.octahedral import add_border
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


# --------------------------------------------------------------------------- far clamp (issue 17)

COUNTS = np.array([4, 3, 5])
ORIGIN = np.array([-1.0, 0.5, -2.0])
SPACING = np.array([1.0, 0.7, 1.3])
TOP = ORIGIN + SPACING * (COUNTS - 1)
BOUNDS = np.array([ORIGIN - [0.6, 0.3, 1.1], TOP + [0.4, 0.9, 0.2]])     # the scene reaches past the grid box


def _grid(rng):
    """Relocated positions (up to 0.45 spacing off the grid) and the reach of each probe (B = 0.3)."""
    pos = base_positions(COUNTS, ORIGIN, SPACING) + rng.uniform(-0.45, 0.45, (int(COUNTS.prod()), 3)) * SPACING
    bias = bias_scale(SPACING, 0.3)
    return pos, bias, reach(pos, COUNTS, ORIGIN, SPACING, bias, BOUNDS)


def _unit(rng, n):
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _shading_points(rng, n):
    """Points anywhere in the scene bounds, random unit normals and view directions."""
    return rng.uniform(BOUNDS[0], BOUNDS[1], (n, 3)), _unit(rng, n), _unit(rng, n)


def test_reach_bounds_the_distance_from_every_cage_probe_to_the_biased_point():
    """x_b = x + (0.2·n + 0.8·ω_o)·bias (DDGI-P eq 2) for x in the scene bounds: every probe of x_b's cage
    (clamped to the grid's border cells outside it) is at most its reach away, and the bound is not loose."""
    rng = np.random.default_rng(3)
    pos, bias, lim = _grid(rng)
    x, n, v = _shading_points(rng, 200000)
    xb = x + (NORMAL_BIAS * n + VIEW_BIAS * v) * bias
    base, _ = cell_coords(xb, COUNTS, ORIGIN, SPACING)
    cage = cage_indices(base, COUNTS)                                       # (N, 8)
    r = np.linalg.norm(xb[:, None, :] - pos[cage], axis=-1)
    ratio = r / lim[cage]
    assert ratio.max() <= 1.0 and ratio.max() > 0.8
    # outside the grid box the cage is the border cell's: probe 0's region reaches the scene bounds' corner
    assert lim[0] >= np.linalg.norm(pos[0] - BOUNDS[0] + bias)


def _moments(rng, lim, m=8):
    """(P, m+2, m+2, 2) depth moments (with their octahedral border) mixing near texels (below the reach) and far
    ones (beyond it), so that both lone far texels and far regions occur."""
    P = len(lim)
    near = rng.uniform(0.05, 1.0, (P, m, m)) * lim[:, None, None]
    far = rng.uniform(1.0, 20.0, (P, m, m)) * lim[:, None, None]
    pick = rng.uniform(size=(P, 1, 1)) < 0.3                                # some probes mostly near
    is_far = rng.uniform(size=near.shape) < np.where(pick, 0.3, 0.85)
    mean = np.where(is_far, far, near)
    mean2 = mean * mean * (1 + rng.uniform(0, 0.3, mean.shape))           # E[d²] ≥ E[d]²
    return add_border(np.stack([mean, mean2], axis=-1).astype(np.float32))


def test_clamp_far_keeps_the_ddgi_irradiance_identical():
    """The DDGI sampler (the Python twin of mode_ddgi.glsl) gives bit-identical irradiance with the clamped
    moments at points anywhere in the scene bounds, in float32 and in half floats (the stored format), while most
    texels turn constant. Clamping the far texels alone (without the 3x3 rule) would change it."""
    rng = np.random.default_rng(5)
    pos, _, lim = _grid(rng)
    P = len(pos)
    dep = _moments(rng, lim)
    clamped, share = clamp_far(dep, lim)
    assert 0.1 < share < 0.9
    assert np.all(clamped[..., 0] <= dep[..., 0]) and np.all((clamped == dep) | (clamped[..., :1] >= lim[:, None, None, None]))
    assert np.array_equal(add_border(clamped[:, 1:-1, 1:-1]), clamped)   # the border still copies the interior
    states = np.full(P, ACTIVE, np.uint8)
    states[rng.choice(P, 5, replace=False)] = OFF
    irr = rng.uniform(0.1, 10.0, (P, 10, 10, 3)).astype(np.float32)
    x, n, v = _shading_points(rng, 40000)

    def ddgi(d):
        return sample_irradiance(x, n, v, COUNTS, ORIGIN, SPACING, pos, states, irr, d, 0.3)

    for a, b in ((dep, clamped), (dep.astype(np.float16).astype(np.float32), clamped.astype(np.float16).astype(np.float32))):
        want, got = ddgi(a), ddgi(b)
        assert np.array_equal(got, want)
    # the test sees the difference: per-texel clamping without the neighbourhood rule changes points
    naive = dep.copy()
    cut = dep[..., 0] >= lim[:, None, None]
    naive[..., 0] = np.where(cut, lim[:, None, None], dep[..., 0])
    naive[..., 1] = np.where(cut, lim[:, None, None] ** 2, dep[..., 1])
    assert (np.abs(ddgi(naive) - ddgi(dep)).max(axis=1) > 0).mean() > 0.001


def test_clamp_far_rounds_the_reach_up_to_a_half_float():
    lim = np.array([4.3578, 1.0])                                  # 4.3578 is between two halves; 1.0 is one
    dep = np.full((2, 3, 3, 2), 100.0, np.float32)
    out, share = clamp_far(dep, lim)
    assert share == 1.0
    stored = out[..., 0].astype(np.float16).astype(np.float64)
    assert np.all(stored[0] >= 4.3578) and stored[0, 0, 0] - 4.3578 < 4.3578 * 2.0 ** -10 and np.all(stored[1] == 1.0)
    assert np.array_equal(out[..., 1], out[..., 0] ** 2)
