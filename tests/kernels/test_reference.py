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
    """Dark points (at most DARK_FRACTION of the mean) get max_spp paths; noisy ones spp·2^k, the least k that brings
    their noise under the target relative to their light (direct + indirect, at most NOISE_CAP x the mean);
    pooled by path count; the rest untouched; a budget on the extra paths relaxes the target."""
    from workers.kernels.reference import DARK_FRACTION, NOISE_CAP, NOISE_TARGET, refine_points

    e = np.array([[1.0] * 3, [1.0] * 3, [0.05] * 3, [0.001] * 3, [1.0] * 3, [0.2] * 3])   # mean 0.5418
    mean = 0.5418
    s = np.full((6, 3), 0.01)
    s[4] = 0.13              # relative to its light capped at 0.5 x mean: 0.48 -> 0.17 < 0.2 at 8 x 64 paths
    s[5] = 0.06              # relative to its light 0.2: 0.3 -> 0.21 at 2 x, 0.15 at 4 x 64 paths
    d = np.zeros((6, 3))
    asked = []

    def trace(idx, n):
        asked.append((idx.tolist(), n))
        return np.full((len(idx), 3), 0.02), np.full((len(idx), 3), 0.01)

    assert 0.05 <= DARK_FRACTION * mean < 0.2 and NOISE_CAP * mean < 1.0 and NOISE_TARGET == 0.2
    e2, s2, paths = refine_points(trace, d, e, s, 64, 1024, budget=100)
    assert sorted(asked) == [([2, 3], 960), ([4], 448), ([5], 192)]
    assert paths.tolist() == [64, 64, 1024, 1024, 512, 256]
    np.testing.assert_allclose(e2[2], (64 * 0.05 + 960 * 0.02) / 1024)
    np.testing.assert_allclose(e2[3], (64 * 0.001 + 960 * 0.02) / 1024)
    np.testing.assert_allclose(s2[3], np.sqrt((64 * 0.01) ** 2 + (960 * 0.01) ** 2) / 1024)
    np.testing.assert_allclose(e2[4], (64 * 1.0 + 448 * 0.02) / 512)
    np.testing.assert_array_equal(e2[:2], e[:2])
    # direct light counts in a point's light: point 5 lit directly is no longer noisy (its light is capped at
    # NOISE_CAP x the mean, 0.27: 0.06 / 0.27 = 0.22 -> 2 x); nor is point 4 with a tenth of its noise
    d[5] = 10.0
    s[4] = 0.013
    assert refine_points(trace, d, e, s, 64, 1024, budget=100)[2].tolist() == [64, 64, 1024, 1024, 64, 128]
    # the budget relaxes the target: at most 0.3 x N x spp = 115 extra paths -> only point 4, once (dark ones still)
    d[5] = 0.0
    s[4] = 0.13
    assert refine_points(trace, d, e, s, 64, 1024, budget=0.3)[2].tolist() == [64, 64, 1024, 1024, 128, 64]
    # nothing more when max_spp <= spp, or nothing is dark or noisy
    asked.clear()
    assert refine_points(trace, d, e, s, 64, 64)[2].tolist() == [64] * 6 and asked == []
    assert refine_points(trace, d[:3], np.ones((3, 3)), s[:3] * 0, 64, 1024)[2].tolist() == [64] * 3 and asked == []

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
