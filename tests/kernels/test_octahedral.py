"""Octahedral maps (workers/kernels/octahedral.py): encoding, border texels, sampling, accumulation."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import octahedral as octa
from workers.kernels.octahedral import (
    accumulate_octahedral,
    add_border,
    bilinear_sample,
    oct_decode,
    oct_encode,
    oct_texel_directions,
)
from workers.kernels.sampling import fibonacci_sphere, random_rotation, rotated_directions

SEEDS = [0, 1, 2]


def _random_dirs(rng, n):
    d = rng.standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# The 6 axes, the 8 octant diagonals and directions on the folded edges (z < 0, x or y = 0).
SPECIAL = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    + [[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)]
    + [[0.3, 0, -1], [-0.3, 0, -1], [0, 0.3, -1], [0, -0.3, -1], [1, 1, 0], [1, -2, 0]],
    dtype=np.float64,
)


# ------------------------------------------------------------------ encode / decode
@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 2e-6)])
def test_decode_encode_is_identity(seed, dtype, tol):
    d = np.concatenate([_random_dirs(np.random.default_rng(seed), 5000), SPECIAL / np.linalg.norm(SPECIAL, axis=1, keepdims=True)])
    uv = oct_encode(d.astype(dtype))
    assert uv.dtype == dtype and uv.shape == (len(d), 2)
    assert np.all(np.abs(uv) <= 1.0)
    back = oct_decode(uv)
    assert back.dtype == dtype
    np.testing.assert_allclose(back, d, atol=tol)


def test_encode_does_not_need_unit_length():
    d = _random_dirs(np.random.default_rng(3), 100)
    np.testing.assert_allclose(oct_encode(d * 7.5), oct_encode(d), atol=1e-12)


def test_encode_keeps_leading_shape():
    d = _random_dirs(np.random.default_rng(4), 24).reshape(2, 3, 4, 3)
    assert oct_encode(d).shape == (2, 3, 4, 2)
    assert oct_decode(oct_encode(d)).shape == (2, 3, 4, 3)


@pytest.mark.parametrize("seed", SEEDS)
def test_encode_decode_is_identity_on_the_domain(seed):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-1, 1, size=(5000, 2)) * (1 - 1e-9)  # open square: each direction has one uv
    np.testing.assert_allclose(oct_encode(oct_decode(uv)), uv, atol=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_edges_of_the_square_are_mirrored(seed):
    # (±1, v) and (±1, -v) are one direction, as are (u, ±1) and (-u, ±1): the seams add_border copies.
    t = np.random.default_rng(seed).uniform(-1, 1, 100)
    one = np.ones_like(t)
    for a, b in [((one, t), (one, -t)), ((-one, t), (-one, -t)), ((t, one), (-t, one)), ((t, -one), (-t, -one))]:
        np.testing.assert_allclose(oct_decode(np.stack(a, -1)), oct_decode(np.stack(b, -1)), atol=1e-12)


def test_fold_axis_is_world_z():
    np.testing.assert_allclose(oct_encode(np.array([0.0, 0.0, 1.0])), [0, 0])
    np.testing.assert_allclose(np.abs(oct_encode(np.array([0.0, 0.0, -1.0]))), [1, 1])
    np.testing.assert_allclose(oct_encode(np.array([[1.0, 0, 0], [0, 1.0, 0]])), [[1, 0], [0, 1]])


def test_encode_rejects_zero_and_bad_shapes():
    with pytest.raises(ValueError):
        oct_encode(np.zeros((2, 3)))
    with pytest.raises(ValueError):
        oct_encode(np.ones((2, 2)))
    with pytest.raises(ValueError):
        oct_decode(np.ones((2, 3)))


# ------------------------------------------------------------------ texel directions
@pytest.mark.parametrize("n", [1, 2, 8, 16])
def test_texel_directions(n):
    t = oct_texel_directions(n)
    assert t.shape == (n, n, 3) and t.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(t.astype(np.float64), axis=-1), 1.0, atol=1e-6)
    c = (np.arange(n) + 0.5) * 2 / n - 1
    uv = oct_encode(t.astype(np.float64))
    np.testing.assert_allclose(uv[..., 0], np.broadcast_to(c[None, :], (n, n)), atol=1e-6)  # u follows columns
    np.testing.assert_allclose(uv[..., 1], np.broadcast_to(c[:, None], (n, n)), atol=1e-6)  # v follows rows


# ------------------------------------------------------------------ border
def _interior_index(coord: float, n: int) -> int:
    return int(np.floor((coord + 1) / 2 * n))


def _mirror(u: float, v: float) -> tuple[float, float]:
    """Fold a point outside [-1, 1]² back inside across the crossed edge(s): (u, v) ~ (2 - u, -v)."""
    if u > 1:
        u, v = 2 - u, -v
    elif u < -1:
        u, v = -2 - u, -v
    if v > 1:
        u, v = -u, 2 - v
    elif v < -1:
        u, v = -u, -2 - v
    return u, v


@pytest.mark.parametrize("n", [1, 2, 3, 8, 16])
@pytest.mark.parametrize("seed", SEEDS[:2])
def test_border_texels_equal_their_mirrored_sources(n, seed):
    maps = np.random.default_rng(seed).standard_normal((3, n, n, 2)).astype(np.float32)
    b = add_border(maps)
    assert b.shape == (3, n + 2, n + 2, 2) and b.dtype == maps.dtype
    np.testing.assert_array_equal(b[:, 1:-1, 1:-1], maps)
    for r in range(n + 2):
        for c in range(n + 2):
            if 0 < r < n + 1 and 0 < c < n + 1:
                continue
            # the border texel's centre lies outside the square; fold it back and look up the source
            u, v = _mirror((c - 1 + 0.5) * 2 / n - 1, (r - 1 + 0.5) * 2 / n - 1)
            src = maps[:, _interior_index(v, n), _interior_index(u, n)]
            np.testing.assert_array_equal(b[:, r, c], src, err_msg=f"border texel ({r}, {c})")


def test_border_corners_and_edges_by_index():
    n = 4
    m = np.arange(n * n).reshape(1, n, n, 1)
    b = add_border(m)[0, ..., 0]
    interior = m[0, ..., 0]
    assert b[0, 0] == interior[n - 1, n - 1] and b[n + 1, n + 1] == interior[0, 0]
    assert b[0, n + 1] == interior[n - 1, 0] and b[n + 1, 0] == interior[0, n - 1]
    np.testing.assert_array_equal(b[0, 1:-1], interior[0, ::-1])
    np.testing.assert_array_equal(b[1:-1, n + 1], interior[::-1, n - 1])


def test_border_accepts_single_map_and_rejects_non_square():
    assert add_border(np.zeros((8, 8, 3))).shape == (10, 10, 3)
    with pytest.raises(ValueError):
        add_border(np.zeros((2, 8, 7, 1)))


# ------------------------------------------------------------------ bilinear sampling
@pytest.mark.parametrize("n", [4, 8, 16])
def test_bilinear_at_texel_centres_returns_texels(n):
    m = np.random.default_rng(n).standard_normal((n, n, 3))
    out = bilinear_sample(add_border(m), oct_texel_directions(n).astype(np.float64))
    np.testing.assert_allclose(out, m, atol=1e-5)  # texel directions are float32


def _seam_pairs(rng, count):
    """Points on the octahedral seams (and near -Z) and a tangent that crosses the seam there."""
    pts, tangents = [], []
    for _ in range(count):
        s = rng.uniform(0.05, 3.0)
        kind = rng.integers(0, 3)
        if kind == 0:  # u = ±1 edge: z < 0, y = 0; crossing it flips the sign of y
            p, t = np.array([rng.choice([-1, 1]) * s, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
        elif kind == 1:  # v = ±1 edge: z < 0, x = 0
            p, t = np.array([0.0, rng.choice([-1, 1]) * s, -1.0]), np.array([1.0, 0.0, 0.0])
        else:  # the -Z pole, where the four corners meet; cross in a random tangent direction
            a = rng.uniform(0, 2 * np.pi)
            p, t = np.array([0.0, 0.0, -1.0]), np.array([np.cos(a), np.sin(a), 0.0])
        pts.append(p / np.linalg.norm(p))
        tangents.append(t)
    return np.array(pts), np.array(tangents)


@pytest.mark.parametrize("n", [4, 8, 16])
@pytest.mark.parametrize("seed", SEEDS)
def test_bilinear_is_continuous_across_seams(n, seed):
    rng = np.random.default_rng(seed)
    m = rng.uniform(-1, 1, (n, n, 2))  # arbitrary texels: continuity must come from the border
    b = add_border(m)
    p, t = _seam_pairs(rng, 60)
    for eps in (1e-3, 1e-5, 1e-7):
        plus = bilinear_sample(b, p + eps * t)
        minus = bilinear_sample(b, p - eps * t)
        # |Δ| ≤ (Lipschitz of the bilinear map in uv) × |Δuv|, Δuv = O(eps); values are in [-1, 1]
        assert np.abs(plus - minus).max() <= 4 * n * eps * 2, eps
    # the two sides really land on different texels: without the border copy they would jump
    uv_p, uv_m = oct_encode(p + 1e-5 * t), oct_encode(p - 1e-5 * t)
    assert np.all(np.abs(uv_p - uv_m).max(axis=1) > 0.05)


@pytest.mark.parametrize("n", [8, 16, 32])
def test_bilinear_of_a_smooth_function_converges(n):
    # A linear function of direction stored at texel centres: the error is O(texel) at the
    # octahedron's creases (the map is only C0 there) and O(texel²) on average.
    a = np.array([0.3, -0.5, 0.8])
    m = (oct_texel_directions(n).astype(np.float64) @ a)[..., None]
    d = _random_dirs(np.random.default_rng(11), 5000)
    err = np.abs(bilinear_sample(add_border(m), d)[:, 0] - d @ a)
    assert err.max() <= 1.2 / n
    assert err.mean() <= 2.5 / n**2


# ------------------------------------------------------------------ accumulation
def _accumulate_loop(ray_dirs, values, texel_dirs, power):
    p_count, r_count, c_count = values.shape
    n, m = texel_dirs.shape[:2]
    out = np.zeros((p_count, n, m, c_count))
    rd = np.broadcast_to(ray_dirs, (p_count, r_count, 3))
    for p in range(p_count):
        for i in range(n):
            for j in range(m):
                w = np.maximum(0, rd[p] @ texel_dirs[i, j]) ** power
                if w.sum() > 0:
                    out[p, i, j] = (w[:, None] * values[p]).sum(0) / w.sum()
    return out


@pytest.mark.parametrize("power", [1.0, 2.5, 50.0])
@pytest.mark.parametrize("shared", [False, True])
def test_accumulate_matches_loop(power, shared):
    rng = np.random.default_rng(int(power) + shared)
    p_count, r_count, n = 3, 96, 4
    rd = _random_dirs(rng, r_count) if shared else _random_dirs(rng, p_count * r_count).reshape(p_count, r_count, 3)
    val = rng.uniform(0, 5, (p_count, r_count, 2))
    td = oct_texel_directions(n)
    got = accumulate_octahedral(rd, val, td, power)
    assert got.shape == (p_count, n, n, 2) and got.dtype == np.float32
    np.testing.assert_allclose(got, _accumulate_loop(rd, val, td.astype(np.float64), power), rtol=2e-4, atol=1e-5)


def test_accumulate_chunking_does_not_change_results():
    rng = np.random.default_rng(5)
    rd = _random_dirs(rng, 7 * 64).reshape(7, 64, 3).astype(np.float32)
    val = rng.uniform(0, 1, (7, 64, 2)).astype(np.float32)
    td = oct_texel_directions(8)
    whole = octa._accumulate_octahedral(rd, val, td, 50.0)
    tiny = octa._accumulate_octahedral(rd, val, td, 50.0, budget_bytes=1)  # one probe per chunk
    np.testing.assert_array_equal(whole[0], tiny[0])
    np.testing.assert_array_equal(whole[1], tiny[1])


@pytest.mark.parametrize("power", [1.0, 50.0])
def test_accumulate_constant_is_constant(power):
    rd = rotated_directions(256, random_rotation(np.random.default_rng(1)))
    val = np.broadcast_to(np.array([2.0, 0.25], np.float32), (4, 256, 2))
    np.testing.assert_allclose(accumulate_octahedral(rd, val, oct_texel_directions(16), power),
                               np.broadcast_to([2.0, 0.25], (4, 16, 16, 2)), rtol=1e-5)


def test_accumulate_cosine_weighted_radiance_is_irradiance_over_pi():
    # radiance L(ω) = max(0, ω·a): E(n) = (2/3)((π − γ) cos γ + sin γ), cos γ = n·a
    a = np.array([0.0, 0.6, 0.8])
    rd = fibonacci_sphere(8192)
    val = np.maximum(0.0, rd.astype(np.float64) @ a)[None, :, None]
    td = oct_texel_directions(8)
    got = accumulate_octahedral(rd, val, td, 1.0)[0, ..., 0]
    g = np.arccos(np.clip(td.astype(np.float64) @ a, -1, 1))
    expected = (2 / 3) * ((np.pi - g) * np.cos(g) + np.sin(g))
    np.testing.assert_allclose(got * np.pi, expected, atol=2e-3)


def test_accumulate_merge_with_weights():
    rng = np.random.default_rng(9)
    rd = _random_dirs(rng, 2 * 128).reshape(2, 128, 3)
    val = rng.uniform(0, 3, (2, 128, 1))
    td = oct_texel_directions(4)
    whole = accumulate_octahedral(rd, val, td, 50.0)
    m0, w0 = accumulate_octahedral(rd[:, :70], val[:, :70], td, 50.0, return_weights=True)
    m1, w1 = accumulate_octahedral(rd[:, 70:], val[:, 70:], td, 50.0, return_weights=True)
    merged = (m0 * w0[..., None] + m1 * w1[..., None]) / (w0 + w1)[..., None]
    np.testing.assert_allclose(merged, whole, rtol=1e-4)


def test_accumulate_texels_without_rays_are_zero():
    rd = np.array([[0.0, 0.0, 1.0]] * 4)  # every ray straight up
    val = np.ones((1, 4, 1))
    td = oct_texel_directions(8)
    out, w = accumulate_octahedral(rd, val, td, 1.0, return_weights=True)
    below = td[..., 2] <= 0
    assert np.all(out[0, below] == 0) and np.all(w[0, below] == 0)
    assert np.allclose(out[0, ~below], 1.0)


def test_accumulate_validates():
    td = oct_texel_directions(4)
    with pytest.raises(ValueError, match="finite"):
        accumulate_octahedral(np.ones((1, 2, 3)), np.array([[[1.0], [np.inf]]]), td, 1.0)
    with pytest.raises(ValueError, match="power"):
        accumulate_octahedral(np.ones((2, 3)), np.ones((1, 2, 1)), td, 0.0)
    with pytest.raises(ValueError, match="ray_dirs"):
        accumulate_octahedral(np.ones((3, 3)), np.ones((1, 2, 1)), td, 1.0)
