"""DDGI irradiance sampler (workers/kernels/ddgi.py) against a slow, obviously-correct reference."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import grid
from workers.kernels.ddgi import bias_scale, octahedral_bilinear, sample_irradiance
from workers.kernels.grid import ACTIVE, OFF, SLEEPING
from workers.kernels.octahedral import add_border, bilinear_sample


def _unit(a):
    a = np.asarray(a, np.float64)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def slow_reference(points, normals, views, counts, origin, spacing, pos, states, irr, dep, B=0.3):
    """One point and one probe at a time, straight from RTXGI's DDGIGetVolumeIrradiance (linear blend)."""
    spacing = np.asarray(spacing, np.float64)
    D = min(float(s) for s in spacing if s > 0)
    out = np.zeros((len(points), 3))
    for i in range(len(points)):
        x = np.asarray(points[i], np.float64)
        n = np.asarray(normals[i], np.float64)
        w_o = np.asarray(views[i], np.float64)
        xb = x + (n * 0.2 + w_o * 0.8) * (0.75 * D) * B  # DDGI-P eq 2
        base, alpha = grid.cell_coords(xb[None], counts, origin, spacing)
        cage = grid.cage_indices(base, counts)[0]
        num, den = np.zeros(3), 0.0
        for c in range(8):
            q = cage[c]
            if states[q] == OFF:
                continue
            off = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
            trilinear = np.prod(np.maximum(0.001, np.where(off == 1, alpha[0], 1 - alpha[0])))
            to_probe = pos[q] - x
            dist = np.linalg.norm(to_probe)
            cos = to_probe @ n / dist if dist > 0 else 0.0  # a point exactly on the probe: documented choice
            weight = ((cos + 1) / 2) ** 2 + 0.2
            r = np.linalg.norm(xb - pos[q])
            cheb = 1.0
            mean, mean2 = bilinear_sample(dep[q], xb - pos[q]).astype(np.float64) if r > 0 else (np.inf, np.inf)
            if r > mean:
                var = abs(mean * mean - mean2)
                cheb = (var / (var + (r - mean) ** 2)) ** 3
            weight *= max(0.05, cheb)
            weight = max(1e-6, weight)
            if weight < 0.2:
                weight *= weight * weight / 0.2**2
            weight *= trilinear
            num += weight * bilinear_sample(irr[q], n).astype(np.float64)
            den += weight
        out[i] = num / den if den > 0 else 0.0
    return out


def _random_volume(rng, counts=(3, 2, 4), spacing=(1.0, 1.5, 0.8), origin=(-1.0, 0.5, 2.0), n_irr=8, n_dep=16,
                   p_off=0.2):
    counts = np.array(counts)
    P = int(np.prod(counts))
    base = grid.base_positions(counts, origin, spacing)
    pos = base + rng.uniform(-0.3, 0.3, (P, 3)) * np.asarray(spacing)  # relocated
    states = rng.choice(np.array([OFF, ACTIVE, SLEEPING], np.uint8), P, p=[p_off, (1 - p_off) / 2, (1 - p_off) / 2])
    irr = add_border(rng.uniform(0, 3, (P, n_irr, n_irr, 3)).astype(np.float32))
    mean = rng.uniform(0.2, 2.5, (P, n_dep, n_dep))
    mean2 = mean**2 + rng.uniform(0, 0.3, (P, n_dep, n_dep)) ** 2
    dep = add_border(np.stack([mean, mean2], axis=-1).astype(np.float32))
    return counts, np.array(origin), np.array(spacing), pos, states, irr, dep


def _random_queries(rng, counts, origin, spacing, N):
    lo = np.asarray(origin) - 0.3 * np.asarray(spacing)
    hi = np.asarray(origin) + (np.asarray(counts) - 1 + 0.3) * np.asarray(spacing)  # a little outside too
    pts = rng.uniform(lo, hi, (N, 3))
    nrm = _unit(rng.standard_normal((N, 3)))
    view = _unit(rng.standard_normal((N, 3)))
    view = np.where((view * nrm).sum(1, keepdims=True) < 0, -view, view)  # the viewer is in front
    return pts, nrm, view


# ------------------------------------------------------------------------------------ octahedral_bilinear
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_octahedral_bilinear_equals_reference_exactly(dtype):
    rng = np.random.default_rng(0)
    maps = add_border(rng.random((7, 8, 8, 3)).astype(dtype))
    dirs = np.concatenate([rng.standard_normal((2000, 3)),
                           [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                            [0.3, 0, -1], [0, -0.3, -1], [1, 1, 0], [1, -1, -1e-9]]])
    probe = rng.integers(0, 7, len(dirs))
    got = octahedral_bilinear(maps, probe, dirs)
    want = np.stack([bilinear_sample(maps[p], d) for p, d in zip(probe, dirs)])
    assert got.dtype == want.dtype == dtype
    np.testing.assert_array_equal(got, want)


def test_octahedral_bilinear_rejects_bad_input():
    maps = add_border(np.zeros((2, 4, 4, 1), np.float32))
    with pytest.raises(ValueError):
        octahedral_bilinear(maps, [0], [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError):
        octahedral_bilinear(maps, [2], [[0.0, 0.0, 1.0]])


# ------------------------------------------------------------------------------------ sampler
def test_bias_scale_uses_min_positive_spacing():
    assert bias_scale([2.0, 0.0, 0.5], 0.3) == pytest.approx(0.75 * 0.5 * 0.3)
    assert bias_scale([1.0, 1.0, 1.0], 0.0) == 0.0


@pytest.mark.parametrize("seed", [0, 1])
def test_uniform_maps_return_the_constant(seed):
    rng = np.random.default_rng(seed)
    counts, origin, spacing, pos, states, _, _ = _random_volume(rng, p_off=0.0)
    P = len(pos)
    value = np.array([0.3, 1.2, 2.5], np.float32)
    irr = np.broadcast_to(value, (P, 10, 10, 3)).copy()
    dep = np.ones((P, 18, 18, 2), np.float32)  # every probe sees a wall at 1 m (zero variance)
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 3000)
    e = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep)
    assert e.dtype == np.float32 and e.shape == (3000, 3)
    np.testing.assert_allclose(e, np.broadcast_to(value, e.shape), rtol=2e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_matches_slow_reference(seed, dtype):
    rng = np.random.default_rng(seed)
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng)
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 300)
    # a few points exactly on probes and on un-relocated grid nodes
    pts[:5] = pos[:5]
    pts[5:10] = grid.base_positions(counts, origin, spacing)[-5:]
    args = (counts, origin, spacing, pos, states, irr.astype(dtype), dep.astype(dtype))
    got = sample_irradiance(pts.astype(dtype), nrm.astype(dtype), view.astype(dtype), *args)
    want = slow_reference(pts.astype(dtype), nrm.astype(dtype), view.astype(dtype), *args)
    assert np.any(want > 0)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)


def test_matches_reference_with_other_bias_and_flat_axis():
    rng = np.random.default_rng(7)
    # one probe along y (spacing 0 there): D comes from x and z only
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng, counts=(4, 1, 3), spacing=(0.7, 0.0, 1.1),
                                                                     n_irr=6, n_dep=10, p_off=0.1)
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 200)
    pts[:, 1] += rng.uniform(-1, 1, 200)
    for B in (0.0, 0.3, 1.0):
        got = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep, self_shadow_bias=B)
        want = slow_reference(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep, B=B)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)


def _wall_setup():
    """2x2x2 probes on the unit cube; a wall at x = 0.6 hides the x = 1 probes from points at x < 0.6.

    The x = 0 probes see open space (mean distance 10 m) and hold irradiance 1; the x = 1 probes see
    the wall 0.4 m away in every direction (tiny variance) and hold irradiance 0.
    """
    counts = np.array([2, 2, 2])
    origin, spacing = np.zeros(3), np.ones(3)
    pos = grid.base_positions(counts, origin, spacing)
    states = np.full(8, ACTIVE, np.uint8)
    behind = pos[:, 0] > 0.5
    irr = np.where(behind[:, None, None, None], 0.0, 1.0) * np.ones((8, 10, 10, 3))
    mean = np.where(behind, 0.4, 10.0)[:, None, None] * np.ones((8, 18, 18))
    dep = np.stack([mean, mean**2 + 1e-4], axis=-1)
    return counts, origin, spacing, pos, states, irr.astype(np.float32), dep.astype(np.float32)


def test_probe_behind_a_wall_gets_almost_no_weight():
    counts, origin, spacing, pos, states, irr, dep = _wall_setup()
    rng = np.random.default_rng(0)
    n = 200
    pts = np.stack([rng.uniform(0.05, 0.45, n), rng.uniform(0.1, 0.9, n), rng.uniform(0.1, 0.9, n)], axis=1)
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))  # parallel to the wall: wrap shading does not tell the sides apart
    e = sample_irradiance(pts, nrm, nrm, counts, origin, spacing, pos, states, irr, dep)
    assert e.min() > 0.99  # all but ~0.2% of the weight on the visible probes
    # without the wall the hidden probes get their trilinear share (about x of it)
    dep_open = np.stack([np.full((8, 18, 18), 10.0), np.full((8, 18, 18), 100.0)], axis=-1).astype(np.float32)
    e_open = sample_irradiance(pts, nrm, nrm, counts, origin, spacing, pos, states, irr, dep_open)
    assert np.all(e_open[:, 0] < 1.0 - 0.5 * pts[:, 0])
    np.testing.assert_allclose(e, slow_reference(pts, nrm, nrm, counts, origin, spacing, pos, states, irr, dep),
                               rtol=1e-5)


def test_off_probes_are_ignored():
    rng = np.random.default_rng(4)
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng, p_off=0.3)
    off = states == OFF
    assert off.any()
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 500)
    e = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep)
    irr2, dep2, pos2 = irr.copy(), dep.copy(), pos.copy()
    irr2[off] = 1e6
    dep2[off] = rng.uniform(0, 5, dep2[off].shape)
    pos2[off] += 0.1
    e2 = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos2, states, irr2, dep2)
    np.testing.assert_array_equal(e, e2)
    # with uniform maps the remaining probes still normalize to the constant
    irr_u = np.full_like(irr, 0.7)
    eu = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr_u, dep)
    live = np.any(eu != 0, axis=1)
    np.testing.assert_allclose(eu[live], 0.7, rtol=2e-6)


def test_all_off_cage_gives_zero():
    rng = np.random.default_rng(5)
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng, counts=(3, 2, 2), p_off=0.0)
    states = states.copy()
    # turn off the cage of the first cell along x (i = 0, 1): points there see no live probe
    ijk = grid.probe_grid_indices(counts)
    states[ijk[:, 0] <= 1] = OFF
    pts = origin + np.array([[0.5, 0.5, 0.5], [0.2, 0.9, 0.1]]) * spacing
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    e = sample_irradiance(pts, nrm, nrm, counts, origin, spacing, pos, states, irr, dep, self_shadow_bias=0.0)
    assert np.all(e == 0)
    states[:] = OFF
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 50)
    assert np.all(sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep) == 0)


def test_non_finite_rows_give_zero_and_others_are_unaffected():
    rng = np.random.default_rng(6)
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng, p_off=0.0)
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 6)
    ref = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep)
    pts[1] = np.nan
    nrm[3] = 0.0
    view[4] = np.inf
    e = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep)
    assert np.all(e[[1, 3, 4]] == 0)
    np.testing.assert_array_equal(e[[0, 2, 5]], ref[[0, 2, 5]])


def test_shape_validation():
    rng = np.random.default_rng(8)
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng)
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 4)
    with pytest.raises(ValueError):
        sample_irradiance(pts, nrm[:3], view, counts, origin, spacing, pos, states, irr, dep)
    with pytest.raises(ValueError):
        sample_irradiance(pts, nrm, view, counts, origin, spacing, pos[:-1], states, irr, dep)
    with pytest.raises(ValueError):
        sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr[..., :2], dep)
    with pytest.raises(ValueError):
        sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep[..., :1])
    assert sample_irradiance(pts[:0], nrm[:0], view[:0], counts, origin, spacing, pos, states, irr, dep).shape == (0, 3)


def test_trilinear_interpolation_without_visibility_effects():
    """Open space, bias 0, two probes on a line and normals perpendicular to it: the weights reduce to
    trilinear ones, so with irradiance = probe x-index the result is the fraction α along the line."""
    counts = np.array([2, 1, 1])
    origin, spacing = np.zeros(3), np.array([2.0, 0.0, 0.0])
    pos = grid.base_positions(counts, origin, spacing)
    states = np.full(2, ACTIVE, np.uint8)
    irr = np.stack([np.zeros((10, 10, 3)), np.ones((10, 10, 3))]).astype(np.float32)
    dep = np.stack([np.full((18, 18), 100.0), np.full((18, 18), 1e4)], axis=-1)[None].repeat(2, 0).astype(np.float32)
    x = np.array([0.5, 1.0, 1.5])
    pts = np.stack([x, np.zeros(3), np.zeros(3)], axis=1)
    nrm = np.tile([0.0, 1.0, 0.0], (3, 1))  # perpendicular to the probe line: wrap = 0.25 + 0.2 for both
    e = sample_irradiance(pts, nrm, nrm, counts, origin, spacing, pos, states, irr, dep, self_shadow_bias=0.0)
    # both probes: wrap = (0 + 1)²/4 + 0.2 = 0.45 (no crush), Chebyshev 1; corners repeated along the
    # one-probe y and z axes get trilinear factors 0.001 that cancel in the normalization, so E = α
    np.testing.assert_allclose(e, np.repeat((x / 2.0)[:, None], 3, axis=1), rtol=1e-6)


def test_a_large_batch_equals_its_parts():
    """200k float32 points in one call (the evaluate stage's size; speed is tests/bench's business): finite, and
    each point's value independent of the batch it came in (the first 10 alone give the same numbers)."""
    rng = np.random.default_rng(9)
    counts, origin, spacing, pos, states, irr, dep = _random_volume(rng, counts=(8, 8, 8), p_off=0.1)
    pts, nrm, view = _random_queries(rng, counts, origin, spacing, 200_000)
    pts, nrm, view = (a.astype(np.float32) for a in (pts, nrm, view))
    head = sample_irradiance(pts[:10], nrm[:10], view[:10], counts, origin, spacing, pos, states, irr, dep)
    out = sample_irradiance(pts, nrm, view, counts, origin, spacing, pos, states, irr, dep)
    assert out.shape == (200_000, 3) and np.isfinite(out).all()
    np.testing.assert_array_equal(out[:10], head)


@pytest.mark.parametrize("seed", range(3))
def test_cage_rays_equal_the_numpy_construction(seed):
    """cage_rays (numba) gives exactly the rays the light stage built with numpy temporaries before."""
    from workers.kernels.ddgi import cage_probes, cage_rays

    rng = np.random.default_rng(seed)
    counts, origin, spacing = (4, 3, 5), np.zeros(3), np.array([1.0, 1.5, 0.8])
    P = int(np.prod(counts))
    pos = grid.base_positions(counts, origin, spacing).reshape(-1, 3) + rng.normal(0, 0.1, (P, 3))
    states = rng.choice([ACTIVE, OFF, SLEEPING], P, p=[0.7, 0.2, 0.1]).astype(np.uint8)
    n = 500
    pts = rng.uniform(-0.5, 4.5, (n, 3))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    view = -nrm
    biased, cage = cage_probes(pts, nrm, view, counts, origin, spacing, 0.3)
    biased[:3] = pos[cage[:3, 0]]                 # points on a probe: the zero-length rays are skipped
    live, o, d, tfar, slot = cage_rays(biased, cage, pos, states)

    ref_live = states[cage] != OFF
    dv = pos[cage] - biased[:, None, :]
    dist = np.linalg.norm(dv, axis=-1)
    trace = ref_live & (dist > 1e-9)
    assert np.array_equal(live.astype(bool), ref_live)
    assert np.array_equal(slot, np.flatnonzero(trace))
    np.testing.assert_array_equal(o, np.broadcast_to(biased[:, None, :], dv.shape)[trace].astype(np.float32))
    np.testing.assert_array_equal(d, (dv[trace] / dist[trace][:, None]).astype(np.float32))
    np.testing.assert_array_equal(tfar, (dist[trace] * (1 - 1e-5)).astype(np.float32))
    assert (~trace[:3, 0]).all()
