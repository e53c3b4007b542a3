"""Gathering probe irradiance at points (workers/kernels/gather.py): the sampler and its sparse matrix agree."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import grid as kgrid
from workers.kernels.ddgi import sample_irradiance
from workers.kernels.gather import MatrixGather, SamplerGather, ddgi_weights
from workers.kernels.grid import ACTIVE, OFF

N = 6


def _probes(counts=(3, 2, 4), off=()):
    g = {"counts": list(counts), "origin": [0.0, 0.0, 0.0], "spacing": [1.0, 1.0, 1.0]}
    pos = kgrid.base_positions(g["counts"], g["origin"], g["spacing"]).reshape(-1, 3).astype(np.float32)
    P = pos.shape[0]
    states = np.full(P, ACTIVE)
    states[list(off)] = OFF
    depth = np.zeros((P, 10, 10, 2), np.float32)
    depth[..., 0], depth[..., 1] = 50.0, 2500.0                    # far: Chebyshev passes everywhere
    return g, pos, states, depth


def _points(rng, k, counts):
    pts = (rng.random((k, 3)) * (np.array(counts) - 1)).astype(np.float32)
    nrm = rng.normal(size=(k, 3))
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    return pts, nrm, nrm.copy()


@pytest.mark.parametrize("counts", [(3, 2, 4), (1, 3, 2)])
def test_ddgi_weights_reproduce_the_sampler(counts):
    rng = np.random.default_rng(0)
    g, pos, states, depth = _probes(counts, off=(1,))
    pts, nrm, view = _points(rng, 300, counts)
    vis = rng.integers(0, 2, (300, 8)).astype(np.uint8)
    W = ddgi_weights(pts, nrm, view, g, pos, states, depth, N, 0.3, vis)
    assert W.shape == (300, pos.shape[0] * (N + 2) ** 2) and W.nnz == 32 * 300
    maps = rng.random((pos.shape[0], N + 2, N + 2, 3)).astype(np.float32)
    ref = sample_irradiance(pts, nrm, view, g["counts"], g["origin"], g["spacing"], pos, states, maps, depth, 0.3,
                            visible=vis)
    assert np.allclose(W @ maps.reshape(-1, 3), ref, atol=1e-5)
    assert ddgi_weights(pts[:0], nrm[:0], view[:0], g, pos, states, depth, N, 0.3).shape == (0, W.shape[1])


def test_uniform_maps_gather_their_value_and_both_gathers_agree_for_a_batch():
    # the DDGI weights are normalized (DDGI-P §2.2): maps holding c everywhere give c at every point
    rng = np.random.default_rng(1)
    g, pos, states, depth = _probes()
    pts, nrm, view = _points(rng, 200, g["counts"])
    sampler = SamplerGather(pts, nrm, view, g, pos, states, depth, 0.3)
    matrix = MatrixGather(ddgi_weights(pts, nrm, view, g, pos, states, depth, N, 0.3))
    c = np.array([0.5, 1.5, 2.5, 3.0, 0.25, 7.0], np.float32)       # two configurations side by side
    uniform = np.broadcast_to(c, (pos.shape[0], N + 2, N + 2, 6)).copy()
    assert np.allclose(sampler(uniform), c, rtol=1e-5) and np.allclose(matrix(uniform), c, rtol=1e-5)
    maps = rng.random((pos.shape[0], N + 2, N + 2, 6)).astype(np.float32)
    both = sampler(maps)
    assert both.shape == (200, 6) and np.allclose(matrix(maps), both, atol=1e-5)
    assert np.array_equal(both[:, 3:], sampler(np.ascontiguousarray(maps[..., 3:])))


@pytest.mark.parametrize("counts", [(3, 2, 4), (1, 3, 2), (4, 1, 1)])
def test_sampler_gather_weights_once_equal_the_sampler(counts):
    # SamplerGather computes the sampler's weights once (sampler_weights) and blends each bounce's maps with
    # them: the sampler's values to float32 rounding, with OFF probes, occluded corners, one-probe axes, points
    # outside the grid and rows the sampler returns 0 for (non-finite point, zero normal)
    rng = np.random.default_rng(2)
    g, pos, states, depth = _probes(counts, off=(0, 2))
    pos = pos + rng.normal(0, 0.1, pos.shape).astype(np.float32)
    depth[..., 0] = rng.uniform(0.2, 2.0, depth.shape[:-1])                # Chebyshev active in places
    depth[..., 1] = depth[..., 0] ** 2 + rng.uniform(0, 0.2, depth.shape[:-1])
    pts, nrm, view = _points(rng, 400, counts)
    pts = pts + rng.uniform(-0.5, 0.5, pts.shape).astype(np.float32)        # some outside the grid
    view = np.roll(view, 1, axis=0)
    pts[3], nrm[4] = np.nan, 0.0
    vis = rng.integers(0, 2, (400, 8)).astype(np.uint8)
    maps = rng.random((pos.shape[0], N + 2, N + 2, 6)).astype(np.float32)
    for v in (None, vis):
        got = SamplerGather(pts, nrm, view, g, pos, states, depth, 0.3, v, n=N)(maps)
        for j in range(2):
            ref = sample_irradiance(pts, nrm, view, g["counts"], g["origin"], g["spacing"], pos, states,
                                    np.ascontiguousarray(maps[..., 3 * j:3 * j + 3]), depth, 0.3, visible=v)
            assert np.allclose(got[:, 3 * j:3 * j + 3], ref, rtol=2e-6, atol=1e-6)
            assert np.all(got[3:5] == 0) and np.any(ref != 0)
    with pytest.raises(ValueError):
        SamplerGather(pts, nrm, view, g, pos, states, depth, 0.3, n=N)(maps[:, 1:, 1:])   # built for n = 6


def test_sh_read_is_the_samplers_weights_over_each_cage_probes_clamped_sh_irradiance():
    """read='sh' (the light stage's gather, light.gather): the same weights as the map read, each cage probe's L2 SH
    irradiance at the point's normal (RH01 eq 7-8), clamped at 0 where the SH rings below it; constant radiance L
    gives π·L at any normal."""
    from workers.kernels.sh import sh_irradiance, sh_project
    from workers.kernels.sampling import fibonacci_sphere

    rng = np.random.default_rng(4)
    counts = (3, 2, 4)
    g, pos, states, depth = _probes(counts, off=(2,))
    pts, nrm, view = _points(rng, 400, counts)
    vis = rng.integers(0, 2, (400, 8)).astype(np.uint8)
    P = pos.shape[0]
    sh = rng.normal(size=(P, 9, 6)).astype(np.float32)           # two configurations: 6 columns
    maps = np.zeros((P, N + 2, N + 2, 6), np.float32)
    octa = SamplerGather(pts, nrm, view, g, pos, states, depth, 0.3, vis, n=N)
    gsh = SamplerGather(pts, nrm, view, g, pos, states, depth, 0.3, vis, n=N, read="sh")
    assert gsh.reads_sh and not octa.reads_sh
    got = gsh(maps, sh)
    w = octa.weights
    want = np.zeros((400, 6))
    for c in range(8):
        q = w.base + (c & 1) * w.steps[0] + ((c >> 1) & 1) * w.steps[1] + ((c >> 2) & 1) * w.steps[2]
        e = sh_irradiance(sh[q].astype(np.float64), nrm.astype(np.float64))
        want += w.weight[:, c, None] * np.maximum(e, 0.0)
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5 * np.abs(want).max())
    assert (want[:, 0] > 0).sum() > 100 and (got >= 0).all()
    # RGB (C = 3) takes its own kernel: the same sums in the same order as the general one, so the same floats
    np.testing.assert_array_equal(gsh(maps[..., :3], np.ascontiguousarray(sh[..., 3:])), got[:, 3:])
    # constant radiance: π·L wherever the weights sum to 1
    L = np.array([0.5, 1.0, 2.0])
    dirs = fibonacci_sphere(4096)
    c = sh_project(dirs, np.tile(L, (4096, 1)), order=2).astype(np.float32)      # (9, 3)
    flat = np.broadcast_to(c, (P, 9, 3)).copy()
    e = gsh(maps[..., :3], flat)
    ok = w.weight.sum(1) > 0.5
    assert ok.sum() > 100
    np.testing.assert_allclose(e[ok], np.pi * L[None].repeat(ok.sum(), 0), rtol=2e-3)
    with pytest.raises(ValueError):
        gsh(maps)                                                  # the SH read needs the SH
    with pytest.raises(ValueError):
        SamplerGather(pts, nrm, view, g, pos, states, depth, 0.3, read="maps")
