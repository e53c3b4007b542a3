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
