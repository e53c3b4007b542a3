"""Ray direction patterns for probe tracing (DDGI-I §3.2, DDGI-P §2.3).

Each probe casts the same spherical Fibonacci pattern (Keinert et al. 2015, DDGI-I ref [9]),
rotated by one uniformly random rotation per iteration so that successive iterations sample
different directions (DDGI-P §2.3: "rotating the pattern randomly every frame").

Frames: directions are unit vectors in world space (glTF frame, +Y up); the pattern itself
has its polar axis along +Z, which does not matter once it is randomly rotated.

Consumers: stages/trace (probe rays), kernels/octahedral and kernels/sh (Monte Carlo weights
4π/n for the uniform pattern). Inverse: none.
"""
from __future__ import annotations

import numpy as np

__all__ = ["fibonacci_sphere", "random_rotation", "rotated_directions"]

_GOLDEN_RATIO = (1.0 + np.sqrt(5.0)) / 2.0  # φ = 1.618034


def fibonacci_sphere(n: int) -> np.ndarray:
    """Spherical Fibonacci point set: ``n`` near-uniform unit directions.

    Same formula as RTXGI's ``SphericalFibonacci(i, n)`` (the DDGI reference code):
    ``φ_i = 2π·frac(i·(Φ − 1))``, ``cos θ_i = 1 − (2i + 1)/n``.

    Parameters
    ----------
    n : int
        Number of directions, ``n >= 1``.

    Returns
    -------
    dirs : (n, 3) float32
        Unit vectors, polar axis +Z. Each point owns an equal area 4π/n of the sphere,
        so the uniform Monte Carlo weight of a direction is ``4π / n`` (steradians).

    Notes
    -----
    Computed in float64 and rounded once to float32. The z components are symmetric
    about 0 (their mean is exactly 0 up to rounding); x and y means are O(1/n).

    References
    ----------
    .. [Keinert] B. Keinert et al., "Spherical Fibonacci Mapping", ACM TOG 34(6), 2015.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"fibonacci_sphere: n must be >= 1, got {n}")
    return _fibonacci_sphere(n)


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n, dtype=np.float64)
    phi = 2.0 * np.pi * np.mod(i * (_GOLDEN_RATIO - 1.0), 1.0)  # azimuth, golden-angle steps
    cos_theta = 1.0 - (2.0 * i + 1.0) / n  # equal-area bands in z
    sin_theta = np.sqrt(np.clip(1.0 - cos_theta * cos_theta, 0.0, 1.0))
    out = np.stack([np.cos(phi) * sin_theta, np.sin(phi) * sin_theta, cos_theta], axis=-1)
    return out.astype(np.float32)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation drawn uniformly (Haar measure) from SO(3).

    Uses a uniformly distributed unit quaternion (normalized 4D Gaussian, Shoemake 1992),
    which is uniform on SO(3). Used once per trace iteration to rotate the Fibonacci
    pattern (DDGI-P §2.3).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness; the same seeded generator state gives the same rotation.

    Returns
    -------
    rotation : (3, 3) float64
        Proper rotation matrix (orthonormal, det = +1), acting on column vectors:
        ``world = rotation @ pattern``.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"random_rotation: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    q = rng.standard_normal(4)
    norm = np.linalg.norm(q)
    while norm < 1e-12:  # probability ~0; keeps the quaternion well defined
        q = rng.standard_normal(4)
        norm = np.linalg.norm(q)
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )


def rotated_directions(n: int, rotation: np.ndarray) -> np.ndarray:
    """The Fibonacci pattern of ``n`` directions rotated by ``rotation``.

    Parameters
    ----------
    n : int
        Number of directions.
    rotation : (3, 3) array_like
        Rotation matrix acting on column vectors (e.g. from :func:`random_rotation`);
        pass ``np.eye(3)`` for the unrotated pattern.

    Returns
    -------
    dirs : (n, 3) float32
        ``rotation @ fibonacci_sphere(n)[i]`` for each i, renormalized to unit length
        after rounding to float32. World space.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3):
        raise ValueError(f"rotated_directions: rotation must have shape (3, 3), got {r.shape}")
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ValueError("rotated_directions: rotation must be a proper orthonormal matrix (R Rᵀ = I, det R = +1)")
    d = fibonacci_sphere(n).astype(np.float64) @ r.T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d.astype(np.float32)
