"""The bounce integrator (workers/kernels/bounce.py): closed forms, batches against single configurations."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

from workers.kernels.bounce import integrate, integrate_one, irradiance_maps
from workers.kernels.convergence import RHO_CAP, extrapolated_tail
from workers.kernels.gather import MatrixGather
from workers.kernels.grid import ACTIVE, OFF
from workers.kernels.sampling import fibonacci_sphere

N = 4            # interior texels per side
T = N + 2


def _rays(P=2, R=128):
    return fibonacci_sphere(R).astype(np.float32), P, R


def test_irradiance_maps_of_constant_radiance_is_pi_L_and_off_probes_are_dark():
    dirs, P, R = _rays(3)
    L = np.array([0.5, 1.0, 2.0], np.float32)
    rad = np.broadcast_to(L, (P, R, 3)).copy()
    states = np.array([ACTIVE, OFF, ACTIVE])
    maps = irradiance_maps(dirs, rad, N, states)
    assert maps.shape == (P, T, T, 3) and maps.dtype == np.float32
    assert np.allclose(maps[[0, 2]], math.pi * L, rtol=1e-5)            # DDGI-I eq 1, α = 0: a furnace gives π·L
    assert np.all(maps[1] == 0)


def _box(a: float, e0, P=2, R=128):
    """Every ray of every probe hits a front face of albedo a, lit by e0 (B, 3): a closed box in which every
    point sees the same irradiance; the gather reads probe 0's first interior texel."""
    dirs, P, R = _rays(P, R)
    H = P * R
    index = np.arange(H)
    miss = np.zeros((P, R), bool)
    albedo = np.full((H, 3), a, np.float32)
    e = np.broadcast_to(np.asarray(e0, np.float32)[:, None, :], (len(e0), H, 3)).copy()

    def gather(maps):
        return np.broadcast_to(maps[0, 1, 1], (H, maps.shape[-1]))

    return index, miss, albedo, e, dirs, np.full(P, ACTIVE), gather


@pytest.mark.parametrize("a", [0.3, 0.8])
def test_closed_box_sums_the_geometric_series(a):
    # E_b = a·(E0 + E_{b−1}) = E0 (a + a² + … + a^b); converged: E0·a/(1 − a)
    e0 = np.array([[1.0, 2.0, 3.0]])
    index, miss, albedo, e, dirs, states, gather = _box(a, e0)
    for b in (1, 2, 5):
        irr, rad, change, residual = integrate_one(index, miss, albedo, e[0], dirs, states, N, gather,
                                                   bounces=b, max_bounces=128, tolerance=1e-3)
        want = e0[0] * sum(a ** k for k in range(1, b + 1))
        assert len(change) == b and np.allclose(irr, want, rtol=1e-5)
        assert np.allclose(rad, want / math.pi, rtol=1e-5)               # L = a/π·(E0 + E_{b−1}) = E_b/π
    # a fixed count adds nothing; its residual is the light still to come: the tail estimate is exact for a
    # geometric series, δ_b·a/(1 − a) / E_b = a^b / (1 − a^b), at every bounce from the third while the increment
    # stands well above float32 rounding of the maps (a float32 product over the rays: ~1e-6 of E; at a = 0.8 the
    # last increments are 2e-5 of E, and BLAS builds differ there by 4%)
    _, _, change, residual = integrate_one(index, miss, albedo, e[0], dirs, states, N, gather, bounces=12,
                                           max_bounces=128, tolerance=1e-4)
    assert len(residual) == 12 and all(math.isinf(r) for r in residual[:2])
    for b, r in enumerate(residual, start=1):
        if b >= 3 and a ** b > 1e-3:
            assert r == pytest.approx(a ** b / (1 - a ** b), rel=1e-2), b
    # iterating to convergence: the ratios are all a, so the tail is known exactly at the first bounce that can
    # estimate it (three ratios: the fourth) and where it is at most RHO_CAP of the light (a = 0.8: the eighth),
    # and added; the maps and the rays are the limit
    irr, rad, change, residual = integrate_one(index, miss, albedo, e[0], dirs, states, N, gather, bounces=None,
                                               max_bounces=500, tolerance=1e-4)
    first = next(b for b in range(4, 100) if a ** b / (1 - a ** b) <= RHO_CAP)
    assert len(change) == first and all(math.isinf(r) for r in residual[:3]) and residual[-1] < 1e-4
    assert np.allclose(irr, e0[0] * a / (1 - a), rtol=1e-5)
    assert np.allclose(rad, e0[0] * a / (1 - a) / math.pi, rtol=1e-5)    # L = a/π·(E0 + E_∞) = E_∞/π


def test_a_probe_cycling_at_float32_rounding_does_not_hold_the_series():
    # sealed-box: two probes' maps toggled between two roundings forever (an increment of ~2e-6 of their value
    # every bounce, ratio 1); the others converge geometrically: the tail can be estimated and added
    P = 50
    value = np.ones((P, 1))
    deltas = [np.full((P, 1, 3), 0.5 ** b / 3) for b in range(8, 12)]
    for d in deltas:
        d[:2] = 2.4e-6 / 3                                          # the cyclers, per channel
    res, factor = extrapolated_tail(deltas, value)
    assert res[0] < 1e-4 and np.all(factor[:2] == 0) and np.allclose(factor[2:], 1.0)   # r = 0.5: r/(1 − r) = 1
    # an increment well above rounding with a ratio of 1 is light still arriving: not converged
    for d in deltas:
        d[:2] = 1e-4 / 3
    res, factor = extrapolated_tail(deltas, value)
    assert math.isinf(res[0]) and np.all(factor[:2] == 0)


def _probe_error(maps, limit, states):
    """Σ|E − E_∞| / Σ|E_∞| per live probe."""
    live = states != OFF
    return np.abs(maps - limit)[live].reshape(live.sum(), -1).sum(1) / np.abs(limit)[live].reshape(live.sum(), -1).sum(1)


def test_the_added_tail_meets_the_tolerance_in_fewer_bounces():
    # a scene whose series is not one geometric ratio (random albedos, a random gather): iterating to tolerance τ
    # with the tail added lands within τ of the limit at every probe, in fewer bounces than waiting for the tail
    # to fall below τ (the rule before light stage 12: the first fixed-count residual below τ)
    rng = np.random.default_rng(7)
    index, miss, albedo, dirs, states, gather = _random_scene(rng)
    albedo[:] = np.clip(albedo + 0.15, 0, 0.95)                     # bright: a long series
    e = rng.uniform(0, 5, (index.size, 3)).astype(np.float32)
    kw = dict(max_bounces=400)
    limit, _, _, _ = integrate_one(index, miss, albedo, e, dirs, states, N, gather, bounces=300, tolerance=0, **kw)
    _, _, _, plain = integrate_one(index, miss, albedo, e, dirs, states, N, gather, bounces=200, tolerance=0, **kw)
    for tol in (1e-2, 5e-3, 1e-3):
        irr, rad, change, residual = integrate_one(index, miss, albedo, e, dirs, states, N, gather, bounces=None,
                                                   tolerance=tol, **kw)
        # the tail is added to the rays as to the maps: the maps are still the rays' maps (the SH come from the rays)
        assert np.allclose(irradiance_maps(dirs, rad, N, states), irr, rtol=1e-4, atol=1e-6)
        waited = next(b for b, r in enumerate(plain, start=1) if r < tol)
        err = _probe_error(irr, limit, states)
        assert residual[-1] < tol and err.max() < tol, (tol, err.max())
        assert len(change) < waited, (tol, len(change), waited)
        # without the tail the same bounce count would be further off
        short, _, _, _ = integrate_one(index, miss, albedo, e, dirs, states, N, gather, bounces=len(change),
                                       tolerance=0, **kw)
        assert _probe_error(short, limit, states).max() > 2 * err.max()


def test_misses_see_the_sky_and_emission_adds_to_every_bounce():
    dirs, P, R = _rays(2)
    sky = np.array([0.2, 0.3, 0.4])
    none, empty = np.zeros(0, np.int64), np.zeros((0, 3), np.float32)
    irr, rad, _, _ = integrate_one(none, np.ones((P, R), bool), empty, empty, dirs, np.full(P, ACTIVE), N,
                                   lambda m: empty, sky=sky, bounces=None, max_bounces=16, tolerance=1e-3)
    assert np.allclose(irr, math.pi * sky, rtol=1e-5) and np.allclose(rad, sky)
    index, miss, albedo, e, dirs, states, gather = _box(0.5, np.zeros((1, 3)))
    irr, _, _, _ = integrate_one(index, miss, albedo, e[0], dirs, states, N, gather,
                                 emission=np.full_like(albedo, 1.0), bounces=3, max_bounces=3, tolerance=0)
    # L_b = 1 + a/π·E_{b−1}: E = π (1 + a + a²) after 3 bounces
    assert np.allclose(irr, math.pi * (1 + 0.5 + 0.25), rtol=1e-5)


def _random_scene(rng, P=3, R=96, H=200):
    dirs, P, R = _rays(P, R)
    index = np.sort(rng.choice(P * R, H, replace=False))
    miss = np.ones(P * R, bool)
    miss[index] = False
    albedo = rng.uniform(0.2, 0.9, (H, 3)).astype(np.float32)
    # a random linear gather whose rows sum to 1 (a convex blend of texels, like the DDGI sampler)
    W = sp.random(H, P * T * T, density=0.05, random_state=np.random.RandomState(1), dtype=np.float32).tocsr()
    W = sp.diags(1.0 / np.maximum(np.asarray(W.sum(axis=1)).ravel(), 1e-6)).astype(np.float32) @ W
    return index, miss.reshape(P, R), albedo, dirs, np.array([ACTIVE, OFF, ACTIVE]), MatrixGather(W.tocsr())


def test_a_batch_equals_its_configurations_one_at_a_time():
    rng = np.random.default_rng(3)
    index, miss, albedo, dirs, states, gather = _random_scene(rng)
    e = rng.uniform(0, 5, (3, index.size, 3)).astype(np.float32)
    e[1] *= 1e-3                                                    # dim: converges after the same ratio
    e[2, : index.size // 2] = 0                                     # half dark: another series
    got = {}

    def retire(ids, radiance, maps, b):
        for j, c in enumerate(ids):
            assert c not in got
            got[c] = (np.array(radiance[..., 3 * j:3 * j + 3]), np.array(maps[..., 3 * j:3 * j + 3]), b)

    log = integrate(index, miss, albedo, e, dirs, states, N, gather, retire, bounces=None, max_bounces=64,
                    tolerance=1e-4)
    assert sorted(got) == [0, 1, 2]
    for c in range(3):
        irr, rad, change, residual = integrate_one(index, miss, albedo, e[c], dirs, states, N, gather, bounces=None,
                                                   max_bounces=64, tolerance=1e-4)
        assert got[c][2] == log.bounces[c] == len(change) == len(log.change[c])
        assert np.allclose(got[c][1], irr, rtol=1e-5, atol=1e-7) and np.allclose(got[c][0], rad, rtol=1e-5, atol=1e-8)
        # the last residuals are small differences of float32 maps: a batch's wider product rounds otherwise
        # (up to 3e-4 with numpy 2.4's OpenBLAS); a column mix-up would be off by O(1)
        assert np.allclose(log.residual[c], residual, rtol=1e-3)
        assert np.all(irr[1] == 0)                                  # the OFF probe


def test_fixed_bounces_stop_every_configuration_there_and_report_progress():
    rng = np.random.default_rng(4)
    index, miss, albedo, dirs, states, gather = _random_scene(rng)
    e = rng.uniform(0, 1, (2, index.size, 3)).astype(np.float32)
    calls, fractions = [], []

    def retire(ids, radiance, maps, b):
        calls.append((list(ids), b))

    log = integrate(index, miss, albedo, e, dirs, states, N, gather, retire,
                    bounces=4, max_bounces=64, tolerance=1.0, report=fractions.append)
    assert calls == [([0, 1], 4)] and list(log.bounces) == [4, 4] and fractions == [0.25, 0.5, 0.75, 1.0]


def test_the_loops_ray_major_maps_equal_irradiance_maps():
    # integrate holds radiance ray-major and finishes its maps in one compiled pass (π · mean, OFF = 0, border):
    # irradiance_maps' numbers
    from workers.kernels.bounce import _RayMajorMaps
    rng = np.random.default_rng(6)
    for n, R, P, C in ((8, 128, 40, 3), (3, 32, 9, 6), (1, 16, 5, 3)):
        dirs = fibonacci_sphere(R).astype(np.float32)
        rad = (rng.random((P, R, C)) * 3).astype(np.float32)
        states = np.full(P, ACTIVE)
        states[::4] = OFF
        want = irradiance_maps(dirs, rad, n, states)
        got = _RayMajorMaps(dirs, n, states)(np.ascontiguousarray(rad.transpose(1, 0, 2)))
        assert got.shape == want.shape and got.dtype == np.float32
        assert np.allclose(got, want, rtol=1e-6, atol=1e-7) and np.all(got[::4] == 0)


@pytest.mark.parametrize("rho_near", [0.5, 0.2, 0.8])
def test_near_field_occlusion_in_a_closed_box(rho_near):
    # every hit sees part a of its hemisphere covered by a nearby surface of albedo ρ' lit as the hit is:
    # E = (1 − a)·M + a·ρ'·(E0 + E), M = alb·(E0 + E) the probes' maps; converged
    # E = ((1 − a)·alb + a·ρ')·E0 / (1 − (1 − a)·alb − a·ρ'). With ρ' = alb (a uniform box) nothing changes.
    from workers.kernels.probe_hits import NearField
    alb, a = 0.5, 0.3
    e0 = np.array([[1.0, 2.0, 3.0]])
    index, miss, albedo, e, dirs, states, gather = _box(alb, e0)
    H = index.size
    near = NearField(index=np.arange(H), a=np.full(H, a, np.float32), albedo=np.full((H, 3), rho_near, np.float32),
                     emission=np.zeros((H, 3), np.float32))
    irr, _, _, _ = integrate_one(index, miss, albedo, e[0], dirs, states, N, gather, bounces=None,
                                 max_bounces=500, tolerance=1e-5, near=near)
    k = (1 - a) * alb + a * rho_near
    E = k * e0[0] / (1 - k)
    assert np.allclose(irr, alb * (e0[0] + E), rtol=1e-4)
    if rho_near == alb:
        assert np.allclose(irr, e0[0] * alb / (1 - alb), rtol=1e-4)
    # the occluders' emission L'_e reaches the hit as a·π·L'_e (a light-only bounce: 2 bounces, E0 = 0)
    e1 = NearField(index=near.index, a=near.a, albedo=near.albedo, emission=np.full((H, 3), 2.0, np.float32))
    irr2, _, _, _ = integrate_one(index, miss, albedo, np.zeros_like(e[0]), dirs, states, N, gather, bounces=2,
                                  max_bounces=2, tolerance=0, near=e1)
    assert np.allclose(irr2, alb * a * math.pi * 2.0, rtol=1e-5)


def test_near_field_leaves_hits_without_occlusion_bit_identical():
    from workers.kernels.probe_hits import NearField
    rng = np.random.default_rng(5)
    index, miss, albedo, dirs, states, gather = _random_scene(rng)
    e = rng.uniform(0, 1, (index.size, 3)).astype(np.float32)
    kw = dict(bounces=6, max_bounces=6, tolerance=0)
    ref = integrate_one(index, miss, albedo, e, dirs, states, N, gather, **kw)
    empty = NearField(index=np.zeros(0, np.int64), a=np.zeros(0, np.float32), albedo=np.zeros((0, 3), np.float32),
                      emission=np.zeros((0, 3), np.float32))
    got = integrate_one(index, miss, albedo, e, dirs, states, N, gather, near=empty, **kw)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    # occlusion on a few hits changes those rays only at the first shaded bounce (the second)
    some = NearField(index=np.array([3, 7]), a=np.float32([0.4, 0.2]), albedo=np.full((2, 3), 0.1, np.float32),
                     emission=np.zeros((2, 3), np.float32))
    got = integrate_one(index, miss, albedo, e, dirs, states, N, gather, near=some, bounces=2, max_bounces=2,
                        tolerance=0)
    ref2 = integrate_one(index, miss, albedo, e, dirs, states, N, gather, bounces=2, max_bounces=2, tolerance=0)
    changed = np.flatnonzero(np.any(got[1].reshape(-1, 3) != ref2[1].reshape(-1, 3), axis=1))
    assert set(changed.tolist()) <= {int(index[3]), int(index[7])} and changed.size >= 1


@pytest.mark.parametrize("P, T, nb", [(5, 100, 1), (3000, 144, 2), (7, 324, 3)])
def test_channel_sums_are_numpys_float64_sums(P, T, nb):
    """The convergence statistics' per-probe sums (bounce._channel_sums) are numpy's, bit for bit, over values spread
    across six decades (where the summation order shows)."""
    from workers.kernels.bounce import _channel_sums

    rng = np.random.default_rng(P)
    x = (rng.random((P, T, 3 * nb)) * 10 ** rng.uniform(-3, 3, (P, T, 3 * nb))).astype(np.float32)
    want = x.reshape(P, T, nb, 3).sum(axis=1, dtype=np.float64)
    np.testing.assert_array_equal(_channel_sums(x).reshape(P, nb, 3), want)


@pytest.mark.parametrize("previous", [False, True])
def test_add_tail_is_the_numpy_expression(previous):
    """bounce._add_tail adds ρ·ΔE·f to the stopping configurations' rays as the numpy expression it replaced does,
    float32 for float32 (two of three configurations stopping: a column pick)."""
    from workers.kernels.bounce import _add_tail

    rng = np.random.default_rng(3)
    H, P, B, rows_all = 500, 40, 3, 900
    rows = rng.permutation(rows_all)[:H].astype(np.int64)
    rho, e_ind, e_prev = (rng.random((H, 3 * B), dtype=np.float32) for _ in range(3))
    cols = np.array([0, 1, 2, 6, 7, 8], np.int64)
    f = rng.random((P, cols.size), dtype=np.float32) * 3
    hit_probe = rng.integers(0, P, H).astype(np.int64)
    picked = rng.random((rows_all, cols.size), dtype=np.float32)
    want = picked.copy()
    d_e = e_ind[:, cols] - e_prev[:, cols] if previous else e_ind[:, cols]
    want[rows] += rho[:, cols] * d_e * f[hit_probe]
    _add_tail(picked, rows, rho, e_ind, e_prev if previous else np.zeros((0, 0), np.float32), cols, f, hit_probe)
    np.testing.assert_array_equal(picked, want)


def test_the_threaded_per_row_helpers_equal_one_numpy_pass():
    """The loop's helpers on two threads: a retiring configuration's rays in probe order (``_probe_major``) equal
    ``held[:, inv].transpose(1, 0, 2)`` made contiguous; the per-pattern products (``_RayMajorMaps``) and the
    shading of the hits split in halves give the floats of one thread."""
    from workers.kernels import bounce as kb
    from workers.kernels.sampling import ProbeRays, rotated_patterns

    rng = np.random.default_rng(2)
    held = rng.random((16, 11, 6), dtype=np.float32)
    inv = rng.permutation(11)
    got = kb._probe_major(held, inv)
    assert got.flags.c_contiguous and np.array_equal(got, np.ascontiguousarray(held[:, inv].transpose(1, 0, 2)))
    assert np.array_equal(kb._probe_major(held, None), np.ascontiguousarray(held.transpose(1, 0, 2)))

    R, P = 32, 90
    rays = ProbeRays(rotated_patterns(R, 5, rng).astype(np.float32), np.arange(P) % 5)
    acc = kb._RayMajorMaps(rays, 4, np.full(P, ACTIVE))
    rad = rng.random((R, P, 3), dtype=np.float32)
    two = acc(rad), acc.sh(rad)
    threads, kb._MAP_THREADS = kb._MAP_THREADS, 1
    try:
        one = acc(rad), acc.sh(rad)
    finally:
        kb._MAP_THREADS = threads
    assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])

    radiance = np.zeros((500, 3), np.float32)
    rows = rng.permutation(500)[:301]
    base, rho, e = (rng.random((301, 3), dtype=np.float32) for _ in range(3))
    kb._halves(lambda a, b: kb._shade_hits(radiance, rows[a:b], base[a:b], rho[a:b], e[a:b]), rows.size)
    want = np.zeros_like(radiance)
    want[rows] = base + rho * e
    assert np.array_equal(radiance, want)
