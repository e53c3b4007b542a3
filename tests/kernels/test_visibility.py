"""The visibility field θ (workers/kernels/visibility.py; MD §3.4 step 1, eq 2, 5-6).

Scenes are tiny closed boxes built here as (T, 3, 3) float32 triangle soups with outward,
counter-clockwise faces (glTF), so back-face hits mean "inside".
"""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import visibility as V
from workers.kernels.grid import ACTIVE, OFF, base_positions, probe_count
from workers.raycast import EmbreeRayCaster

# the 6 faces of a box as corner-index quads (corner i at (lo|hi)[i & 1], [i >> 1 & 1], [i >> 2 & 1]),
# counter-clockwise seen from outside
_QUADS = [(4, 6, 2, 0), (3, 7, 5, 1), (1, 5, 4, 0), (6, 7, 3, 2), (2, 3, 1, 0), (5, 7, 6, 4)]


def box(lo, hi) -> np.ndarray:
    """(12, 3, 3) float32: a closed axis-aligned box with outward faces."""
    c = np.array([[(lo, hi)[(i >> a) & 1][a] for a in range(3)] for i in range(8)], np.float64)
    tris = [t for q in _QUADS for t in ((c[q[0]], c[q[1]], c[q[2]]), (c[q[0]], c[q[2]], c[q[3]]))]
    return np.array(tris, np.float32)


def far_speck() -> np.ndarray:
    """One tiny triangle far away from everything: open space."""
    return np.array([[[500, 500, 500], [500.01, 500, 500], [500, 500.01, 500]]], np.float32)


# a 2 x 2 x 3 grid of unit spacing: probe layers z = 0, 1, 2; a 0.2 m thick wall between layers 0 and 1
COUNTS, ORIGIN, SPACING = (2, 2, 3), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
WALL = box((-5.0, -5.0, 0.41), (6.0, 6.0, 0.59))
S = 8


def grid_probes(counts=COUNTS, origin=ORIGIN, spacing=SPACING):
    return base_positions(counts, origin, spacing), np.full(probe_count(counts), ACTIVE, np.int64)


def run(tris, *, counts=COUNTS, z_range=None, threads=2, states=None, **kw):
    caster = EmbreeRayCaster(tris, threads=threads)
    pos, st = grid_probes(counts)
    if states is not None:
        st = states
    Z = V.field_shape(counts, kw.pop("S", S))[0]
    return V.theta_slab(caster, counts, ORIGIN, SPACING, pos, st, S, z_range or (0, Z), **kw)


def sample_z():
    """z coordinate of every field row of the wall scene."""
    Z, Y, X = V.field_shape(COUNTS, S)
    return V.sample_positions(COUNTS, ORIGIN, SPACING, S, (0, Z)).reshape(Z, Y, X, 3)[:, 0, 0, 2]


# ---------------------------------------------------------------------- geometry of the field
def test_field_shape():
    assert V.field_shape((2, 2, 3), 8) == (16, 8, 8)
    assert V.field_shape((16, 8, 16), 8) == (120, 56, 120)
    assert V.field_shape((5, 1, 3), 4) == (8, 4, 16)  # one-probe axis: one cell
    with pytest.raises(ValueError):
        V.field_shape((0, 2, 2), 8)
    with pytest.raises(ValueError):
        V.field_shape((2, 2, 2), 0)


def test_sample_positions_geometry():
    counts, origin, spacing, s = (3, 4, 2), np.array([1.0, -2.0, 0.5]), np.array([2.0, 0.5, 3.0]), 4
    Z, Y, X = V.field_shape(counts, s)
    p = V.sample_positions(counts, origin, spacing, s, (0, Z))
    assert p.shape == (Z * Y * X, 3) and p.dtype == np.float64
    np.testing.assert_allclose(p[0], origin + spacing * 0.5 / s, rtol=0, atol=1e-12)  # first sample
    # sample (x, y, z) at origin + spacing * (cell + (sub + 0.5) / S), C order (z, y, x)
    z, y, x = np.meshgrid(np.arange(Z), np.arange(Y), np.arange(X), indexing="ij")
    f = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    want = origin + spacing * (f // s + (f % s + 0.5) / s)
    np.testing.assert_allclose(p, want, rtol=0, atol=1e-12)
    # texel centres of a texture over the grid box: (f + 0.5) / (cells * S) of the box extent
    box_ext = spacing * (np.array(counts) - 1)
    np.testing.assert_allclose(p, origin + box_ext * (f + 0.5) / np.array([X, Y, Z]), rtol=0, atol=1e-12)
    # a z range is the matching rows of the whole field
    np.testing.assert_array_equal(V.sample_positions(counts, origin, spacing, s, (1, 3)), p[1 * Y * X:3 * Y * X])


def test_sample_positions_one_probe_axis():
    # ny = 1: samples lie in the probe plane y = origin_y whatever the spacing
    p = V.sample_positions((2, 1, 2), (0.0, 3.0, 0.0), (1.0, 7.0, 1.0), 2, (0, 2))
    assert p.shape == (2 * 2 * 2, 3)
    np.testing.assert_array_equal(p[:, 1], 3.0)
    np.testing.assert_allclose(np.unique(p[:, 0]), [0.25, 0.75])


def test_slab_ranges_and_join():
    assert V.slab_ranges(24, 8, 1) == [(0, 24)]
    assert V.slab_ranges(24, 8, 2) == [(0, 16), (16, 24)]
    assert V.slab_ranges(24, 8, 3) == [(0, 8), (8, 16), (16, 24)]
    assert V.slab_ranges(24, 8, 10) == [(0, 8), (8, 16), (16, 24)]  # never an empty slab
    r = V.slab_ranges(40 * 6, 6, 7)
    assert r[0][0] == 0 and r[-1][1] == 240 and all(a % 6 == 0 and b % 6 == 0 for a, b in r)
    assert all(r[i][1] == r[i + 1][0] for i in range(len(r) - 1))
    sizes = [b - a for a, b in r]
    assert max(sizes) - min(sizes) <= 6
    with pytest.raises(ValueError):
        V.slab_ranges(25, 8, 2)
    with pytest.raises(ValueError):
        V.join_slabs([])


# ---------------------------------------------------------------------- θ
def test_open_space_all_visible():
    theta, dc, stats = run(far_speck())
    assert theta.shape == (16, 8, 8, 8) and theta.dtype == np.uint8
    assert dc.shape == (16, 8, 8) and dc.dtype == bool
    assert (theta == 255).all() and not dc.any()
    assert stats["rays"] == stats["primary_rays"] == 16 * 8 * 8 * 8 and stats["dont_care"] == 0


def test_wall_blocks_across_and_marks_inside():
    theta, dc, _ = run(WALL)
    z = sample_z()[:8]  # the first cell layer
    below, inside, above = z < 0.41, (z > 0.41) & (z < 0.59), (z > 0.59) & (z < 1.0)
    assert below.sum() == 3 and inside.sum() == 2 and above.sum() == 3
    lower, upper = [0, 1, 2, 3], [4, 5, 6, 7]  # corners at the cell's lower / upper probe layer
    cell0 = theta[:8]
    assert (cell0[below][..., lower] == 255).all() and (cell0[below][..., upper] == 0).all()
    assert (cell0[above][..., upper] == 255).all() and (cell0[above][..., lower] == 0).all()
    assert (cell0[inside] == 0).all()  # inside the wall: every probe is behind a surface
    assert dc[:8][inside].all() and not dc[:8][~inside].any()
    assert (theta[8:] == 255).all() and not dc[8:].any()  # the second cell has no wall


def test_theta_does_not_depend_on_where_the_scene_stands():
    # a wall 5-10 cm in front of the upper probes, and the same scene 2 km away: the rays stop short of their target
    # by a length that follows the scene's size, not its distance from the origin (it was 1e-4 x the largest
    # coordinate: 0.2 m there, so the rays stopped before the wall and saw through it)
    wall = box((-5.0, -5.0, 0.85), (6.0, 6.0, 0.9))
    thetas = []
    for shift in (0.0, 2000.0):
        off = np.array([shift, 0.0, shift])
        origin = tuple(np.add(ORIGIN, off))
        pos, st = grid_probes(COUNTS, origin)
        theta, dc, _ = V.theta_slab(EmbreeRayCaster(wall + off.astype(np.float32)), COUNTS, origin, SPACING, pos, st,
                                    S, (0, V.field_shape(COUNTS, S)[0]))
        thetas.append(theta)
    z = sample_z()[:8]
    assert (thetas[0][:8][z < 0.85][..., 4:] == 0).all()  # the wall hides the upper probes from below it
    np.testing.assert_array_equal(thetas[1], thetas[0])


def test_double_sided_wall_has_no_inside():
    n = WALL.shape[0]
    theta_ds, dc_ds, _ = run(WALL, double_sided_tris=np.ones(n, bool))
    theta, _, _ = run(WALL)
    assert not dc_ds.any()
    np.testing.assert_array_equal(theta_ds, theta)  # visibility itself ignores sidedness
    _, dc_idx, _ = run(WALL, double_sided_tris=np.arange(n))
    assert not dc_idx.any()


def test_off_probes_zero():
    pos, st = grid_probes()
    off = [1, 6, 9]  # probes (1,0,0), (0,1,1), (1,0,2)
    st[off] = OFF
    theta, dc, _ = run(far_speck(), states=st)
    Z = theta.shape[0]
    # corner c of cell k (k = z // S) is probe (c & 1) + 2 * (c >> 1 & 1) + 4 * (k + (c >> 2))
    for k in range(Z // S):
        for c in range(8):
            p = (c & 1) + 2 * ((c >> 1) & 1) + 4 * (k + (c >> 2))
            want = 0 if p in off else 255
            assert (theta[k * S:(k + 1) * S, :, :, c] == want).all(), (k, c)
    assert not dc.any()  # unblocked rays to 2 OFF probes against 6 open ones


def test_samples_in_a_solid_with_off_probes_are_inside():
    # a solid block holding the lower probe layer (OFF, as relocation would leave them); the
    # samples inside the block see those probes unblocked and the upper ones through back faces
    block = box((-5.0, -5.0, -5.0), (6.0, 6.0, 0.5))
    pos, st = grid_probes()
    st[:4] = OFF
    theta, dc, _ = run(block, states=st, z_range=(0, 8))
    z = sample_z()[:8]
    assert dc[z < 0.5].all() and not dc[z > 0.5].any()
    assert (theta[..., :4] == 0).all()
    assert (theta[z > 0.5][..., 4:] == 255).all() and (theta[z < 0.5][..., 4:] == 0).all()


def test_inside_rule_matches_parity_on_boxes():
    # several closed boxes floating in a 3 x 3 x 3 grid; probes inside a box are OFF
    tris = np.concatenate([box((0.3, 0.2, 0.35), (0.9, 1.4, 0.8)), box((1.2, 0.6, 1.1), (1.7, 1.15, 1.9)),
                           box((0.1, 1.3, 1.3), (0.7, 1.9, 1.7))])
    counts = (3, 3, 3)
    caster = EmbreeRayCaster(tris, threads=2)
    pos, st = grid_probes(counts)
    st[caster.inside_parity(pos, n_dirs=5)] = OFF
    Z, Y, X = V.field_shape(counts, 4)
    _, dc, _ = V.theta_slab(caster, counts, ORIGIN, SPACING, pos, st, 4, (0, Z))
    parity = caster.inside_parity(V.sample_positions(counts, ORIGIN, SPACING, 4, (0, Z)), n_dirs=5)
    assert parity.any()
    np.testing.assert_array_equal(dc.reshape(-1), parity)


def test_rays_one_ignores_jitter():
    a = run(WALL, jitter=0.0)
    b = run(WALL, jitter=0.4, seed=7)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_soft_rays_fractional_near_wall_edge():
    # a wall covering x < 0.5 only: rays from samples near x = 0.5 to jittered targets around the
    # upper probes pass on either side of its edge
    half = box((-5.0, -5.0, 0.41), (0.5, 6.0, 0.59))
    theta, dc, stats = run(half, rays=16, jitter=0.3, z_range=(0, 8))
    assert stats["secondary_rays"] == stats["samples"] * 8 * 15
    assert stats["rays"] == stats["samples"] * 8 * 16
    z = sample_z()[:8]
    upper = theta[z < 0.41][..., 4:]
    soft = (upper > 0) & (upper < 255)
    assert soft.any() and (upper == 0).any() and (upper == 255).any()
    # θ is a multiple of 255 / 16, rounded
    allowed = np.floor(np.arange(17) * 255 / 16 + 0.5).astype(np.uint8)
    assert np.isin(theta, allowed).all()
    theta_open, dc_open, _ = run(far_speck(), rays=16, jitter=0.3)
    assert (theta_open == 255).all() and not dc_open.any()


def test_soft_rays_depend_on_seed_only():
    half = box((-5.0, -5.0, 0.41), (0.5, 6.0, 0.59))
    a = run(half, rays=8, jitter=0.3, seed=1, z_range=(0, 8))[0]
    b = run(half, rays=8, jitter=0.3, seed=1, z_range=(0, 8))[0]
    c = run(half, rays=8, jitter=0.3, seed=2, z_range=(0, 8))[0]
    np.testing.assert_array_equal(a, b)
    assert (a != c).any()


# ---------------------------------------------------------------------- determinism
@pytest.mark.parametrize("rays", [1, 4])
@pytest.mark.parametrize("slabs", [2, 3])
def test_slabs_join_bit_identical(rays, slabs):
    half = box((-5.0, -5.0, 0.41), (0.5, 6.0, 0.59))
    counts = (2, 3, 4)  # 3 cell layers
    whole = run(half, counts=counts, rays=rays, jitter=0.3, seed=3)
    Z = whole[0].shape[0]
    parts = [run(half, counts=counts, rays=rays, jitter=0.3, seed=3, z_range=r)[:2]
             for r in V.slab_ranges(Z, S, slabs)]
    assert len(parts) == slabs
    theta, dc = V.join_slabs(parts)
    np.testing.assert_array_equal(theta, whole[0])
    np.testing.assert_array_equal(dc, whole[1])


def test_threads_and_chunks_identical(monkeypatch):
    half = box((-5.0, -5.0, 0.41), (0.5, 6.0, 0.59))
    counts = (5, 4, 3)
    one = run(half, counts=counts, rays=4, jitter=0.3, threads=1)
    two = run(half, counts=counts, rays=4, jitter=0.3, threads=2)
    monkeypatch.setattr(V, "CHUNK_RAYS", 4096)  # many chunks, each split over the threads
    small = run(half, counts=counts, rays=4, jitter=0.3, threads=2)
    for a, b in ((one, two), (one, small)):
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
    assert one[2]["rays"] == two[2]["rays"] == small[2]["rays"]


def test_empty_range_and_validation():
    theta, dc, stats = run(far_speck(), z_range=(4, 4))
    assert theta.shape == (0, 8, 8, 8) and dc.shape == (0, 8, 8) and stats["rays"] == 0
    with pytest.raises(ValueError):
        run(far_speck(), z_range=(0, 17))
    caster = EmbreeRayCaster(far_speck(), threads=1)
    pos, st = grid_probes()
    with pytest.raises(ValueError):
        V.theta_slab(caster, COUNTS, ORIGIN, SPACING, pos[:-1], st, S, (0, 8))
    with pytest.raises(ValueError):
        V.theta_slab(caster, COUNTS, ORIGIN, SPACING, pos, st, S, (0, 8), rays=0)


def test_probe_at_sample_is_visible():
    # a probe relocated exactly onto a sample: the zero-length ray is unblocked
    pos, st = grid_probes()
    p0 = V.sample_positions(COUNTS, ORIGIN, SPACING, S, (0, 1))[0]
    pos = pos.copy()
    pos[0] = p0
    caster = EmbreeRayCaster(far_speck(), threads=1)
    theta, dc, _ = V.theta_slab(caster, COUNTS, ORIGIN, SPACING, pos, st, S, (0, 1))
    assert theta[0, 0, 0, 0] == 255 and (theta == 255).all() and not dc.any()
