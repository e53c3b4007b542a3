"""Probe-ray hits as shading points and their cage visibility (workers/kernels/probe_hits.py)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from workers.kernels import grid as kgrid
from workers.kernels.grid import ACTIVE, OFF
from workers.kernels.probe_hits import hit_surfaces, probe_visibility
from workers.scene import NormalizedScene


def _wall(z=1.0, albedo=(0.2, 0.4, 0.6), emission=(0.0, 1.0, 0.0)):
    """Two triangles covering [-1, 1]² at height z, facing -z (toward probes below)."""
    q = np.array([[(-1, -1, z), (1, 1, z), (1, -1, z)], [(-1, -1, z), (-1, 1, z), (1, 1, z)]], np.float32)
    mat = {"name": "m", "base_color": list(albedo) + [1.0], "base_color_texture": None, "emissive": list(emission),
           "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 1.0}
    return NormalizedScene(triangles=q, normals=np.tile(np.float32([0, 0, -1]), (2, 3, 1)),
                           uv0=np.zeros((2, 3, 2), np.float32), material=np.zeros(2, np.int32), materials=[mat])


def test_hit_surfaces_keep_front_hits_with_normals_toward_the_probe():
    scene = _wall()
    dirs = np.array([[0, 0, 1], [0, 0, -1], [0.6, 0, 0.8]], np.float32)
    # probe 0 below the wall: ray 0 hits tri 0 at (u, v) = (0.25, 0.25), ray 1 misses, ray 2 hits tri 1 from the back
    hits = np.zeros((2, 3, 4), np.float32)
    tri = np.full((2, 3), -1, np.int32)
    hits[0, 0] = (1.0, 0.25, 0.25, 0.0)
    tri[0, 0] = 0
    hits[0, 2] = (1.25, 0.5, 0.25, 1.0)
    tri[0, 2] = 1
    hits[1, 2] = (1.25, 0.3, 0.3, 0.0)
    tri[1, 2] = 1
    s = hit_surfaces(scene, dirs, hits, tri)
    assert s.P == 2 and s.R == 3 and sorted(s.index.tolist()) == [0, 5]
    assert np.array_equal(s.miss, tri < 0)
    i0 = int(np.flatnonzero(s.index == 0)[0])
    v0, v1, v2 = scene.triangles[0]
    assert np.allclose(s.position[i0], 0.5 * v0 + 0.25 * v1 + 0.25 * v2)
    assert np.allclose(s.view, -dirs[[2 if k == 5 else 0 for k in s.index]])
    assert np.all(np.einsum("ij,ij->i", s.normal, s.view) > 0)          # the side the ray arrived on
    assert np.allclose(s.albedo, (0.2, 0.4, 0.6)) and np.allclose(s.emission, (0, 1, 0))
    assert all(a.dtype == np.float32 for a in (s.position, s.normal, s.view, s.albedo, s.emission))
    import workers.kernels.probe_hits as ph                    # shaded HIT_CHUNK hits at a time: the same arrays
    chunk, ph.HIT_CHUNK = ph.HIT_CHUNK, 1
    try:
        one = hit_surfaces(scene, dirs, hits, tri)
    finally:
        ph.HIT_CHUNK = chunk
    for name in ("index", "position", "normal", "view", "albedo", "emission", "miss"):
        assert np.array_equal(getattr(one, name), getattr(s, name))



def test_hit_surfaces_are_each_rays_surface_in_spatial_order():
    """Every hit is its own ray's surface (surface_at_hits at that ray's triangle and barycentrics: positions as its
    float32, albedo, emission), and the hits come in the stable order of their coarse 64³ cell (ties in ray order):
    the order, found from the positions before anything is shaded, that the light stage's sampler reads from cache."""
    from workers.kernels.shading import surface_at_hits

    scene = _wall()
    rng = np.random.default_rng(3)
    P, R = 40, 64
    dirs = rng.normal(size=(R, 3)).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    tri = rng.integers(-1, 2, (P, R)).astype(np.int32)                       # misses, both triangles
    uv = rng.uniform(0, 0.5, (P, R, 2)).astype(np.float32)
    hits = np.concatenate([rng.uniform(0.1, 3, (P, R, 1)), uv, (rng.uniform(size=(P, R, 1)) < 0.2)], -1)
    hits = hits.astype(np.float32)
    s = hit_surfaces(scene, dirs, hits, tri)
    flat = hits.reshape(-1, 4)
    want = np.flatnonzero((tri.ravel() >= 0) & (flat[:, 3] < 0.5))
    assert sorted(s.index.tolist()) == want.tolist()
    ref = surface_at_hits(scene, tri.ravel()[s.index], flat[s.index, 1], flat[s.index, 2])
    for name in ("position", "albedo", "emission"):
        assert np.array_equal(getattr(s, name), ref[name]), name
    lo, hi = s.position.min(axis=0), s.position.max(axis=0)
    cell = np.floor((s.position - lo) / np.maximum(hi - lo, 1e-6) * 63.999).astype(np.int64)
    key = cell[:, 0] + 64 * (cell[:, 1] + 64 * cell[:, 2])
    assert np.all(np.diff(key) >= 0) and key[0] < key[-1]
    same = np.diff(key) == 0
    assert np.all(np.diff(s.index)[same] > 0)                                # ties keep ray order


class _Caster:
    def __init__(self, blocked: bool):
        self.blocked, self.rays = blocked, 0

    def occluded(self, o, d, tfar):
        self.rays += len(o)
        return np.full(len(o), self.blocked)


def test_probe_visibility_traces_live_cage_probes_only():
    g = {"counts": [2, 2, 2], "origin": [0.0, 0.0, 0.0], "spacing": [1.0, 1.0, 1.0]}
    pos = kgrid.base_positions(g["counts"], g["origin"], g["spacing"]).reshape(-1, 3).astype(np.float32)
    states = np.full(8, ACTIVE)
    states[[2, 5]] = OFF
    pts = np.float32([[0.5, 0.5, 0.5], [0.2, 0.7, 0.4]])
    nrm = np.float32([[0, 1, 0], [1, 0, 0]])
    surf = SimpleNamespace(position=pts, normal=nrm, view=nrm)
    open_, rays = probe_visibility(surf, g, pos, states, _Caster(False), 0.3)
    assert open_.shape == (2, 8) and open_.dtype == np.uint8 and rays == 12
    # corner c of the 2x2x2 cage is probe c: the live ones are visible
    assert np.array_equal(open_, np.tile((states != OFF).astype(np.uint8), (2, 1)))
    shut, _ = probe_visibility(surf, g, pos, states, _Caster(True), 0.3)
    assert not shut.any()


def test_counting_order_is_the_stable_argsort():
    # hit_surfaces orders the hits by a coarse 3D cell with a counting sort: numpy's stable argsort, faster
    from workers.kernels.probe_hits import _counting_order
    rng = np.random.default_rng(5)
    for n_keys, size in ((1, 10), (7, 1000), (64 ** 3, 50000)):
        key = rng.integers(0, n_keys, size)
        assert np.array_equal(_counting_order(key, n_keys), np.argsort(key, kind="stable"))
    assert _counting_order(np.zeros(0, np.int64), 8).shape == (0,)


def _corner(L=50.0, wall_albedo=(0.8, 0.6, 0.4), floor_albedo=(0.3, 0.3, 0.3)):
    """A floor z = 0 (facing +z) and a wall x = 0 (facing +x), both L m wide: a concave 90° edge along y."""
    floor = [[(-L, -L, 0), (L, -L, 0), (L, L, 0)], [(-L, -L, 0), (L, L, 0), (-L, L, 0)]]
    wall = [[(0, -L, 0), (0, L, 0), (0, L, L)], [(0, -L, 0), (0, L, L), (0, -L, L)]]
    tris = np.array(floor + wall, np.float32)
    mats = [{"name": nm, "base_color": list(c) + [1.0], "base_color_texture": None, "emissive": [0.0, 0.0, 0.0],
             "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 1.0}
            for nm, c in (("floor", floor_albedo), ("wall", wall_albedo))]
    nrm = np.repeat(np.float32([[0, 0, 1], [0, 0, 1], [1, 0, 0], [1, 0, 0]])[:, None], 3, axis=1)
    return NormalizedScene(triangles=tris, normals=nrm, uv0=np.zeros((4, 3, 2), np.float32),
                           material=np.array([0, 0, 1, 1], np.int32), materials=mats)


def test_near_occlusion_at_a_concave_edge_is_the_closed_form_and_zero_in_the_open():
    from workers.kernels.probe_hits import near_occlusion
    from workers.raycast.embree import EmbreeRayCaster

    scene = _corner()
    caster = EmbreeRayCaster(scene.triangles)
    r, N = 0.3, 3000
    d = np.array([0.01, 0.05, 0.1, 0.2, 0.29, 0.31, 2.0])
    pos = np.zeros((len(d) * N, 3), np.float32)
    pos[:, 0] = np.repeat(d, N)
    pos[:, 1] = np.tile(np.linspace(-5, 5, N), len(d))
    up = np.tile(np.float32([0, 0, 1]), (len(pos), 1))
    nf = near_occlusion(scene, pos, up, up, caster, r, 8, 1e-4)
    a = np.zeros(len(pos))
    a[nf.index] = nf.a
    mean = a.reshape(len(d), N).mean(axis=1)
    # a floor point at distance d from an infinite wall: the cosine-weighted directions that reach the wall within
    # r project onto the unit disk's segment x > c = d/r (Malley): a = (acos c − c·√(1 − c²))/π
    c = np.minimum(d / r, 1.0)
    want = (np.arccos(c) - c * np.sqrt(1 - c * c)) / math.pi
    assert np.allclose(mean, want, atol=0.01), (mean, want)
    assert np.all(a.reshape(len(d), N)[d > r] == 0)                  # beyond the radius, and the open floor: 0 exactly
    assert nf.rays == len(pos) * 8
    # the occluders are the wall: its albedo, no emission; the hits' own material does not enter
    assert np.allclose(nf.albedo, (0.8, 0.6, 0.4), atol=1e-6) and np.all(nf.emission == 0)
    # a wall hit next to the floor sees the floor (both faces single-sided, seen from the front)
    side = np.tile(np.float32([1, 0, 0]), (N, 1))
    p = np.zeros((N, 3), np.float32)
    p[:, 2], p[:, 1] = 0.02, np.linspace(-5, 5, N)
    nf = near_occlusion(scene, p, side, side, caster, r, 8, 1e-4)
    assert nf.index.size > 0.9 * N and np.allclose(nf.albedo, 0.3, atol=1e-6)
    # seen from behind, a single-sided occluder carries no light (albedo 0, DDGI-P §4.1): the floor behind the wall
    q = p.copy()
    q[:, 0], q[:, 2] = -0.05, 0.0
    behind = near_occlusion(scene, q, up[:N], up[:N], caster, r, 8, 1e-4)
    assert behind.index.size > 0.5 * N and np.all(behind.albedo == 0)
