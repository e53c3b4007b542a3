"""The reference at G-buffer pixels and points (workers/kernels/reference.py), closed forms."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from workers.kernels.reference import exitant_radiance


def test_exitant_radiance_is_emission_plus_albedo_over_pi_times_irradiance():
    gb = SimpleNamespace(emission=np.full((2, 2, 3), 0.5, np.float32), albedo=np.full((2, 2, 3), 0.25, np.float32),
                         shaded=np.array([[True, False], [True, True]]))
    e_dir, e_ind = np.full((2, 2, 3), 2.0), np.full((2, 2, 3), 1.0)
    out = exitant_radiance(gb, e_dir, e_ind)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0, 0], 0.5 + 0.25 / math.pi * 3.0, rtol=1e-6)
    np.testing.assert_array_equal(out[0, 1], 0.0)                      # not shaded (a back face, no geometry)


def _far_triangle():
    from tests.kernels.test_pathtrace import _material, _scene

    return _scene([[[0, -1000, 0], [0.001, -1000, 0], [0, -1000, 0.001]]], [_material(0.5)])


def test_irradiance_at_points_open_sky_is_pi_l_exactly():
    """Every path misses: E_indirect = π·L per path, so the estimate is exact with standard error 0; the direct
    light is :func:`direct_irradiance`'s; one batch per ``batch_points`` points."""
    from workers.kernels.reference import irradiance_at_points
    from workers.kernels.shading import direct_irradiance
    from workers.raycast import RayCaster

    s = _far_triangle()
    pts = np.array([[0, 0, 0], [1, 2, 3], [5, 0, 0.0]])
    nrm = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    light = [{"type": "point", "position": [0, 3, 0], "intensity": 9.0, "color": [1, 1, 1], "range": None}]
    seen = []
    e_dir, e_ind, err, stats = irradiance_at_points(s, pts, nrm, nrm, light, sky=(0.5, 1.0, 2.0), spp=16, bounces=2,
                                                    eps=1e-4, batch_points=2, report=seen.append)
    np.testing.assert_allclose(e_ind, np.tile(math.pi * np.array([0.5, 1.0, 2.0]), (3, 1)), rtol=1e-6)
    np.testing.assert_allclose(err, 0.0, atol=1e-12)                   # (rounding of a variance of equal terms)
    np.testing.assert_allclose(e_dir, direct_irradiance(pts, nrm, light, RayCaster(s.triangles), 1e-4))
    assert e_dir[0, 0] == pytest.approx(1.0)                          # 9 cd at 3 m, facing it: 9/9 lux
    assert stats["batches"] == 2 and stats["rays"] > 0 and seen[-1] == 1.0


def test_irradiance_at_points_of_nothing():
    from workers.kernels.reference import irradiance_at_points

    seen = []
    e_dir, e_ind, err, stats = irradiance_at_points(_far_triangle(), np.zeros((0, 3)), np.zeros((0, 3)),
                                                    np.zeros((0, 3)), report=seen.append)
    assert e_dir.shape == e_ind.shape == err.shape == (0, 3) and stats == {} and seen == [1.0]


def test_refine_points_pools_more_paths_where_the_reference_is_dark_or_noisy():
    """Dark points (at most DARK_FRACTION of the mean) get max_spp paths; the others spp·2^k, more where a path's
    variance is larger (n >= c·sqrt(v / mean v)), within budget × N × spp extra paths; pooled by path count."""
    from workers.kernels.reference import DARK_FRACTION, refine_points

    e = np.array([[1.0] * 3, [1.0] * 3, [0.05] * 3, [0.001] * 3, [1.0] * 3, [0.2] * 3])   # mean 0.5418
    s = np.full((6, 3), 0.01)
    s[4] = 0.16              # per-path variance 256 x points 0 and 1's
    s[5] = 0.04              # 16 x
    d = np.zeros((6, 3))
    asked = []

    def trace(idx, n):
        asked.append((idx.tolist(), n))
        return np.full((len(idx), 3), 0.02), np.full((len(idx), 3), 0.01)

    assert 0.05 <= DARK_FRACTION * 0.5418 < 0.2
    e2, s2, paths = refine_points(trace, d, e, s, 64, 1024, budget=2.0)
    assert paths[2] == paths[3] == 1024                       # dark
    assert paths[4] > paths[5] > paths[0] == paths[1] == 64   # by their noise
    assert (paths[[0, 1, 4, 5]] - 64).sum() <= 2.0 * 6 * 64
    assert all(n in (64, 128, 256, 512, 1024) for n in paths)
    assert sorted(asked) == sorted((np.flatnonzero(paths == n).tolist(), int(n) - 64) for n in np.unique(paths[paths > 64]))
    np.testing.assert_allclose(e2[2], (64 * 0.05 + 960 * 0.02) / 1024)
    np.testing.assert_allclose(s2[3], np.sqrt((64 * 0.01) ** 2 + (960 * 0.01) ** 2) / 1024)
    np.testing.assert_allclose(e2[4], (64 * 1.0 + (paths[4] - 64) * 0.02) / paths[4])
    np.testing.assert_array_equal(e2[:2], e[:2])
    # a larger budget refines more; none leaves the dark points alone and spends nothing else
    more = refine_points(trace, d, e, s, 64, 1024, budget=8.0)[2]
    assert (more >= paths).all() and more.sum() > paths.sum()
    assert refine_points(trace, d, e, s, 64, 1024, budget=0.0)[2].tolist() == [64, 64, 1024, 1024, 64, 64]
    # nothing more when max_spp <= spp, or nothing is dark or noisy
    asked.clear()
    assert refine_points(trace, d, e, s, 64, 64)[2].tolist() == [64] * 6 and asked == []
    assert refine_points(trace, d[:3], np.ones((3, 3)), s[:3] * 0, 64, 1024)[2].tolist() == [64] * 3 and asked == []


def test_refine_points_pools_the_noise_over_neighbours_that_face_the_same_way():
    """A pilot point that saw no noise, among same-facing neighbours that did, is refined like them (its own few
    paths missed the rare bright ones); a point facing the other way at the same place is not pooled with them."""
    from workers.kernels.reference import POOL_NEIGHBOURS, refine_points

    n = 40
    pos = np.zeros((n, 3))
    pos[:, 0] = np.arange(n) * 0.01
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))
    e = np.ones((n, 3))
    s = np.full((n, 3), 0.01)
    s[:8] = 0.2                       # a noisy cluster at x < 0.08
    s[3] = 0.0                        # ... one of whose points saw no noise
    nrm[5] = [0.0, -1.0, 0.0]         # ... and one faces the other way, its own noise nil
    s[5] = 0.0
    trace = lambda idx, k: (np.ones((len(idx), 3)), np.full((len(idx), 3), 0.01))
    alone = refine_points(trace, np.zeros((n, 3)), e, s, 64, 1024, budget=1.0)[2]
    assert alone[3] == alone[5] == 64 and alone[0] > 64
    surface = {"position": pos, "normal": nrm}
    pooled = refine_points(trace, np.zeros((n, 3)), e, s, 64, 1024, budget=1.0, surface=surface)[2]
    assert POOL_NEIGHBOURS >= 8
    assert pooled[3] > 64 and pooled[3] >= pooled[20]
    assert pooled[5] == 64
    # with albedo and emission the tone-mapped noise is weighed too (the same choice here)
    surface.update(albedo=np.full((n, 3), 0.7), emission=np.zeros((n, 3)))
    tm = refine_points(trace, np.zeros((n, 3)), e, s, 64, 1024, budget=1.0, surface=surface)[2]
    assert tm[3] > 64 and tm[5] == 64


def test_refinement_chosen_on_a_pilot_leaves_values_and_errors_unbiased():
    """refine_points' pilot (kernels/reference.py): heavy-tailed paths (2% carry 40, the rest 0.2; mean 0.996), 16
    paths a point, refined up to 256. Chosen on the first pass itself, the points whose paths missed the rare bright
    ones look certain and stay (72% of them, at 0.2): the pooled mean reads 0.54 of the truth and the squared error
    is 3.1x the mean s² the metrics subtract (kernels/point_metrics.py, "Noise bias"). Chosen on an independent
    8-path pilot, both are unbiased: the mean within 1%, E|E − R|² / mean s² within 3% (measured: 1.006, 1.008)."""
    from workers.kernels.reference import pilot_spp, refine_points

    n_pts, spp, p_hi, hi, lo = 20000, 16, 0.02, 40.0, 0.2
    truth = p_hi * hi + (1 - p_hi) * lo
    rng = np.random.default_rng(0)

    def paths(n, k):
        """n points' mean and standard error of k paths each, (n, 3)."""
        bright = rng.binomial(k, p_hi, size=n)
        m = (bright * hi + (k - bright) * lo) / k
        var = (bright * (hi - m) ** 2 + (k - bright) * (lo - m) ** 2) / (k - 1)
        return np.repeat(m[:, None], 3, 1), np.repeat(np.sqrt(var / k)[:, None], 3, 1)

    def refined(pilot: bool):
        e, s = paths(n_pts, spp)
        p = (*paths(n_pts, pilot_spp(spp)), pilot_spp(spp)) if pilot else None
        e2, s2, n = refine_points(lambda idx, k: paths(len(idx), k), np.zeros((n_pts, 3)), e, s, spp, 256, pilot=p)
        assert n.max() > spp
        return float(e2[:, 0].mean() / truth), float(np.mean((e2[:, 0] - truth) ** 2) / np.mean(s2[:, 0] ** 2))

    assert pilot_spp(spp) == 8 and pilot_spp(192) == 48
    mean, err_ratio = refined(pilot=False)
    assert mean < 0.7 and err_ratio > 2.0, (mean, err_ratio)
    mean, err_ratio = refined(pilot=True)
    assert abs(mean - 1) < 0.02 and abs(err_ratio - 1) < 0.1, (mean, err_ratio)


def test_refine_points_gives_few_dark_points_a_share_of_the_paths():
    """Dark points share DARK_BUDGET × N × spp paths (a power-of-two multiple of spp each, at least max_spp, at most
    dark_max): 2 dark points among 1,000 get far more than max_spp, many get max_spp. A point whose pilot reads it
    above the dark threshold but within two standard errors of it (and at most twice the threshold) counts as dark;
    one as bright but certain does not."""
    from workers.kernels.reference import DARK_BUDGET, DARK_FRACTION, refine_points

    n, spp = 1000, 64
    e = np.ones((n, 3))
    e[:2] = 0.001                                            # dark
    e[2] = 1.5 * DARK_FRACTION                               # above the threshold, but noisy: ± 1 x threshold
    e[3] = 1.5 * DARK_FRACTION                               # the same, certain
    s = np.full((n, 3), 1e-4)
    s[2] = DARK_FRACTION
    trace = lambda idx, k: (np.full((len(idx), 3), 0.001), np.full((len(idx), 3), 1e-4))  # noqa: E731
    paths = refine_points(trace, np.zeros((n, 3)), e, s, spp, 1024, budget=0.0)[2]
    share = spp + DARK_BUDGET * n * spp / 3
    want = spp * 2 ** int(np.floor(np.log2(share / spp)))
    assert want > 1024 and paths[0] == paths[1] == paths[2] == want and paths[3] == spp
    assert refine_points(trace, np.zeros((n, 3)), e, s, spp, 1024, budget=0.0, dark_max=2048)[2][0] == 2048
    many = e.copy()
    many[: n // 2] = 0.001                                   # half the points dark: max_spp each
    assert set(refine_points(trace, np.zeros((n, 3)), many, s, spp, 1024, budget=0.0)[2][: n // 2]) == {1024}
