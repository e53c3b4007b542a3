"""Ray patterns (workers/kernels/sampling.py): Fibonacci sphere and random rotations."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels.sampling import fibonacci_sphere, random_rotation, rotated_directions

SIZES = [1, 2, 16, 64, 256, 1024, 4096]


@pytest.mark.parametrize("n", SIZES)
def test_fibonacci_unit_float32(n):
    d = fibonacci_sphere(n)
    assert d.shape == (n, 3) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d.astype(np.float64), axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("n", [16, 64, 256, 1024, 4096])
def test_fibonacci_well_spread(n):
    d = fibonacci_sphere(n).astype(np.float64)
    # mean direction ≈ 0 (z is exactly symmetric, x and y are O(1/n))
    assert np.abs(d.mean(axis=0)).max() <= 1.0 / n
    # nearest-neighbour angle ≥ 3/√n (the set reaches ≈ 3.09/√n; i.i.d. uniform points reach ~1/n)
    c = d @ d.T
    np.fill_diagonal(c, -1.0)
    min_angle = np.arccos(np.clip(c.max(), -1, 1))
    assert min_angle * np.sqrt(n) >= 3.0
    # equal-area bands: the fraction of points above z0 is (1 - z0)/2 to within 1/n
    for z0 in (-0.7, -0.2, 0.0, 0.35, 0.9):
        assert abs((d[:, 2] > z0).mean() - (1 - z0) / 2) <= 1.0 / n + 1e-12


def test_fibonacci_rejects_bad_n():
    with pytest.raises(ValueError):
        fibonacci_sphere(0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_rotation_is_proper_and_seeded(seed):
    r = random_rotation(np.random.default_rng(seed))
    assert r.shape == (3, 3)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(r, random_rotation(np.random.default_rng(seed)))


def test_random_rotation_is_haar_uniform():
    rng = np.random.default_rng(7)
    rs = np.stack([random_rotation(rng) for _ in range(4000)])
    # Haar measure on SO(3): E[tr R] = 0 (Var = 1), and R e_z is uniform on the sphere
    assert abs(np.trace(rs, axis1=1, axis2=2).mean()) < 0.08
    ez = rs[:, :, 2]
    assert np.abs(ez.mean(axis=0)).max() < 0.05
    np.testing.assert_allclose((ez**2).mean(axis=0), 1 / 3, atol=0.03)


@pytest.mark.parametrize("seed", [0, 5])
def test_rotated_directions(seed):
    r = random_rotation(np.random.default_rng(seed))
    d = rotated_directions(256, r)
    assert d.dtype == np.float32 and d.shape == (256, 3)
    np.testing.assert_allclose(d, fibonacci_sphere(256).astype(np.float64) @ r.T, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(d.astype(np.float64), axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(rotated_directions(64, np.eye(3)), fibonacci_sphere(64))


def test_rotated_directions_rejects_non_rotations():
    with pytest.raises(ValueError):
        rotated_directions(8, np.diag([1.0, 1.0, -1.0]))  # reflection
    with pytest.raises(ValueError):
        rotated_directions(8, 2 * np.eye(3))
    with pytest.raises(ValueError):
        rotated_directions(8, np.eye(2))
