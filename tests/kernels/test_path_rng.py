"""Counter-based random numbers and cosine directions of the path tracer (workers/kernels/path_rng.py)."""
from __future__ import annotations

import numpy as np

from workers.kernels.path_rng import cosine_directions, uniforms


def test_uniforms_and_cosine_directions():
    u = uniforms(7, np.arange(200_000, dtype=np.uint64), 3, 1)
    assert 0 <= u.min() and u.max() < 1
    assert abs(u.mean() - 0.5) < 0.003 and abs(u.var() - 1 / 12) < 0.002
    assert not np.array_equal(u, uniforms(7, np.arange(200_000, dtype=np.uint64), 3, 0))   # dims independent
    n = np.tile([0.0, 0.0, -1.0], (200_000, 1))
    d = cosine_directions(n, 3, np.arange(200_000, dtype=np.uint64), 0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    cos = -d[:, 2]
    assert cos.min() >= 0
    assert abs(cos.mean() - 2 / 3) < 0.003          # E[cos] under pdf cos/π
    assert abs((cos ** 2).mean() - 0.5) < 0.003     # E[cos²]
    assert abs(d[:, 0].mean()) < 0.005 and abs(d[:, 1].mean()) < 0.005


def test_uniforms_depend_only_on_their_counter():
    """A path's numbers are the same whichever other paths are drawn with it (chunking-independent)."""
    ids = np.arange(1000, dtype=np.uint64)
    whole = uniforms(11, ids, 2, 0)
    np.testing.assert_array_equal(uniforms(11, ids[::-1], 2, 0), whole[::-1])
    np.testing.assert_array_equal(uniforms(11, ids[500:], 2, 0), whole[500:])
    assert not np.array_equal(uniforms(12, ids, 2, 0), whole)          # the seed matters
    assert not np.array_equal(uniforms(11, ids, 3, 0), whole)          # and the vertex


def test_cosine_directions_about_any_normal():
    """Unit directions in the normal's hemisphere, mean cosine 2/3, for a normal off every axis and the −z pole
    (the branch of Duff et al.'s basis)."""
    rng = np.random.default_rng(0)
    n = rng.normal(size=(3, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for normal in list(n) + [np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])]:
        d = cosine_directions(np.tile(normal, (50_000, 1)), 1, np.arange(50_000, dtype=np.uint64), 1)
        c = d @ normal
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        assert c.min() >= 0 and abs(c.mean() - 2 / 3) < 0.005


def test_cosine_directions_validation():
    import pytest

    with pytest.raises(ValueError, match="normals"):
        cosine_directions(np.zeros((3, 3)), 0, np.arange(4, dtype=np.uint64), 0)


def test_stratified_uniforms_are_scrambled_nets():
    """Each replicate (samples j ≡ g mod G) of a point is an Owen-scrambled Sobol net: 64 samples put exactly one
    point in every elementary interval of area 1/64 (8x8, 64x1, 1x64, 4x16 cells); 48 samples (not a power of two)
    at most one in each 8x8 cell of the first 32 and of the next 16."""
    from workers.kernels.path_rng import stratified_uniforms

    for point, seed in ((0, 3), (12345, 9)):
        u = stratified_uniforms(seed, np.full(64 * 4, point, np.uint64), np.arange(64 * 4), 64 * 4, 4)
        assert 0 <= u.min() and u.max() < 1
        for g in range(4):
            v = u[g::4]
            for nx, ny in ((8, 8), (64, 1), (1, 64), (4, 16), (16, 4)):
                cells = np.floor(v * [nx, ny]).astype(int)
                assert len({tuple(c) for c in cells}) == 64, (g, nx, ny)
        assert not np.array_equal(u[0::4], u[1::4])              # the replicates are scrambled apart
    v = stratified_uniforms(5, np.zeros(48, np.uint64), np.arange(48), 48, 1)
    assert len({tuple(c) for c in np.floor(v[:32] * [8, 4]).astype(int)}) == 32
    assert len({tuple(c) for c in np.floor(v[32:] * [4, 4]).astype(int)}) == 16


def test_stratified_uniforms_are_uniform_and_independent_per_point_and_replicate():
    """Every sample is uniform on [0, 1)² (mean 1/2, variance 1/12, uncorrelated coordinates) whatever its index, and
    the means of different points and replicates are uncorrelated (independent scrambles); the numbers of a path
    depend only on (seed, point, sample, replicates), not on the other paths drawn with it."""
    from workers.kernels.path_rng import stratified_uniforms

    n_pts, spp, G = 20000, 16, 4
    pts = np.repeat(np.arange(n_pts, dtype=np.uint64), spp)
    j = np.tile(np.arange(spp), n_pts)
    u = stratified_uniforms(7, pts, j, spp, G).reshape(n_pts, spp, 2)
    for k in (0, 5, 15):                                       # one sample index across points: uniform
        assert abs(u[:, k].mean() - 0.5) < 0.006 and np.all(np.abs(u[:, k].var(axis=0) - 1 / 12) < 0.003)
        assert abs(np.corrcoef(u[:, k, 0], u[:, k, 1])[0, 1]) < 0.03
    means = np.stack([u[:, g::G, 0].mean(axis=1) for g in range(G)], axis=1)        # (points, G)
    c = np.corrcoef(means.T)
    assert np.all(np.abs(c[np.triu_indices(G, 1)]) < 0.03)
    assert abs(np.corrcoef(means[:-1, 0], means[1:, 0])[0, 1]) < 0.03                # neighbouring points
    # within a replicate the samples are stratified: the mean of 4 is far less variable than 4 independent ones
    assert means[:, 0].var() < 0.25 * (1 / 12 / 4)
    sub = stratified_uniforms(7, pts[::-7], j[::-7], spp, G)
    np.testing.assert_array_equal(sub, u.reshape(-1, 2)[::-7])
    assert not np.array_equal(stratified_uniforms(8, pts[:64], j[:64], spp, G), u.reshape(-1, 2)[:64])


def test_stratified_validation():
    import pytest

    from workers.kernels.path_rng import first_cosine_directions, stratified_uniforms

    with pytest.raises(ValueError, match="samples"):
        stratified_uniforms(0, np.zeros(3, np.uint64), np.array([0, 1, 4]), 4, 2)
    with pytest.raises(ValueError, match="replicates"):
        stratified_uniforms(0, np.zeros(3, np.uint64), np.arange(3), 4, 0)
    with pytest.raises(ValueError, match="normals"):
        first_cosine_directions(np.zeros((2, 3)), 0, np.zeros(3, np.uint64), np.arange(3), 4, 2)
    d, c = first_cosine_directions(np.tile([0.0, 1.0, 0.0], (3, 1)), 0, np.zeros(3, np.uint64), np.arange(3), 4, 2)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d[:, 1], c)
