"""Real spherical harmonics up to L2: basis, Monte Carlo projection of radiance, irradiance.

Probe radiance is projected onto SH per probe (DESIGN stage 2: the volume-texture form that
leaking probe GI and MD need) and shaded as irradiance with the clamped-cosine convolution of
Ramamoorthi & Hanrahan 2001 (eq 7-8 there): E(n) = Σ_lm Â_l L_lm Y_lm(n).

Coefficient order and constants (three.js ``SphericalHarmonics3``; x, y, z are the components
of a unit direction in world space, glTF frame +Y up; the GLSL in proto/glsl uses the same):

====  =====  ==================================  ===========================
 k    (l,m)   Y_k(x, y, z)                        constant
====  =====  ==================================  ===========================
 0    (0, 0)  c0                                  c0 = 1/(2√π)      = 0.282095
 1    (1,-1)  c1 · y                              c1 = √(3/(4π))    = 0.488603
 2    (1, 0)  c1 · z
 3    (1, 1)  c1 · x
 4    (2,-2)  c2 · x y                            c2 = ½√(15/π)     = 1.092548
 5    (2,-1)  c2 · y z
 6    (2, 0)  c3 · (3 z² − 1)                     c3 = ¼√(5/π)      = 0.315392
 7    (2, 1)  c2 · x z
 8    (2, 2)  c4 · (x² − y²)                      c4 = ¼√(15/π)     = 0.546274
====  =====  ==================================  ===========================

L1 uses k = 0..3 (4 coefficients), L2 all 9. The basis is orthonormal on the sphere:
∫ Y_k Y_j dω = δ_kj.

Cosine-lobe convolution (Ramamoorthi & Hanrahan 2001, eq 8): Â0 = π, Â1 = 2π/3, Â2 = π/4, so
that constant radiance L gives E = π·L. Folded constants as in three.js ``getIrradianceAt``:
π·c0 = 0.886227, (2π/3)·c1 = 1.023328, (π/4)·c2 = 0.858086, (π/4)·c3 = 0.247708,
(π/4)·c4 = 0.429043.

L2 volumes (``sh_l2``, proto/bundle.md 5.1): three.js ``LightProbeGrid`` layout, :func:`sh_l2_atlas` —
the 27 numbers of a probe (coefficient k major, colour minor: c0.rgb, c1.rgb, ..., c8.rgb, then one 0) in 7
RGBA texels, each of the 7 a probe sub-volume of nz + 2 z slices (one padding slice, a copy of the nearest
data slice, at each end) stacked along z: one 3D texture, 7 fetches. :func:`sh_l2_sample` reads it as the GLSL
does (``gi_grid.glsl`` ``giPaddedStackedUVW``, ``sh.glsl`` ``shIrradianceL2Packed``).

Consumers: stages/light (projection), stages/evaluate and proto/glsl (irradiance).

References
----------
.. [RH01] R. Ramamoorthi, P. Hanrahan, "An Efficient Representation for Irradiance
   Environment Maps", SIGGRAPH 2001.
"""
from __future__ import annotations

import numpy as np

from workers.kernels.sampling import fibonacci_sphere, probe_rays

__all__ = [
    "SH_C0",
    "SH_C1",
    "SH_C2",
    "SH_C3",
    "SH_C4",
    "SH_BAND_CONVOLUTION",
    "sh_count",
    "sh_basis",
    "sh_project",
    "sh_project_probes",
    "sh_irradiance",
    "sh_irradiance_basis",
    "sh_irradiance_l1_nonlinear",
    "sh_irradiance_l2",
    "SH_L2_TEXELS",
    "sh_l2_atlas",
    "sh_l2_from_atlas",
    "sh_l2_atlas_depth",
    "SH_L2_FLOOR",
    "sh_l2_floor",
    "SH_L2_MARGIN",
    "sh_l2_nonnegative",
]

SH_C0 = 0.5 / np.sqrt(np.pi)  # 0.282095, Y00
SH_C1 = np.sqrt(3.0 / (4.0 * np.pi))  # 0.488603, band 1
SH_C2 = 0.5 * np.sqrt(15.0 / np.pi)  # 1.092548, xy, yz, xz
SH_C3 = 0.25 * np.sqrt(5.0 / np.pi)  # 0.315392, (3z² − 1)
SH_C4 = 0.25 * np.sqrt(15.0 / np.pi)  # 0.546274, (x² − y²)

# Â_l, the clamped-cosine kernel per band (RH01 eq 8): π, 2π/3, π/4.
SH_BAND_CONVOLUTION = np.array([np.pi, 2.0 * np.pi / 3.0, np.pi / 4.0])

_BAND_OF_COEFF = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])


def sh_count(order: int) -> int:
    """Number of coefficients of SH up to band ``order`` (1 -> 4, 2 -> 9)."""
    if order not in (1, 2):
        raise ValueError(f"SH order must be 1 or 2, got {order}")
    return (order + 1) ** 2


def _order_of(count: int) -> int:
    if count == 4:
        return 1
    if count == 9:
        return 2
    raise ValueError(f"SH coefficient count must be 4 (L1) or 9 (L2), got {count}")


def sh_basis(dirs, order: int = 2) -> np.ndarray:
    """Real SH basis functions evaluated at directions, in the order of the module table.

    Parameters
    ----------
    dirs : (..., 3) array_like of float
        Unit directions, world space (not renormalized: pass unit vectors).
    order : {1, 2}
        Highest band.

    Returns
    -------
    y : (..., 4) or (..., 9) float64
    """
    d = np.asarray(dirs, dtype=np.float64)
    if d.shape[-1:] != (3,):
        raise ValueError(f"sh_basis: dirs must have shape (..., 3), got {d.shape}")
    return _sh_basis(d, sh_count(order))


def _sh_basis(d: np.ndarray, count: int) -> np.ndarray:
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    cols = [np.full_like(x, SH_C0), SH_C1 * y, SH_C1 * z, SH_C1 * x]
    if count == 9:
        cols += [SH_C2 * x * y, SH_C2 * y * z, SH_C3 * (3.0 * z * z - 1.0), SH_C2 * x * z, SH_C4 * (x * x - y * y)]
    return np.stack(cols, axis=-1)


def sh_project(dirs, values, weights=None, order: int = 2) -> np.ndarray:
    """Monte Carlo projection of radiance samples onto SH: L_k ≈ Σ_r w_r · L(ω_r) · Y_k(ω_r).

    Parameters
    ----------
    dirs : (R, 3) array_like of float
        Unit sample directions, world space (e.g. a rotated Fibonacci pattern).
    values : (..., R, C) array_like of float
        Radiance per sample and channel (e.g. (P, R, 3) linear RGB, W·sr⁻¹·m⁻² or
        scene units). Must be finite.
    weights : None, float, (R,) or (..., R) array_like
        Solid-angle weight of each sample in steradians. None means uniformly distributed
        samples: 4π / R (right for :func:`workers.kernels.sampling.fibonacci_sphere`).
    order : {1, 2}
        Highest band: 4 or 9 coefficients.

    Returns
    -------
    coeffs : (..., 4 | 9, C) float64
        In the order of the module table. Shade with :func:`sh_irradiance`.
    """
    d = np.asarray(dirs, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"sh_project: dirs must have shape (R, 3), got {d.shape}")
    r_count = d.shape[0]
    if v.ndim < 2 or v.shape[-2] != r_count:
        raise ValueError(f"sh_project: values must have shape (..., {r_count}, C) to match dirs, got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("sh_project: values must be finite")
    if weights is None:
        w = np.full(r_count, 4.0 * np.pi / r_count)  # uniform sphere sampling: 4π/R sr each
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim == 0:
            w = np.full(r_count, float(w))
        if w.shape[-1:] != (r_count,):
            raise ValueError(f"sh_project: weights must be a scalar or have shape (..., {r_count}), got {w.shape}")
    return _sh_project(d, v, w, sh_count(order))


def sh_project_probes(dirs, values, order: int = 2) -> np.ndarray:
    """:func:`sh_project` of each probe's radiance samples on its own direction pattern (uniform weights 4π/R).

    ``dirs``: (R, 3) (every probe the same) or :class:`workers.kernels.sampling.ProbeRays`; ``values`` (P, R, C).
    Returns (P, 4 | 9, C) float64."""
    v = np.asarray(values)
    return probe_rays(dirs, v.shape[0]).per_pattern(lambda d, x: sh_project(d, x, order=order), v)


def _sh_project(d, v, w, count):
    y = _sh_basis(d, count)  # (R, K)
    return np.matmul(y.T, v * w[..., None])  # Σ_r Y_k(ω_r) · w_r · L(ω_r)


def sh_irradiance(coeffs, normals) -> np.ndarray:
    """Irradiance E(n) = Σ_k Â_l(k) · L_k · Y_k(n) from radiance SH (RH01 eq 7-8).

    Parameters
    ----------
    coeffs : (..., 4 | 9, C) array_like of float
        Radiance SH from :func:`sh_project` (L1 or L2, detected from the size of axis -2).
    normals : (..., 3) array_like of float
        Unit surface normals, world space. Leading dimensions broadcast with those of
        ``coeffs`` (e.g. coeffs (9, C) with normals (N, 3), or coeffs (P, 9, C) with (P, 3)).

    Returns
    -------
    irradiance : (..., C) float64
        E in the units of the radiance times sr (W·m⁻² for W·sr⁻¹·m⁻²). Constant radiance L
        gives π·L for every normal. Not clamped: L2 ringing can make it slightly negative.
    """
    c = np.asarray(coeffs, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if c.ndim < 2:
        raise ValueError(f"sh_irradiance: coeffs must have shape (..., 4 | 9, C), got {c.shape}")
    count = c.shape[-2]
    _order_of(count)  # validates 4 or 9
    if n.shape[-1:] != (3,):
        raise ValueError(f"sh_irradiance: normals must have shape (..., 3), got {n.shape}")
    return np.einsum("...k,...kc->...c", sh_irradiance_basis(n, count), c)


def sh_irradiance_basis(normals, count: int = 9) -> np.ndarray:
    """(..., count) float64 ``Â_l · Y_k(n)`` at unit normals (..., 3): E(n) of radiance SH c is ``basis · c``
    (RH01 eq 7, with eq 8's clamped-cosine kernel Â_l = π, 2π/3, π/4). :func:`sh_irradiance`'s kernel; the light
    stage's SH gather keeps it per hit (:mod:`workers.kernels.gather`)."""
    return _sh_basis(np.asarray(normals, np.float64), count) * SH_BAND_CONVOLUTION[_BAND_OF_COEFF[:count]]


def sh_irradiance_l1_nonlinear(coeffs, normals) -> np.ndarray:
    """Non-linear L1 irradiance reconstruction (Hazel 2017, "Reducing the ringing of L1 spherical
    harmonics"; the Geomerics / Enlighten evaluation). The runtime GI modes' default
    (``proto/glsl/sh.glsl`` ``shIrradianceL1``).

    Per colour channel, with ``R0 = Â_0 Y00 L0`` (the mean irradiance) and ``R1 = ½ Â_1 Y1 (L1x, L1y, L1z)``
    (the linear reconstruction is ``R0 + 2 R1·n``)::

        r = min(|R1| / R0, 1),  q = (1 + n·R1/|R1|) / 2,  p = 1 + 2r,  a = (1 − r) / (1 + r)
        E(n) = R0 · (a + (1 − a)(p + 1) q^p)            (0 where R0 ≤ 0; R0 where |R1| ≤ 1e-6 R0)

    Its mean over the sphere is R0, as the linear one's; as r → 0 it tends to the linear one; it is never
    negative, where the linear one rings below zero on the far side of a strongly directional probe.

    coeffs : (..., 4, C) L1 radiance SH (order L0, L1y, L1z, L1x as :func:`sh_project`); normals : (..., 3)
    unit, broadcasting with coeffs' leading dimensions. Returns (..., C) float64.
    """
    c = np.asarray(coeffs, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if c.ndim < 2 or c.shape[-2] != 4:
        raise ValueError(f"sh_irradiance_l1_nonlinear: coeffs must have shape (..., 4, C), got {c.shape}")
    if n.shape[-1:] != (3,):
        raise ValueError(f"sh_irradiance_l1_nonlinear: normals must have shape (..., 3), got {n.shape}")
    r0 = SH_BAND_CONVOLUTION[0] * SH_C0 * c[..., 0, :]                                    # (..., C)
    r1 = 0.5 * SH_BAND_CONVOLUTION[1] * SH_C1 * np.stack([c[..., 3, :], c[..., 1, :], c[..., 2, :]], -1)
    length = np.linalg.norm(r1, axis=-1)                                                  # (..., C)
    pos = r0 > 0
    safe_r0 = np.where(pos, r0, 1.0)
    directional = pos & (length > 1e-6 * np.abs(safe_r0))
    safe_len = np.where(directional, length, 1.0)
    r = np.minimum(length / safe_r0, 1.0)
    q = np.clip(0.5 * (1.0 + np.einsum("...ck,...k->...c", r1, n) / safe_len), 0.0, 1.0)
    p_ = 1.0 + 2.0 * r
    a = (1.0 - r) / (1.0 + r)
    e = r0 * (a + (1.0 - a) * (p_ + 1.0) * q ** p_)
    return np.where(directional, e, np.where(pos, r0, 0.0))


def sh_irradiance_l2(coeffs, normals) -> np.ndarray:
    """L2 irradiance E(n) of 9-coefficient radiance SH (RH01 eq 7-8; what ``sh.glsl`` ``shIrradianceL2`` and
    ``web/src/math/sh.js`` ``shIrradianceL2`` compute): :func:`sh_irradiance` restricted to ``(..., 9, C)``.

    Per band the clamped-cosine kernel Â_l (RH01 eq 8) multiplies the coefficients:
    E = π·c0·L0 + (2π/3)·c1·(L1y y + L1z z + L1x x) + (π/4)·[c2 (L4 xy + L5 yz + L7 xz) + c3 L6 (3z² − 1)
    + c4 L8 (x² − y²)]. Not clamped (the GLSL modes clamp at 0).
    """
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim < 2 or c.shape[-2] != 9:
        raise ValueError(f"sh_irradiance_l2: coeffs must have shape (..., 9, C), got {c.shape}")
    return sh_irradiance(c, normals)


SH_L2_TEXELS = 7
"""RGBA texels (sub-volumes) per probe of an L2 volume: 27 numbers in 28 slots (three.js LightProbeGrid)."""


def sh_l2_atlas_depth(nz: int, volumes: int = 1) -> int:
    """z size of ``volumes`` L2 volumes of a grid with ``nz`` probes along z stacked: 7·(nz + 2) each."""
    return SH_L2_TEXELS * (int(nz) + 2) * int(volumes)


def sh_l2_atlas(probe_sh) -> np.ndarray:
    """Pack L2 radiance SH per probe into the three.js LightProbeGrid 3D atlas (``sh_l2``).

    probe_sh : (nz, ny, nx, 9, 3) radiance SH (this module's order), e.g. the light stage's ``probe_sh``.
    Returns (7·(nz + 2), ny, nx, 4) float32: sub-volume t (t = 0..6) occupies z slices
    [t·(nz + 2), (t + 1)·(nz + 2)); its slice t·(nz + 2) + 1 + k holds probe layer k, and the first / last slice
    copy layers 0 / nz − 1 (padding, so hardware filtering never mixes sub-volumes). Texel channel q of
    sub-volume t is number 4t + q of the probe's ``[c0.r, c0.g, c0.b, c1.r, ..., c8.b, 0]``.
    """
    a = np.asarray(probe_sh, np.float32)
    if a.ndim != 5 or a.shape[3:] != (9, 3):
        raise ValueError(f"sh_l2_atlas: probe_sh must have shape (nz, ny, nx, 9, 3), got {a.shape}")
    nz, ny, nx = a.shape[:3]
    flat = np.zeros((nz, ny, nx, 4 * SH_L2_TEXELS), np.float32)
    flat[..., :27] = a.reshape(nz, ny, nx, 27)
    sub = flat.reshape(nz, ny, nx, SH_L2_TEXELS, 4).transpose(3, 0, 1, 2, 4)     # (7, nz, ny, nx, 4)
    padded = np.concatenate([sub[:, :1], sub, sub[:, -1:]], axis=1)               # (7, nz + 2, ny, nx, 4)
    return np.ascontiguousarray(padded.reshape(SH_L2_TEXELS * (nz + 2), ny, nx, 4))


def sh_l2_from_atlas(atlas) -> np.ndarray:
    """Inverse of :func:`sh_l2_atlas`: (7·(nz + 2), ny, nx, 4) -> (nz, ny, nx, 9, 3) float32."""
    a = np.asarray(atlas, np.float32)
    if a.ndim != 4 or a.shape[3] != 4 or a.shape[0] % SH_L2_TEXELS or a.shape[0] // SH_L2_TEXELS < 3:
        raise ValueError(f"sh_l2_from_atlas: atlas must have shape (7·(nz + 2), ny, nx, 4), got {a.shape}")
    nz = a.shape[0] // SH_L2_TEXELS - 2
    sub = a.reshape(SH_L2_TEXELS, nz + 2, *a.shape[1:])[:, 1:-1]                 # (7, nz, ny, nx, 4)
    flat = sub.transpose(1, 2, 3, 0, 4).reshape(nz, *a.shape[1:3], 4 * SH_L2_TEXELS)
    return np.ascontiguousarray(flat[..., :27].reshape(nz, *a.shape[1:3], 9, 3))


SH_L2_FLOOR = 0.75
"""β of :func:`sh_l2_floor`: the L2 irradiance of a probe may fall at most this far below its octahedral map."""


def sh_l2_floor(coeffs, dirs, floor, beta: float = SH_L2_FLOOR, iterations: int = 400) -> np.ndarray:
    """Deringing of L2 radiance SH against each probe's own irradiance: the smallest change of the 9 coefficients
    (in the irradiance norm ``∫ (E' − E)² dω = Σ_k Â_l(k)² (c'_k − c_k)²``) such that ``E'(n_t) ≥ β · floor(n_t)``
    at every direction n_t.

    A probe that sees a bright surface on one side and darkness on the other (the Cornell box's short block, lit
    from behind, in front of the open side) has irradiance ~1% of its maximum on the dark side; L2's truncation rings
    there to -1%..+0.5% (RH01's L2 is exact only for band-limited irradiance), a black seam in the modes that read
    only such probes. Its octahedral map (DDGI-I eq 1, the same rays) holds the Monte Carlo value for every
    direction; the constraint lifts the L2 where it falls below β of it, and changes nothing elsewhere (inactive:
    Δc = 0). A quadratic programme per probe and channel, solved in its dual by projected gradient with Nesterov
    momentum (``Δc = M⁻¹ Aᵀ λ``, ``λ ≥ 0``; ``A_tk = Â_l(k) Y_k(n_t)``, ``M = diag(Â²)``, so ``A M⁻¹ Aᵀ = Y Yᵀ``).

    coeffs : (P, 9, C) radiance SH (module order); dirs : (T, 3) unit directions (the octahedral texel centres);
    floor : (P, T, C) irradiance there (the probe's map). Returns (P, 9, C) float64.
    """
    c = np.array(coeffs, dtype=np.float64, copy=True)
    d = np.asarray(dirs, np.float64)
    f = np.asarray(floor, np.float64)
    if c.ndim != 3 or c.shape[1] != 9:
        raise ValueError(f"sh_l2_floor: coeffs must have shape (P, 9, C), got {c.shape}")
    if d.ndim != 2 or d.shape[1] != 3 or f.shape != (c.shape[0], d.shape[0], c.shape[2]):
        raise ValueError(f"sh_l2_floor: dirs (T, 3) and floor (P, T, C) must match, got {d.shape}, {f.shape}")
    Y = _sh_basis(d, 9)                                                       # (T, 9)
    A = Y * SH_BAND_CONVOLUTION[_BAND_OF_COEFF]                               # E(n_t) = A c
    P, _, C = c.shape
    flat = c.transpose(0, 2, 1).reshape(-1, 9)                                # (P·C, 9)
    b = beta * f.transpose(0, 2, 1).reshape(-1, d.shape[0])                   # (P·C, T)
    slack = b - flat @ A.T                                                    # > 0: violated
    bad = np.flatnonzero((slack > 1e-12 * np.maximum(np.abs(b).max(axis=1, keepdims=True), 1e-30)).any(axis=1))
    if bad.size == 0:
        return c
    Q = Y @ Y.T                                                               # A M⁻¹ Aᵀ, (T, T)
    step = 1.0 / np.linalg.eigvalsh(Q).max()
    r = slack[bad]                                                            # b − A c0
    lam = np.zeros_like(r)
    z = lam.copy()
    for i in range(iterations):                                               # max_λ≥0 λᵀr − ½ λᵀQλ
        new = np.maximum(0.0, z + step * (r - z @ Q))
        z = new + (i / (i + 3.0)) * (new - lam)
        lam = new
    flat[bad] += (lam @ A) / SH_BAND_CONVOLUTION[_BAND_OF_COEFF] ** 2         # Δc = M⁻¹ Aᵀ λ
    return flat.reshape(P, C, 9).transpose(0, 2, 1)


SH_L2_MARGIN = 0.002
""":func:`sh_l2_nonnegative` keeps a probe's L2 irradiance at least this fraction of its mean everywhere (room for the
half-float rounding of the stored coefficients)."""


def sh_l2_nonnegative(coeffs, margin: float = SH_L2_MARGIN) -> tuple[np.ndarray, int]:
    """Window the L1 and L2 bands of each probe and channel just enough that its L2 irradiance is at least ``margin``
    of its mean in every direction: ``c'_k = t·c_k`` for k ≥ 1, t ∈ [0, 1] (RH01 eq 7's E(n) = e0 + g(n), e0 =
    Â_0 Y00 L00 the mean over the sphere, g the L1 and L2 terms: t = (1 − margin)·e0 / (−min_n g(n)) where e0 + min g
    falls below margin·e0; a probe whose mean is not positive gets 0).

    :func:`sh_l2_floor` lifts the L2 above its octahedral map at the 64 texel centres only; between them, where the map
    is ~0 (a probe by a sealed wall, the dark side of a lit block), L2's truncation can still ring below 0 (sealed box:
    −0.8% of the light outside). Every mode that blends probes with weights ≥ 0 (leaking, visibility-weighted, the
    mask modes' selections of these SH) is then non-negative before the shaders' clamp too. The mean and the
    direction of the light stay; only a probe that rings loses a little of its directionality.

    min g over the unit sphere: g is a quadratic in n, so its minimum is the trust-region subproblem's, solved exactly
    (:func:`_refine_min`) where the least of 512 Fibonacci directions comes near the margin.

    coeffs : (P, 9, C) radiance SH (module order). Returns ``(coeffs' (P, 9, C) float64, windowed)``: the number of
    (probe, channel) pairs changed.
    """
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 3 or c.shape[1] != 9:
        raise ValueError(f"sh_l2_nonnegative: coeffs must have shape (P, 9, C), got {c.shape}")
    P, _, C = c.shape
    flat = c.transpose(0, 2, 1).reshape(-1, 9).copy()                           # (P·C, 9), ours to change
    was_set = np.any(flat != 0.0, axis=1)
    conv = SH_BAND_CONVOLUTION[_BAND_OF_COEFF]
    e0 = conv[0] * SH_C0 * flat[:, 0]                                           # mean irradiance
    dirs = fibonacci_sphere(512).astype(np.float64)
    Yg = (_sh_basis(dirs, 9) * conv)[:, 1:]                                     # (512, 8): g's basis
    gmin = np.empty(flat.shape[0])
    for a in range(0, flat.shape[0], 4096):                                     # (512, chunk) at a time
        gmin[a:a + 4096] = (Yg @ flat[a:a + 4096, 1:].T).min(axis=0)
    low = np.flatnonzero(e0 + gmin < 2.0 * margin * np.abs(e0) + 0.05 * np.abs(gmin))   # near the margin: exactly
    if low.size:
        gmin[low] = np.minimum(gmin[low], _refine_min(flat[low]))
    dark = e0 <= 0
    lift = ~dark & (e0 + gmin < margin * e0)
    t = np.where(lift, (1.0 - margin) * e0 / np.where(lift, -gmin, 1.0), 1.0)
    flat[:, 1:] *= t[:, None]
    flat[dark] = 0.0
    changed = int(np.count_nonzero(lift) + np.count_nonzero(dark & was_set))
    return flat.reshape(P, C, 9).transpose(0, 2, 1), changed


def _refine_min(flat: np.ndarray) -> np.ndarray:
    """min over the unit sphere of g(n) (the L1 + L2 terms of :func:`sh_irradiance`) for rows ``flat`` (k, 9).

    g(n) = b·n + nᵀAn + const on |n| = 1 is the trust-region subproblem: in A's eigenbasis (λ_1 ≤ λ_2 ≤ λ_3, β = Qᵀb)
    the minimiser is y_i = −β_i / (2(λ_i − μ)) with μ < λ_1 the root of Σ β_i² / (4(λ_i − μ)²) = 1 (bisection; it lies
    in [λ_1 − |β|/2, λ_1]); where that sum stays below 1 up to μ = λ_1 (β_1 ≈ 0, the "hard case") the rest of the
    unit length goes along the first eigenvector."""
    conv = SH_BAND_CONVOLUTION
    a1, a2, a3, a4 = conv[1] * SH_C1, conv[2] * SH_C2, conv[2] * SH_C3, conv[2] * SH_C4
    b = a1 * flat[:, [3, 1, 2]]                                                 # linear part (x, y, z)
    A = np.zeros((flat.shape[0], 3, 3))                                         # g = b·n + nᵀAn − a3·c6
    A[:, 0, 0], A[:, 1, 1], A[:, 2, 2] = a4 * flat[:, 8], -a4 * flat[:, 8], 3.0 * a3 * flat[:, 6]
    A[:, 0, 1] = A[:, 1, 0] = 0.5 * a2 * flat[:, 4]
    A[:, 1, 2] = A[:, 2, 1] = 0.5 * a2 * flat[:, 5]
    A[:, 0, 2] = A[:, 2, 0] = 0.5 * a2 * flat[:, 7]
    const = -a3 * flat[:, 6]
    lam, Q = np.linalg.eigh(A)                                                  # ascending
    beta = np.einsum("kji,kj->ki", Q, b)                                        # Qᵀb
    lo = lam[:, 0] - 0.5 * np.linalg.norm(beta, axis=1) - 1e-12
    hi = lam[:, 0].copy()
    for _ in range(100):                                                        # Σ β²/(4(λ−μ)²) increases in μ
        mu = 0.5 * (lo + hi)
        gap = np.maximum(lam - mu[:, None], 1e-150)
        over = (beta * beta / (4.0 * gap * gap)).sum(axis=1) > 1.0
        hi = np.where(over, mu, hi)
        lo = np.where(over, lo, mu)
    gap = np.maximum(lam - lo[:, None], 1e-150)
    y = -beta / (2.0 * gap)
    rest = 1.0 - (y[:, 1:] ** 2).sum(axis=1)                                    # the hard case: along λ_1
    y[:, 0] = np.where(y[:, 0] ** 2 + (y[:, 1:] ** 2).sum(axis=1) < 1.0,
                       np.where(y[:, 0] > 0, 1.0, -1.0) * np.sqrt(np.maximum(rest, 0.0)), y[:, 0])
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    return (lam * y * y).sum(axis=1) + (beta * y).sum(axis=1) + const
