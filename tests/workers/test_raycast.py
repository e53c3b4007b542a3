"""Ray casting (workers/raycast): exact hits, inside tests, thread/chunk invariance, real Embree."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from workers.raycast import Hits, RayCaster

SEEDS = [0, 1, 2]


def _random_dirs(rng, n):
    d = rng.standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _reference_intersect(tris, o, d):
    """Brute-force Möller-Trumbore in float64: closest t, triangle, u, v (inf / -1 on a miss)."""
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    p = np.cross(d[:, None, :], e2[None])  # (N, T, 3)
    det = np.einsum("tk,ntk->nt", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o[:, None, :] - v0[None]
        u = np.einsum("ntk,ntk->nt", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("nk,ntk->nt", d, q) * inv
        t = np.einsum("tk,ntk->nt", e2, q) * inv
    ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t = np.where(ok, t, np.inf)
    tri = np.argmin(t, axis=1)
    rows = np.arange(len(o))
    best = t[rows, tri]
    hit = np.isfinite(best)
    return best, np.where(hit, tri, -1), u[rows, tri], v[rows, tri]


# ------------------------------------------------------------------ exact answers
def test_single_triangle_exact():
    tri = np.array([[[0, 0, 0], [2, 0, 0], [0, 4, 0]]], np.float32)  # normal (v1-v0)×(v2-v0) = +z
    rc = RayCaster(tri)
    o = np.array([[0.5, 1.0, 3.0], [0.5, 1.0, -2.0], [3.0, 3.0, 1.0], [0.5, 1.0, 3.0]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, 1], [0, 0, -1], [0, 0, 1]], np.float32)
    h = rc.intersect(o, d)
    assert isinstance(h, Hits) and len(h) == 4
    assert h.t.dtype == np.float32 and h.tri.dtype == np.int32 and h.u.dtype == np.float32
    assert h.backface.dtype == bool
    # within float32 rounding: Embree builds differ by an ulp (embreex 4.4.0.post1 gives t = 3 - 2.4e-7)
    np.testing.assert_allclose(h.t, [3.0, 2.0, np.inf, np.inf], rtol=4e-7)
    np.testing.assert_array_equal(h.tri, [0, 0, -1, -1])
    np.testing.assert_allclose(h.u, [0.25, 0.25, 0, 0], rtol=4e-7, atol=1e-7)  # hit = (1-u-v) v0 + u v1 + v v2
    np.testing.assert_allclose(h.v, [0.25, 0.25, 0, 0], rtol=4e-7, atol=1e-7)
    np.testing.assert_array_equal(h.backface, [False, True, False, False])
    np.testing.assert_array_equal(h.hit, [True, True, False, False])
    pts = h.points(o, d)
    np.testing.assert_allclose(pts[:2], [[0.5, 1.0, 0.0], [0.5, 1.0, 0.0]], rtol=4e-7, atol=1e-6)
    assert np.all(np.isnan(pts[2:]))


def test_interval_and_closest_hit():
    # two parallel triangles at z = 0 and z = 1, the second wound clockwise seen from +z
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [0, 1, 1], [1, 0, 1]]], np.float32)
    rc = RayCaster(tris)
    o = np.tile(np.array([[0.2, 0.2, -1.0]], np.float32), (5, 1))
    d = np.tile(np.array([[0, 0, 1.0]], np.float32), (5, 1))
    h = rc.intersect(o, d, tnear=np.array([0, 1.5, 0, 2.5, 0]), tfar=np.array([np.inf, np.inf, 0.5, 10, 1.0]))
    np.testing.assert_array_equal(h.tri, [0, 1, -1, -1, 0])
    np.testing.assert_allclose(h.t, [1.0, 2.0, np.inf, np.inf, 1.0], rtol=1e-6)
    np.testing.assert_array_equal(h.backface, [True, False, False, False, True])
    np.testing.assert_array_equal(rc.occluded(o, d, tfar=[0.5, 0.99, 1.01, 1.5, 3.0], tnear=[0, 0, 0, 1.5, 2.5]),
                                  [False, False, True, False, False])


def test_t_scales_with_direction_length():
    rc = RayCaster(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32))
    h = rc.intersect(np.array([[0.2, 0.2, 4.0]]), np.array([[0, 0, -2.0]]))
    assert h.t[0] == pytest.approx(2.0, rel=4e-7)      # metres along the unnormalized direction: 2, not 4


@pytest.mark.parametrize("seed", SEEDS)
def test_matches_reference_intersector(seed):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1, 1, (60, 1, 3))
    tris = (centres + 0.3 * rng.standard_normal((60, 3, 3))).astype(np.float32)
    o = rng.uniform(-1.5, 1.5, (3000, 3)).astype(np.float32)
    d = _random_dirs(rng, 3000).astype(np.float32)
    h = RayCaster(tris).intersect(o, d)
    t, tri, u, v = _reference_intersect(tris.astype(np.float64), o.astype(np.float64), d.astype(np.float64))
    # compare away from triangle edges, where float32 may decide either way
    clear = (np.minimum(np.minimum(u, v), 1 - u - v) > 1e-4) | (tri < 0)
    assert clear.mean() > 0.9
    np.testing.assert_array_equal(h.tri[clear], tri[clear])
    hit = clear & (tri >= 0)
    assert hit.sum() > 300
    np.testing.assert_allclose(h.t[hit], t[hit], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(h.u[hit], u[hit], atol=1e-4)
    np.testing.assert_allclose(h.v[hit], v[hit], atol=1e-4)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]).astype(np.float64)
    np.testing.assert_array_equal(h.backface[hit], np.einsum("ij,ij->i", d[hit], n[tri[hit]]) > 0)


# ------------------------------------------------------------------ inside tests
def _box_points(rng, n, half):
    inside = rng.uniform(-0.97, 0.97, (n, 3)) * half
    shell = _random_dirs(rng, n) * rng.uniform(1.05, 3.0, (n, 1)) * np.linalg.norm(half)  # beyond the corners
    return inside, shell


@pytest.mark.parametrize("rule", ["parity", "backface"])
@pytest.mark.parametrize("n_dirs", [1, 3, 5])
@pytest.mark.parametrize("seed", SEEDS[:2])
def test_closed_box_inside_outside(rule, n_dirs, seed):
    half = np.array([2.0, 0.5, 1.0])
    box = trimesh.creation.box(extents=2 * half)
    rc = RayCaster(box.triangles)
    rng = np.random.default_rng(seed)
    inside, outside = _box_points(rng, 500, half)
    # points just outside a face, and inside the AABB of nothing else
    near = np.array([[2.01, 0, 0], [0, -0.51, 0], [0, 0, 1.001], [-2.001, 0.4, 0.9]])
    assert rc.inside_parity(inside, n_dirs=n_dirs, rule=rule).all()
    assert not rc.inside_parity(outside, n_dirs=n_dirs, rule=rule).any()
    assert not rc.inside_parity(near, n_dirs=n_dirs, rule=rule).any()


@pytest.mark.parametrize("rule", ["parity", "backface"])
def test_hollow_box_and_sphere(rule):
    # a box with a box-shaped cavity (inner walls facing the cavity), and a separate sphere
    outer = trimesh.creation.box(extents=(4, 4, 4))
    cavity = trimesh.creation.box(extents=(2, 2, 2))
    cavity.invert()  # normals point into the cavity, as for a real hollow solid
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    sphere.apply_translation([5, 0, 0])
    tris = np.concatenate([outer.triangles, cavity.triangles, sphere.triangles])
    rc = RayCaster(tris)
    pts = np.array([[1.5, 0, 0], [0, -1.7, 1.2], [0, 0, 0], [0.5, 0.5, -0.5], [5, 0, 0], [5.2, 0.1, 0], [5.7, 0, 0], [9, 9, 9]])
    np.testing.assert_array_equal(rc.inside_parity(pts, rule=rule), [True, True, False, False, True, True, False, False])


# ------------------------------------------------------------------ determinism and agreement
@pytest.mark.parametrize("seed", SEEDS)
def test_threads_and_chunks_do_not_change_results(seed):
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=4)
    tris = np.concatenate([sphere.triangles, trimesh.creation.box(extents=(3, 0.2, 3)).triangles])
    o = rng.uniform(-2, 2, (20000, 3))
    d = _random_dirs(rng, 20000)
    tnear = rng.uniform(0, 0.3, 20000)
    results = []
    for threads, chunk in [(1, 1 << 16), (2, 1 << 16), (2, 777), (3, 4096)]:
        rc = RayCaster(tris, threads=threads, chunk_size=chunk)
        results.append((rc.intersect(o, d, tnear=tnear), rc.occluded(o, d, tfar=1.0), rc.inside_parity(o[:3000])))
    ref = results[0]
    assert ref[0].hit.mean() > 0.15
    for h, occ, ins in results[1:]:
        for name in ("t", "tri", "u", "v", "backface"):
            np.testing.assert_array_equal(getattr(h, name), getattr(ref[0], name), err_msg=name)
        np.testing.assert_array_equal(occ, ref[1])
        np.testing.assert_array_equal(ins, ref[2])


@pytest.mark.parametrize("seed", SEEDS)
def test_occluded_agrees_with_intersect(seed):
    rng = np.random.default_rng(seed)
    tris = trimesh.creation.icosphere(subdivisions=3).triangles
    tris = np.concatenate([tris, tris * 0.4 + 1.5])
    o = rng.uniform(-1.5, 2.0, (20000, 3))
    d = _random_dirs(rng, 20000)
    tnear = np.where(rng.random(20000) < 0.5, 0.0, rng.uniform(0, 1, 20000))
    tfar = tnear + rng.exponential(1.5, 20000)
    rc = RayCaster(tris, chunk_size=3000)
    h = rc.intersect(o, d, tnear=tnear)
    occ = rc.occluded(o, d, tfar=tfar, tnear=tnear)
    clear = np.abs(h.t - tfar) > 1e-4 * np.maximum(1, tfar)  # ignore hits within rounding of tfar
    assert clear.mean() > 0.99
    np.testing.assert_array_equal(occ[clear], (h.t <= tfar)[clear])
    assert 0.05 < occ.mean() < 0.95  # both outcomes well represented


def test_empty_scene_misses():
    rc = RayCaster(np.zeros((0, 3, 3), np.float32))
    h = rc.intersect(np.zeros((3, 3)), np.ones((3, 3)))
    assert np.all(np.isinf(h.t)) and np.all(h.tri == -1)
    assert not rc.occluded(np.zeros((3, 3)), np.ones((3, 3))).any()
    assert not rc.inside_parity(np.zeros((3, 3))).any()


def test_no_rays():
    rc = RayCaster(trimesh.creation.box().triangles)
    assert len(rc.intersect(np.zeros((0, 3)), np.zeros((0, 3)))) == 0
    assert rc.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
    assert rc.inside_parity(np.zeros((0, 3))).shape == (0,)


def test_inputs_are_not_modified():
    rc = RayCaster(trimesh.creation.box().triangles)
    o = np.zeros((4, 3), np.float32)
    d = _random_dirs(np.random.default_rng(0), 4).astype(np.float32)
    tfar = np.full(4, 10.0, np.float32)
    o0, d0, tf0 = o.copy(), d.copy(), tfar.copy()
    rc.intersect(o, d, tfar=tfar)
    rc.occluded(o, d, tfar=tfar)
    np.testing.assert_array_equal(o, o0)
    np.testing.assert_array_equal(d, d0)
    np.testing.assert_array_equal(tfar, tf0)  # embreex writes into a tfar array it is given


def test_validation():
    with pytest.raises(ValueError):
        RayCaster(np.zeros((2, 3)))
    with pytest.raises(ValueError):
        RayCaster(np.full((1, 3, 3), np.nan))
    with pytest.raises(ValueError):
        RayCaster(np.zeros((1, 3, 3)), threads=0)
    rc = RayCaster(trimesh.creation.box().triangles)
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    with pytest.raises(ValueError):
        rc.intersect(o, np.ones((3, 3)))
    with pytest.raises(ValueError):
        rc.intersect(o, np.zeros((2, 3)))
    with pytest.raises(ValueError):
        rc.intersect(o, d, tnear=-1.0)
    with pytest.raises(ValueError):
        rc.intersect(o, d, tnear=2.0, tfar=1.0)
    with pytest.raises(ValueError):
        rc.intersect(np.full((2, 3), np.nan), d)
    with pytest.raises(ValueError):
        rc.inside_parity(o, rule="winding")
