"""Ray direction patterns for probe tracing (DDGI-I §3.2, DDGI-P §2.3).

Each probe casts a spherical Fibonacci pattern (Keinert et al. 2015, DDGI-I ref [9]) under a uniformly random
rotation (DDGI-P §2.3: "rotating the pattern randomly every frame", so that successive frames sample different
directions). Offline there is one frame: a rotation shared by every probe makes every probe miss, or catch, the same
small bright openings in the same way, an error that interpolation and the bounces then add up instead of averaging
out. :class:`ProbeRays` gives neighbouring probes different rotations instead (:func:`pattern_of_grid`: the 8
corners of every grid cell differ).

Frames: directions are unit vectors in world space (glTF frame, +Y up); the pattern itself
has its polar axis along +Z, which does not matter once it is randomly rotated.

Consumers: stages/trace (probe rays), kernels/octahedral and kernels/sh (Monte Carlo weights
4π/n for the uniform pattern). Inverse: none.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.kernels.grid import probe_grid_indices

__all__ = ["fibonacci_sphere", "random_rotation", "rotated_directions", "ProbeRays", "probe_rays",
           "rotated_patterns", "pattern_of_grid"]

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


@dataclass
class ProbeRays:
    """The ray directions of every probe: K rotated copies of one pattern, probe p casting ``patterns[pattern[p]]``.

    ``patterns`` (K, R, 3) float32 unit directions, world space (the bake frame in a turned bake); ``pattern`` (P,)
    integer, each probe's pattern. K = 1 is the DDGI runtime's one rotation for all probes. Flat ray index
    ``p·R + r`` (the trace stage's (P, R) arrays, raveled) is probe p's ray r.
    """

    patterns: np.ndarray
    pattern: np.ndarray

    @property
    def rays(self) -> int:
        """R, rays per probe."""
        return int(self.patterns.shape[1])

    def groups(self) -> list[tuple[int, np.ndarray]]:
        """``[(k, probe indices (n_k,) int64)]`` for every pattern some probe casts, k ascending."""
        order = np.argsort(self.pattern, kind="stable")
        ks, starts = np.unique(self.pattern[order], return_index=True)
        bounds = list(starts[1:]) + [order.size]
        return [(int(k), order[a:b]) for k, a, b in zip(ks, starts, bounds)]

    def of_rays(self, index) -> np.ndarray:
        """(H, 3) float32 directions of the flat ray indices ``index`` (H,) (``p·R + r``)."""
        index = np.asarray(index, np.int64)
        R = self.rays
        if self.patterns.shape[0] == 1:
            return self.patterns[0][index % R]
        return self.patterns[self.pattern[index // R], index % R]

    def of_probes(self, a: int, b: int) -> np.ndarray:
        """(b − a, R, 3) float32 directions of probes a..b."""
        return self.patterns[self.pattern[a:b]]

    def per_pattern(self, fn, values) -> np.ndarray:
        """``fn(directions (R, 3), values of the probes casting them (n, R, ...)) -> (n, ...)`` applied to each
        pattern's probes, the results put back in probe order: (P, ...) of ``fn``'s dtype (one call with one pattern)."""
        groups = self.groups()
        if len(groups) == 1:
            return fn(self.patterns[groups[0][0]], values)
        out = None
        for k, idx in groups:
            r = fn(self.patterns[k], values[idx])
            out = np.empty((len(self.pattern),) + r.shape[1:], r.dtype) if out is None else out
            out[idx] = r
        return out


def probe_rays(dirs, probes: int) -> ProbeRays:
    """``dirs`` as :class:`ProbeRays` for ``probes`` probes: a ProbeRays as it is, an (R, 3) array as the one
    pattern of every probe."""
    if isinstance(dirs, ProbeRays):
        if dirs.pattern.shape != (probes,):
            raise ValueError(f"probe_rays: {dirs.pattern.shape[0]} probe patterns for {probes} probes")
        return dirs
    d = np.asarray(dirs, np.float32)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"probe_rays: dirs must have shape (R, 3), got {d.shape}")
    return ProbeRays(d[None], np.zeros(int(probes), np.int64))


def rotated_patterns(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    """(k, n, 3) float32: the Fibonacci pattern of ``n`` directions under ``k`` independent uniformly random
    rotations (:func:`random_rotation` of ``rng``, in order; :func:`rotated_directions`)."""
    return np.stack([rotated_directions(n, random_rotation(rng)) for _ in range(int(k))])


def pattern_of_grid(counts, k: int) -> np.ndarray:
    """(P,) int64 pattern of each probe of a grid of ``counts`` (nx, ny, nz) probes (flattened C order from (nz, ny,
    nx)) among ``k`` patterns: the parity of its grid index, ``(i & 1) + 2 (j & 1) + 4 (k & 1)``, so that the 8
    corners of every cell cast 8 different patterns (k ≥ 8), plus 8 × a hash of the 2×2×2 block the probe is in
    (k ≥ 16), modulo k."""
    ii, jj, kk = probe_grid_indices(counts).T
    parity = (ii & 1) + 2 * (jj & 1) + 4 * (kk & 1)
    blocks = max(int(k) // 8, 1)
    h = ((ii >> 1) * 73856093) ^ ((jj >> 1) * 19349663) ^ ((kk >> 1) * 83492791)
    return (parity + 8 * (h % blocks)) % max(int(k), 1)
