"""Mask Decomposition masks (workers/kernels/mask_fit.py): eq 5, eq 9, fill, filter, cluster volumes."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import mask_fit as F
from workers.kernels.coloring import parity_coloring
from workers.kernels.grid import ACTIVE, OFF
from workers.kernels.mask_field import field_fractions

from tests.kernels.mask_fields import random_field


def test_weighted_median_minimizes():
    # Σ w |v − m| is convex and piecewise linear with kinks at the v: its minimum is at one of them
    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 9))
        v, w = rng.random(n), rng.random(n)
        if rng.random() < 0.3:
            w[:] = 1.0                      # ties: a whole interval is optimal
        m = F._weighted_median(v.copy(), w.copy(), n)
        f = lambda x: float(np.sum(w * np.abs(v - x)))  # noqa: E731
        assert f(m) <= min(f(x) for x in v) + 1e-12
        assert v.min() <= m <= v.max()
    # two equal weights: the midpoint of the optimal interval
    assert F._weighted_median(np.array([0.2, 1.0]), np.array([0.5, 0.5]), 2) == pytest.approx(0.6)


def test_fit_masks_is_the_local_minimum_of_eq5():
    counts, S, K = (3, 3, 3), 3, 3
    theta, dc = random_field(counts, S, seed=2)
    rng = np.random.default_rng(0)
    g = rng.integers(0, K, 27)
    m = F.fit_masks(theta, dc, counts, S, g, K)
    r, mass = F.mask_residual(theta, dc, counts, S, g, m)
    assert 0 < r < mass
    assert np.all(m[dc] == 0) and m.min() >= 0 and m.max() <= 1
    for _ in range(10):                                    # no perturbation lowers eq 5
        pert = np.clip(m + rng.normal(0, 0.05, m.shape), 0, 1).astype(np.float32)
        assert F.mask_residual(theta, dc, counts, S, g, pert)[0] >= r - 1e-9


def test_parity_masks_have_zero_residual_and_copy_theta():
    counts, S = (4, 3, 3), 4
    theta, dc = random_field(counts, S, seed=5)
    states = np.full(36, ACTIVE)
    states[[5, 17]] = OFF
    g = parity_coloring(counts)
    m = F.fit_masks(theta, dc, counts, S, g, 8, states)
    q = F.quantize(m)
    assert F.mask_residual(theta, dc, counts, S, g, q, states)[0] == 0.0          # MD §3.2: R̂ = 0
    # channel k of a sample in a cell of base parity b is θ of corner k ^ b (bytes, exactly)
    cx, cy, cz, *_ = field_fractions(counts, S)
    base = (cx[None, None, :] & 1) | ((cy[None, :, None] & 1) << 1) | ((cz[:, None, None] & 1) << 2)
    corner_p = np.zeros(dc.shape + (8,), np.int64)
    for c in range(8):
        i = np.minimum(cx + (c & 1), 3)[None, None, :]
        j = np.minimum(cy + (c >> 1 & 1), 2)[None, :, None]
        k = np.minimum(cz + (c >> 2 & 1), 2)[:, None, None]
        corner_p[..., c] = i + 4 * (j + 3 * k)
    for k in range(8):
        c = k ^ base
        th = np.take_along_axis(theta, c[..., None], axis=3)[..., 0]
        off = np.isin(np.take_along_axis(corner_p, c[..., None], axis=3)[..., 0], [5, 17])
        sel = ~dc & ~off
        assert np.array_equal(q[..., k][sel], th[sel])


def test_fill_dont_care_from_neighbours():
    m = np.zeros((1, 1, 7, 2), np.float32)
    m[0, 0, 0] = [1, 0]
    m[0, 0, 6] = [0, 1]
    dc = np.zeros((1, 1, 7), bool)
    dc[0, 0, 1:6] = True
    out, n = F.fill_dont_care(m.copy(), dc)
    assert n == 5
    assert np.allclose(out[0, 0, :, 0], [1, 1, 1, 0.5, 0, 0, 0])   # nearest side wins, the middle averages
    assert np.allclose(out[0, 0, :, 1], [0, 0, 0, 0.5, 1, 1, 1])
    all_dc, n = F.fill_dont_care(np.ones((2, 2, 2, 1), np.float32), np.ones((2, 2, 2), bool))
    assert n == 0 and np.all(all_dc == 0)


def test_gaussian_filter_matches_scipy():
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(0)
    m = rng.random((6, 7, 9, 3)).astype(np.float32)
    for sigma in (0.5, 1.3):
        ref = ndimage.gaussian_filter(m.astype(np.float64), sigma=(sigma, sigma, sigma, 0), mode="nearest")
        assert np.allclose(F.gaussian_filter(m, sigma, keep_zeros=False), ref, atol=1e-6)
    assert np.array_equal(F.gaussian_filter(m, 0.0), m)
    # keep_zeros: a channel 0 at a sample stays 0, the others are the plain filter
    m[m < 0.3] = 0
    plain = F.gaussian_filter(m, 0.7, keep_zeros=False)
    kept = F.gaussian_filter(m, 0.7)
    assert np.all(kept[m == 0] == 0) and np.all(plain[m == 0] > 0)
    assert np.array_equal(kept[m > 0], plain[m > 0])


def test_light_aware_fit_lowers_eq9_and_keeps_bounds():
    counts, S, K = (3, 3, 2), 3, 2
    theta, dc = random_field(counts, S, seed=3)
    rng = np.random.default_rng(1)
    g = rng.integers(0, K, 18)
    sh = rng.random((18, 9, 3))
    m0 = F.fit_masks(theta, dc, counts, S, g, K)
    m1, info = F.light_aware_fit(m0, theta, dc, counts, S, g, sh, penalty=0.001)
    assert info["loss_after"] <= info["loss_before"] and info["scale"] > 0
    assert m1.min() >= 0 and m1.max() <= 1 and np.all(m1[dc] == m0[dc])
    # a huge penalty keeps the channels that were 0 at 0
    m2, _ = F.light_aware_fit(m0, theta, dc, counts, S, g, sh, penalty=1e9)
    assert np.all(m2[m0 == 0] == 0)
    # all visible, one cluster: eq 3 = eq 2 already with m = 1, the fit keeps it
    full = np.full_like(theta, 255)
    none = np.zeros_like(dc)
    ones = F.fit_masks(full, none, counts, S, np.zeros(18, np.int64), 1)
    assert np.all(ones == 1)
    m3, info3 = F.light_aware_fit(ones, full, none, counts, S, np.zeros(18, np.int64), sh)
    assert np.allclose(m3, 1) and info3["loss_after"] == pytest.approx(0, abs=1e-9)


def test_cluster_volumes_partition_the_probes():
    rng = np.random.default_rng(0)
    sh = rng.random((3, 2, 4, 4, 3)).astype(np.float32)
    g = rng.integers(0, 3, 24)
    states = np.full(24, ACTIVE)
    states[3] = OFF
    vols, w = F.cluster_volumes(sh, g, 3, states)
    total = sum(vols)
    on = (states != OFF).reshape(3, 2, 4)
    assert np.array_equal(total[on], sh[on]) and np.all(total[~on] == 0)
    assert np.array_equal(w.sum(-1), on.astype(np.float32))
    assert np.array_equal(np.argmax(w, -1)[on], g.reshape(3, 2, 4)[on])


def test_half_volume_rounds_and_counts_the_clamped():
    a = np.array([[0.0, 1.0, -3.14159, 1e-3], [7e4, -1e5, 65504.0, 2.0 ** -20]], np.float32)
    clamped = [0]
    h = F.half_volume(a, clamped)
    assert h.dtype == np.float16 and h.flags.c_contiguous and clamped == [2]
    assert h[1, 0] == 65504 and h[1, 1] == -65504 and h[1, 2] == 65504 and h[0, 1] == 1 and h[0, 0] == 0
    rel = np.abs(h[0, 2:].astype(np.float64) - a[0, 2:]) / np.abs(a[0, 2:])
    assert rel.max() <= 2.0 ** -11                           # 11 significant bits
    assert h[1, 3] > 0                                       # subnormal, not flushed


def test_quantize_rounds_to_bytes():
    q = F.quantize(np.array([-0.2, 0.0, 0.5, 1.0 / 255.0 * 0.49, 1.0, 1.7], np.float32))
    assert q.dtype == np.uint8 and q.tolist() == [0, 0, 128, 0, 255, 255]


def test_canonicalize_zeroes_free_channels_and_deep_dont_care():
    counts, S, K = (3, 2, 2), 2, 2
    g = np.zeros(12, np.int64)
    g[[2, 5, 8, 11]] = 1                                  # cluster 1: the x = 2 probes, in the second cell only
    q = np.full((2, 2, 4, K), 200, np.uint8)
    out = F.canonicalize(q, np.zeros((2, 2, 4), bool), counts, S, g, K)
    assert np.all(out[..., :2, 1] == 0) and np.all(out[..., 2:, 1] == 200)   # cell 0 has no cluster-1 corner
    assert np.all(out[..., 0] == 200)
    states = np.full(12, ACTIVE)
    states[[2, 5, 8, 11]] = OFF                           # OFF corners count as absent
    assert np.all(F.canonicalize(q, np.zeros((2, 2, 4), bool), counts, S, g, K, states)[..., 1] == 0)
    dc = np.ones((2, 2, 4), bool)                         # all inside geometry: no surface reads them
    assert np.all(F.canonicalize(q, dc, counts, S, g, K) == 0)
    dc[...] = False
    dc[..., 3] = True                                     # don't-care next to care samples: kept (filled values)
    assert np.array_equal(F.canonicalize(q, dc, counts, S, g, K), out)


def test_validation_messages():
    theta, dc = random_field((3, 3, 3), 2)
    with pytest.raises(ValueError, match="g must be in"):
        F.fit_masks(theta, dc, (3, 3, 3), 2, np.full(27, 5), 4)
