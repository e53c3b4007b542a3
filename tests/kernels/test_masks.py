"""Mask Decomposition kernels (workers/kernels/masks.py): eq 4-8 on synthetic θ fields."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from workers.kernels import masks as M
from workers.kernels.grid import ACTIVE, OFF


def _field(counts, S, seed=0, p_visible=0.6, p_dc=0.1):
    cells = np.maximum(np.asarray(counts) - 1, 1)
    shape = (cells[2] * S, cells[1] * S, cells[0] * S)
    rng = np.random.default_rng(seed)
    theta = np.where(rng.random(shape + (8,)) < p_visible, 255, rng.integers(0, 256, shape + (8,))).astype(np.uint8)
    theta[rng.random(shape + (8,)) < 0.3] = 0
    dc = rng.random(shape) < p_dc
    return theta, dc


def _brute_edges(theta, dc, counts, S, off=None):
    """E(i, j) of eq 6 by direct summation over samples (dict {(i, j): E})."""
    nx, ny, nz = counts
    cx, cy, cz, tx, ty, tz = M.field_fractions(counts, S)
    out: dict = {}
    Z, Y, X = dc.shape
    for z, y, x in itertools.product(range(Z), range(Y), range(X)):
        if dc[z, y, x]:
            continue
        f = (tx[x], ty[y], tz[z])
        probes, phis = [], []
        for c in range(8):
            o = (c & 1, (c >> 1) & 1, (c >> 2) & 1)
            i, j, k = (min(b + d, n - 1) for b, d, n in zip((cx[x], cy[y], cz[z]), o, counts))
            probes.append(i + nx * (j + ny * k))
            phis.append(np.prod([f[a] if o[a] else 1 - f[a] for a in range(3)]))
        for a, b in itertools.combinations(range(8), 2):
            pa, pb = probes[a], probes[b]
            if pa == pb:
                continue
            key = (min(pa, pb), max(pa, pb))
            dth = abs(int(theta[z, y, x, a]) - int(theta[z, y, x, b])) / 255
            out[key] = out.get(key, 0.0) + min(phis[a], phis[b]) * dth
    return out


@pytest.mark.parametrize("counts,S", [((3, 2, 2), 2), ((2, 3, 2), 3), ((3, 1, 2), 2), ((1, 1, 2), 4)])
def test_edge_loss_matches_direct_sum(counts, S):
    theta, dc = _field(counts, S, seed=S)
    pairs, w = M.edge_loss(theta, dc, counts, S)
    brute = _brute_edges(theta, dc, counts, S)
    got = {(int(a), int(b)): float(v) for (a, b), v in zip(pairs, w)}
    assert np.all(pairs[:, 0] < pairs[:, 1])
    assert set(got) == set(brute)            # exactly the pairs sharing a cell, E = 0 ones included
    for k in brute:
        assert got[k] == pytest.approx(brute[k], rel=1e-12, abs=1e-15)


def test_edge_count_is_pairs_sharing_a_cell():
    counts = (4, 3, 5)
    S = 1
    theta, dc = _field(counts, S)
    pairs, _ = M.edge_loss(theta, dc, counts, S)
    n = np.asarray(counts)
    expect = sum(int(np.prod(n - np.abs(d))) for d in M.HALF_DIRECTIONS)
    assert len(M.HALF_DIRECTIONS) == 13
    assert pairs.shape == (expect, 2) == (len({tuple(p) for p in pairs.tolist()}), 2)


def test_edge_loss_dont_care_and_off():
    counts, S = (3, 3, 2), 2
    theta, dc = _field(counts, S, p_dc=0.0)
    _, w = M.edge_loss(theta, np.ones_like(dc), counts, S)
    assert np.all(w == 0)                                           # don't-care samples weigh 0
    states = np.full(18, ACTIVE)
    states[4] = OFF
    pairs, w_off = M.edge_loss(theta, dc, counts, S, states)
    pairs_all, w_all = M.edge_loss(theta, dc, counts, S)
    assert not np.any(pairs == 4)
    keep = ~np.any(pairs_all == 4, axis=1)
    assert np.array_equal(pairs, pairs_all[keep]) and np.array_equal(w_off, w_all[keep])


def test_edge_loss_one_corner_visible_known_answer():
    # one cell, S = 2: θ = 1 for corner 0 only. E(0, j) = Σ_x min(φ0, φj), E = 0 between the others.
    counts, S = (2, 2, 2), 2
    theta = np.zeros((2, 2, 2, 8), np.uint8)
    theta[..., 0] = 255
    pairs, w = M.edge_loss(theta, np.zeros((2, 2, 2), bool), counts, S)
    E = dict(zip(map(tuple, pairs.tolist()), w))
    t = np.array([0.25, 0.75])
    # along x: min over samples of (1-tx)(…)(…) vs tx(…)(…), summed: Σ_y,z (1-ty)(1-tz) · Σ_x min(1-tx, tx)
    axis_edge = np.sum(np.minimum(1 - t, t)) * np.sum(1 - t) ** 2
    assert E[(0, 1)] == pytest.approx(axis_edge) and E[(0, 2)] == pytest.approx(axis_edge)
    assert E[(0, 4)] == pytest.approx(axis_edge)
    assert E[(1, 2)] == 0 and E[(3, 5)] == 0 and E[(6, 7)] == 0


def test_parity_coloring_separates_every_cell():
    counts = (5, 4, 3)
    g = M.parity_coloring(counts).reshape(3, 4, 5)
    for k, j, i in itertools.product(range(2), range(3), range(4)):
        cell = {int(g[k + (c >> 2 & 1), j + (c >> 1 & 1), i + (c & 1)]) for c in range(8)}
        assert cell == set(range(8))
    assert g[0, 0, 0] == 0 and g[1, 0, 1] == 5 and g[1, 1, 1] == 7       # eq 4: bit d = parity of index d


@pytest.mark.parametrize("K", [1, 2, 3, 4, 5, 8])
def test_convex_division_boxes(K):
    counts = (9, 4, 5)
    g = M.convex_division(counts, K, spacing=[0.95, 0.87, 0.9]).reshape(5, 4, 9)
    assert set(np.unique(g)) == set(range(K))
    sizes = np.bincount(g.ravel())
    assert sizes.max() <= 2.5 * sizes.min()
    for k in range(K):
        z, y, x = np.nonzero(g == k)
        box = g[z.min():z.max() + 1, y.min():y.max() + 1, x.min():x.max() + 1]
        assert np.all(box == k)                                   # each colour is a box of probes: convex


def _random_graph(seed, P=300, n=1200):
    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, P, n), rng.integers(0, P, n)
    keep = a != b
    pairs = np.unique(np.sort(np.stack([a[keep], b[keep]], 1), axis=1), axis=0)
    w = np.where(rng.random(len(pairs)) < 0.5, 0.0, rng.random(len(pairs)))
    return pairs, w


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("sweeps", [0, 1, 3, 50])
def test_anneal_never_ends_above_initial(seed, sweeps):
    pairs, w = _random_graph(seed)
    init = np.zeros(300, np.int64)                     # one colour: eq 7 at its maximum
    g, loss, info = M.anneal(pairs, w, 300, 3, sweeps=sweeps, regularization=0.01, seed=seed, init=init)
    e7, e8 = M.coloring_loss(pairs, w, g, 0.01)
    assert loss.shape == (sweeps + 1,)
    assert loss[0] == pytest.approx(w.sum())
    assert info["final_loss"] == pytest.approx(e7 + e8) == pytest.approx(loss.min())
    assert info["final_loss"] <= info["initial_loss"]
    if sweeps >= 50:
        assert e7 + e8 < 0.2 * loss[0]


def test_anneal_seeded_and_reproducible():
    pairs, w = _random_graph(7)
    a = M.anneal(pairs, w, 300, 4, sweeps=40, seed=3)
    b = M.anneal(pairs, w, 300, 4, sweeps=40, seed=3)
    c = M.anneal(pairs, w, 300, 4, sweeps=40, seed=4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[1], c[1])                  # another seed takes another path


def test_anneal_off_probes_never_move():
    pairs, w = _random_graph(1)
    states = np.full(300, ACTIVE)
    states[:50] = OFF
    init = M.convex_division((300, 1, 1), 4)
    g, _, info = M.anneal(pairs, w, 300, 4, sweeps=20, init=init, states=states)
    assert np.array_equal(g[:50], init[:50])
    assert info["movable"] <= 250


def test_anneal_degenerate_cases():
    pairs, w = _random_graph(2)
    g, loss, info = M.anneal(pairs, w, 300, 1, sweeps=5)              # one colour: nothing to do
    assert np.all(g == 0) and np.allclose(loss, w.sum()) and info["accepted"] == 0
    g, loss, _ = M.anneal(np.zeros((0, 2)), np.zeros(0), 10, 4, sweeps=3)    # no edges
    assert loss.shape == (4,) and np.all(loss == 0)


def test_temperature_schedule_geometric():
    T = M.temperature_schedule([0.0, 0.2, 0.4], 5, regularization=0.001)
    assert T[0] == pytest.approx(0.9) and T[-1] == pytest.approx(1e-4)
    assert np.allclose(T[1:] / T[:-1], T[1] / T[0])


def test_weighted_median_minimizes():
    # Σ w |v − m| is convex and piecewise linear with kinks at the v: its minimum is at one of them
    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 9))
        v, w = rng.random(n), rng.random(n)
        if rng.random() < 0.3:
            w[:] = 1.0                      # ties: a whole interval is optimal
        m = M._weighted_median(v.copy(), w.copy(), n)
        f = lambda x: float(np.sum(w * np.abs(v - x)))  # noqa: E731
        assert f(m) <= min(f(x) for x in v) + 1e-12
        assert v.min() <= m <= v.max()
    # two equal weights: the midpoint of the optimal interval
    assert M._weighted_median(np.array([0.2, 1.0]), np.array([0.5, 0.5]), 2) == pytest.approx(0.6)


def test_fit_masks_is_the_local_minimum_of_eq5():
    counts, S, K = (3, 3, 3), 3, 3
    theta, dc = _field(counts, S, seed=2)
    rng = np.random.default_rng(0)
    g = rng.integers(0, K, 27)
    m = M.fit_masks(theta, dc, counts, S, g, K)
    r, mass = M.mask_residual(theta, dc, counts, S, g, m)
    assert 0 < r < mass
    assert np.all(m[dc] == 0) and m.min() >= 0 and m.max() <= 1
    for _ in range(10):                                    # no perturbation lowers eq 5
        pert = np.clip(m + rng.normal(0, 0.05, m.shape), 0, 1).astype(np.float32)
        assert M.mask_residual(theta, dc, counts, S, g, pert)[0] >= r - 1e-9


def test_parity_masks_have_zero_residual_and_copy_theta():
    counts, S = (4, 3, 3), 4
    theta, dc = _field(counts, S, seed=5)
    states = np.full(36, ACTIVE)
    states[[5, 17]] = OFF
    g = M.parity_coloring(counts)
    m = M.fit_masks(theta, dc, counts, S, g, 8, states)
    q = M.quantize(m)
    assert M.mask_residual(theta, dc, counts, S, g, q, states)[0] == 0.0          # MD §3.2: R̂ = 0
    # channel k of a sample in a cell of base parity b is θ of corner k ^ b (bytes, exactly)
    cx, cy, cz, *_ = M.field_fractions(counts, S)
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
    out, n = M.fill_dont_care(m.copy(), dc)
    assert n == 5
    assert np.allclose(out[0, 0, :, 0], [1, 1, 1, 0.5, 0, 0, 0])   # nearest side wins, the middle averages
    assert np.allclose(out[0, 0, :, 1], [0, 0, 0, 0.5, 1, 1, 1])
    all_dc, n = M.fill_dont_care(np.ones((2, 2, 2, 1), np.float32), np.ones((2, 2, 2), bool))
    assert n == 0 and np.all(all_dc == 0)


def test_gaussian_filter_matches_scipy():
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(0)
    m = rng.random((6, 7, 9, 3)).astype(np.float32)
    for sigma in (0.5, 1.3):
        ref = ndimage.gaussian_filter(m.astype(np.float64), sigma=(sigma, sigma, sigma, 0), mode="nearest")
        assert np.allclose(M.gaussian_filter(m, sigma, keep_zeros=False), ref, atol=1e-6)
    assert np.array_equal(M.gaussian_filter(m, 0.0), m)
    # keep_zeros: a channel 0 at a sample stays 0, the others are the plain filter
    m[m < 0.3] = 0
    plain = M.gaussian_filter(m, 0.7, keep_zeros=False)
    kept = M.gaussian_filter(m, 0.7)
    assert np.all(kept[m == 0] == 0) and np.all(plain[m == 0] > 0)
    assert np.array_equal(kept[m > 0], plain[m > 0])


def test_light_aware_fit_lowers_eq9_and_keeps_bounds():
    counts, S, K = (3, 3, 2), 3, 2
    theta, dc = _field(counts, S, seed=3)
    rng = np.random.default_rng(1)
    g = rng.integers(0, K, 18)
    sh = rng.random((18, 9, 3))
    m0 = M.fit_masks(theta, dc, counts, S, g, K)
    m1, info = M.light_aware_fit(m0, theta, dc, counts, S, g, sh, penalty=0.001)
    assert info["loss_after"] <= info["loss_before"] and info["scale"] > 0
    assert m1.min() >= 0 and m1.max() <= 1 and np.all(m1[dc] == m0[dc])
    # a huge penalty keeps the channels that were 0 at 0
    m2, _ = M.light_aware_fit(m0, theta, dc, counts, S, g, sh, penalty=1e9)
    assert np.all(m2[m0 == 0] == 0)
    # all visible, one cluster: eq 3 = eq 2 already with m = 1, the fit keeps it
    full = np.full_like(theta, 255)
    none = np.zeros_like(dc)
    ones = M.fit_masks(full, none, counts, S, np.zeros(18, np.int64), 1)
    assert np.all(ones == 1)
    m3, info3 = M.light_aware_fit(ones, full, none, counts, S, np.zeros(18, np.int64), sh)
    assert np.allclose(m3, 1) and info3["loss_after"] == pytest.approx(0, abs=1e-9)


def test_cluster_volumes_partition_the_probes():
    rng = np.random.default_rng(0)
    sh = rng.random((3, 2, 4, 4, 3)).astype(np.float32)
    g = rng.integers(0, 3, 24)
    states = np.full(24, ACTIVE)
    states[3] = OFF
    vols, w = M.cluster_volumes(sh, g, 3, states)
    total = sum(vols)
    on = (states != OFF).reshape(3, 2, 4)
    assert np.array_equal(total[on], sh[on]) and np.all(total[~on] == 0)
    assert np.array_equal(w.sum(-1), on.astype(np.float32))
    assert np.array_equal(np.argmax(w, -1)[on], g.reshape(3, 2, 4)[on])


def test_validation_messages():
    theta, dc = _field((3, 3, 3), 2)
    with pytest.raises(ValueError, match="theta must have shape"):
        M.edge_loss(theta[:-1], dc[:-1], (3, 3, 3), 2)
    with pytest.raises(ValueError, match="g must be in"):
        M.fit_masks(theta, dc, (3, 3, 3), 2, np.full(27, 5), 4)
    with pytest.raises(ValueError, match="K must be"):
        M.anneal(np.zeros((0, 2)), np.zeros(0), 4, 0)
