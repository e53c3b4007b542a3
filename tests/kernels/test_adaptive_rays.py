"""Adaptive probe rays (workers/kernels/adaptive_rays.py) and per-probe ray patterns (workers/kernels/sampling.py
ProbeRays) through the bounce integrator (workers/kernels/bounce.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels.adaptive_rays import (allocate_sets, extra_patterns, extra_rows, first_bounce_noise, merge_rows,
                                           pooled)
from workers.kernels.bounce import integrate_one, irradiance_maps
from workers.kernels.grid import ACTIVE, OFF
from workers.kernels.sampling import ProbeRays, pattern_of_grid, probe_rays, rotated_patterns

N = 4


def test_pattern_of_grid_gives_the_8_corners_of_every_cell_8_patterns():
    counts = (5, 4, 3)
    for k in (8, 16, 64):
        pat = pattern_of_grid(counts, k).reshape(3, 4, 5)                 # (nz, ny, nx)
        assert pat.min() >= 0 and pat.max() < k
        for z in range(2):
            for y in range(3):
                for x in range(4):
                    assert np.unique(pat[z:z + 2, y:y + 2, x:x + 2]).size == 8
    assert np.unique(pattern_of_grid((16, 16, 16), 64)).size == 64         # the blocks spread over all 64
    assert np.all(pattern_of_grid(counts, 1) == 0)


def test_probe_rays_gives_each_probe_its_own_pattern():
    rng = np.random.default_rng(3)
    pats = rotated_patterns(32, 4, rng)
    assert pats.shape == (4, 32, 3) and np.allclose(np.linalg.norm(pats, axis=-1), 1.0, atol=1e-6)
    assert not np.allclose(pats[0], pats[1])
    rays = ProbeRays(pats, np.array([2, 0, 3, 2, 1]))
    idx = np.array([0, 31, 32, 2 * 32 + 5, 4 * 32 + 7])                      # p·R + r
    want = np.stack([pats[2, 0], pats[2, 31], pats[0, 0], pats[3, 5], pats[1, 7]])
    assert np.array_equal(rays.of_rays(idx), want)
    assert np.array_equal(rays.of_probes(1, 3), pats[[0, 3]])
    assert [(k, list(i)) for k, i in rays.groups()] == [(0, [1]), (1, [4]), (2, [0, 3]), (3, [2])]
    one = probe_rays(pats[0], 5)
    assert one.patterns.shape == (1, 32, 3) and np.all(one.pattern == 0)
    with pytest.raises(ValueError):
        probe_rays(rays, 4)


def test_first_bounce_noise_is_the_relative_stderr_of_the_mean():
    P, R = 3, 16
    miss = np.zeros((P, R), bool)
    index = np.arange(P * R)
    base = np.zeros((P * R, 3), np.float32)
    base[:R] = 1.0                                      # probe 0: even light, no noise
    base[R] = 1.0                                       # probe 1: one bright ray of 16; probe 2: dark
    q = first_bounce_noise(index, miss, base, None, R)
    lum = np.zeros(R)
    lum[0] = 1.0
    assert q[0] == pytest.approx(0.0, abs=1e-9) and q[2] == 0.0
    assert q[1] == pytest.approx(lum.std() / (lum.mean() * math.sqrt(R)))
    # misses see the sky: a probe with only sky is even light
    q2 = first_bounce_noise(np.zeros(0, np.int64), np.ones((1, R), bool), np.zeros((0, 3), np.float32),
                            (0.3, 0.3, 0.3), R)
    assert q2[0] == pytest.approx(0.0, abs=1e-9)


def test_pooled_spreads_a_probe_over_its_neighbourhood():
    counts = (5, 5, 5)
    q = np.zeros(125)
    q[62] = 27.0                                        # the centre (2, 2, 2)
    p = pooled(q, counts).reshape(5, 5, 5)
    assert np.allclose(p[1:4, 1:4, 1:4], 1.0) and p.sum() == pytest.approx(27.0)
    assert np.allclose(pooled(np.full(125, 0.4), counts), 0.4)              # a constant stays (faces clipped)


def test_allocate_sets_follows_the_noise_within_the_budget():
    q = np.array([0.0, 0.1, 0.2, 0.4, 0.8, 0.8])
    states = np.array([ACTIVE, ACTIVE, ACTIVE, ACTIVE, ACTIVE, OFF])
    sets = allocate_sets(q, states, budget=0.5, max_sets=3)
    assert sets.sum() <= int(0.5 * 5) and sets.sum() >= 1
    assert sets[0] == 0 and sets[5] == 0                # no noise; OFF
    assert np.all(np.diff(sets[:5]) >= 0)               # more noise, more rays
    big = allocate_sets(q, states, budget=8.0, max_sets=3)
    assert np.array_equal(big, [0, 3, 3, 3, 3, 0])      # the cap, once the budget allows everything
    assert allocate_sets(q, states, budget=0.0, max_sets=3).sum() == 0
    assert np.array_equal(extra_rows(np.array([0, 2, 0, 1])), [1, 1, 3])


def test_extra_patterns_depend_on_the_probe_and_its_set_alone():
    """A probe's extra sets take different patterns, neighbouring probes others, and one probe allotted a set more
    or less changes no other probe's rays (numbered down the rows, it shifted every probe after it)."""
    k = 64
    sets = np.array([0, 3, 1, 0, 7, 2] + [1] * 200)
    parents = extra_rows(sets)
    pat = extra_patterns(parents, k)
    assert pat.shape == parents.shape and pat.min() >= 0 and pat.max() < k
    for p in np.flatnonzero(sets):
        mine = pat[parents == p]
        assert np.unique(mine).size == mine.size                  # a probe's sets differ
    firsts = pat[np.r_[0, np.flatnonzero(np.diff(parents)) + 1]]
    assert np.unique(firsts).size > 40                             # the probes spread over the patterns
    more = sets.copy()
    more[2] += 1                                                   # one probe a set more
    parents2 = extra_rows(more)
    pat2 = extra_patterns(parents2, k)
    for p in np.flatnonzero(sets):
        if p != 2:
            assert np.array_equal(pat2[parents2 == p], pat[parents == p])
    assert np.array_equal(pat2[parents2 == 2][:1], pat[parents == 2])
    assert extra_patterns(np.zeros(0, np.int64), k).size == 0


def test_merge_rows_is_each_probes_mean_over_its_rows():
    v = np.arange(5 * 2, dtype=np.float32).reshape(5, 2)     # 3 probes, then extra rows of probes 2 and 0
    out = merge_rows(v, np.array([2, 0]))
    assert np.allclose(out, [(v[0] + v[4]) / 2, v[1], (v[2] + v[3]) / 2])
    assert np.array_equal(merge_rows(v[:3], np.zeros(0, np.int64)), v[:3])


def _hits(P, R, seed=0):
    rng = np.random.default_rng(seed)
    index = np.flatnonzero(rng.random(P * R) < 0.8)
    miss = np.ones(P * R, bool)
    miss[index] = False
    return index, miss.reshape(P, R), rng.random((index.size, 3)).astype(np.float32)


def test_integrator_reads_each_probes_own_pattern():
    # one bounce, no gather: the maps are each probe's own irradiance_maps of its own rays' radiance
    P, R = 12, 64
    pats = rotated_patterns(R, 5, np.random.default_rng(1))
    rays = ProbeRays(pats, np.random.default_rng(2).integers(0, 5, P))
    index, miss, e = _hits(P, R)
    albedo = np.full((index.size, 3), math.pi, np.float32)                     # radiance = E_direct
    states = np.full(P, ACTIVE)
    states[3] = OFF
    irr, rad, _, _ = integrate_one(index, miss, albedo, e, rays, states, N, lambda m: None, sky=(0.2, 0.1, 0.05),
                                   bounces=1, max_bounces=1, tolerance=0.0)
    want_rad = np.zeros((P * R, 3), np.float32)
    want_rad[miss.ravel()] = (0.2, 0.1, 0.05)
    want_rad[index] = e
    assert np.allclose(rad, want_rad.reshape(P, R, 3))
    for p in range(P):
        own = irradiance_maps(pats[rays.pattern[p]], want_rad.reshape(P, R, 3)[p:p + 1], N, states[p:p + 1])
        assert np.allclose(irr[p], own[0], rtol=1e-5, atol=1e-6)
    wrong = irradiance_maps(pats[0], want_rad.reshape(P, R, 3), N, states)       # one pattern read for all
    assert not np.allclose(irr, wrong, rtol=1e-3)


def test_integrator_averages_a_probes_extra_rows():
    P, R = 4, 64
    pats = rotated_patterns(R, 3, np.random.default_rng(5))
    parents = np.array([1, 1, 3])
    rows = ProbeRays(pats, np.array([0, 0, 0, 0, 1, 2, 1]))                  # the probes, then their extra rows
    index, miss, e = _hits(P + parents.size, R, seed=4)
    albedo = np.full((index.size, 3), math.pi, np.float32)
    states = np.full(P + parents.size, ACTIVE)
    irr, rad, _, _ = integrate_one(index, miss, albedo, e, rows, states, N, lambda m: None, bounces=1, max_bounces=1,
                                   tolerance=0.0, parents=parents)
    assert irr.shape[0] == P and rad.shape[0] == P + parents.size
    each = [irradiance_maps(pats[rows.pattern[r]], rad[r:r + 1], N, states[r:r + 1])[0] for r in range(P + 3)]
    assert np.allclose(irr[0], each[0], rtol=1e-5, atol=1e-6)
    assert np.allclose(irr[1], (each[1] + each[4] + each[5]) / 3, rtol=1e-5, atol=1e-6)
    assert np.allclose(irr[3], (each[3] + each[6]) / 2, rtol=1e-5, atol=1e-6)
    assert not np.allclose(irr[1], each[1], rtol=1e-3)
    # iterated to convergence the tail is added to the extra rows' rays by their parent's factor: the rays still
    # give the merged maps (each hit gathers k_p/π x its own probe's first texel: probe p's series has its own
    # ratio, below 1 since the hits' albedo is π)
    probe_of_hit = np.concatenate([np.arange(P), parents])[index // R]
    k = (np.array([0.2, 0.7, 0.4, 0.55], np.float32) / np.float32(math.pi))[probe_of_hit][:, None]
    gather = lambda m: k * m[probe_of_hit, 1, 1]                                       # noqa: E731
    irr, rad, change, residual = integrate_one(index, miss, albedo, e, rows, states, N, gather, bounces=None,
                                               max_bounces=64, tolerance=1e-4, parents=parents)
    each = [irradiance_maps(pats[rows.pattern[r]], rad[r:r + 1], N, states[r:r + 1])[0] for r in range(P + 3)]
    assert 4 <= len(change) < 64 and residual[-1] < 1e-4              # converged, a tail of several % added
    assert np.allclose(irr[1], (each[1] + each[4] + each[5]) / 3, rtol=1e-4, atol=1e-6)
    assert np.allclose(irr[3], (each[3] + each[6]) / 2, rtol=1e-4, atol=1e-6)
    assert np.allclose(irr[0], each[0], rtol=1e-4, atol=1e-6)


def test_concat_hits_shifts_the_extra_rows_ray_indices():
    from workers.kernels.probe_hits import HitSurfaces, concat_hits

    def hs(P, R, index, k):
        f = np.full((len(index), 3), k, np.float32)
        return HitSurfaces(index=np.asarray(index, np.int64), position=f, normal=f, view=f, albedo=f, emission=f,
                           miss=np.zeros((P, R), bool), P=P, R=R, geo_normal=f, smooth_normal=f,
                           bent=np.zeros(len(index), bool))

    a, b = hs(3, 4, [0, 5, 11], 1.0), hs(2, 4, [1, 7], 2.0)
    c = concat_hits(a, b)
    assert c.P == 5 and c.R == 4 and c.miss.shape == (5, 4)
    assert np.array_equal(c.index, [0, 5, 11, 13, 19])                      # b's rows after a's 3 probes
    assert np.array_equal(c.albedo[:, 0], [1, 1, 1, 2, 2])
    assert a.position is None and b.position is None                        # consumed
    with pytest.raises(ValueError):
        concat_hits(hs(1, 4, [0], 1.0), hs(1, 8, [0], 1.0))
