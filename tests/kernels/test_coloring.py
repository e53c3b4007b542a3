"""Mask Decomposition colouring (workers/kernels/coloring.py): eq 4, 6-8 on synthetic θ fields."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from workers.kernels import coloring as C
from workers.kernels.grid import ACTIVE, OFF
from workers.kernels.mask_field import field_fractions

from tests.kernels.mask_fields import random_field


def _brute_edges(theta, dc, counts, S, off=None):
    """E(i, j) of eq 6 by direct summation over samples (dict {(i, j): E})."""
    nx, ny, nz = counts
    cx, cy, cz, tx, ty, tz = field_fractions(counts, S)
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
    theta, dc = random_field(counts, S, seed=S)
    pairs, w = C.edge_loss(theta, dc, counts, S)
    brute = _brute_edges(theta, dc, counts, S)
    got = {(int(a), int(b)): float(v) for (a, b), v in zip(pairs, w)}
    assert np.all(pairs[:, 0] < pairs[:, 1])
    assert set(got) == set(brute)            # exactly the pairs sharing a cell, E = 0 ones included
    for k in brute:
        assert got[k] == pytest.approx(brute[k], rel=1e-12, abs=1e-15)


def test_edge_count_is_pairs_sharing_a_cell():
    counts = (4, 3, 5)
    S = 1
    theta, dc = random_field(counts, S)
    pairs, _ = C.edge_loss(theta, dc, counts, S)
    n = np.asarray(counts)
    expect = sum(int(np.prod(n - np.abs(d))) for d in C.HALF_DIRECTIONS)
    assert len(C.HALF_DIRECTIONS) == 13
    assert pairs.shape == (expect, 2) == (len({tuple(p) for p in pairs.tolist()}), 2)


def test_edge_loss_dont_care_and_off():
    counts, S = (3, 3, 2), 2
    theta, dc = random_field(counts, S, p_dc=0.0)
    _, w = C.edge_loss(theta, np.ones_like(dc), counts, S)
    assert np.all(w == 0)                                           # don't-care samples weigh 0
    states = np.full(18, ACTIVE)
    states[4] = OFF
    pairs, w_off = C.edge_loss(theta, dc, counts, S, states)
    pairs_all, w_all = C.edge_loss(theta, dc, counts, S)
    assert not np.any(pairs == 4)
    keep = ~np.any(pairs_all == 4, axis=1)
    assert np.array_equal(pairs, pairs_all[keep]) and np.array_equal(w_off, w_all[keep])


def test_edge_loss_one_corner_visible_known_answer():
    # one cell, S = 2: θ = 1 for corner 0 only. E(0, j) = Σ_x min(φ0, φj), E = 0 between the others.
    counts, S = (2, 2, 2), 2
    theta = np.zeros((2, 2, 2, 8), np.uint8)
    theta[..., 0] = 255
    pairs, w = C.edge_loss(theta, np.zeros((2, 2, 2), bool), counts, S)
    E = dict(zip(map(tuple, pairs.tolist()), w))
    t = np.array([0.25, 0.75])
    # along x: min over samples of (1-tx)(…)(…) vs tx(…)(…), summed: Σ_y,z (1-ty)(1-tz) · Σ_x min(1-tx, tx)
    axis_edge = np.sum(np.minimum(1 - t, t)) * np.sum(1 - t) ** 2
    assert E[(0, 1)] == pytest.approx(axis_edge) and E[(0, 2)] == pytest.approx(axis_edge)
    assert E[(0, 4)] == pytest.approx(axis_edge)
    assert E[(1, 2)] == 0 and E[(3, 5)] == 0 and E[(6, 7)] == 0


def test_parity_coloring_separates_every_cell():
    counts = (5, 4, 3)
    g = C.parity_coloring(counts).reshape(3, 4, 5)
    for k, j, i in itertools.product(range(2), range(3), range(4)):
        cell = {int(g[k + (c >> 2 & 1), j + (c >> 1 & 1), i + (c & 1)]) for c in range(8)}
        assert cell == set(range(8))
    assert g[0, 0, 0] == 0 and g[1, 0, 1] == 5 and g[1, 1, 1] == 7       # eq 4: bit d = parity of index d


@pytest.mark.parametrize("K", [1, 2, 3, 4, 5, 8])
def test_convex_division_boxes(K):
    counts = (9, 4, 5)
    g = C.convex_division(counts, K, spacing=[0.95, 0.87, 0.9]).reshape(5, 4, 9)
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
    g, loss, info = C.anneal(pairs, w, 300, 3, sweeps=sweeps, regularization=0.01, seed=seed, init=init)
    e7, e8 = C.coloring_loss(pairs, w, g, 0.01)
    assert loss.shape == (sweeps + 1,)
    assert loss[0] == pytest.approx(w.sum())
    assert info["final_loss"] == pytest.approx(e7 + e8) == pytest.approx(loss.min())
    assert info["final_loss"] <= info["initial_loss"]
    if sweeps >= 50:
        assert e7 + e8 < 0.2 * loss[0]


def test_anneal_seeded_and_reproducible():
    pairs, w = _random_graph(7)
    a = C.anneal(pairs, w, 300, 4, sweeps=40, seed=3)
    b = C.anneal(pairs, w, 300, 4, sweeps=40, seed=3)
    c = C.anneal(pairs, w, 300, 4, sweeps=40, seed=4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[1], c[1])                  # another seed takes another path


def test_anneal_off_probes_never_move():
    pairs, w = _random_graph(1)
    states = np.full(300, ACTIVE)
    states[:50] = OFF
    init = C.convex_division((300, 1, 1), 4)
    g, _, info = C.anneal(pairs, w, 300, 4, sweeps=20, init=init, states=states)
    assert np.array_equal(g[:50], init[:50])
    assert info["movable"] <= 250


def test_anneal_degenerate_cases():
    pairs, w = _random_graph(2)
    g, loss, info = C.anneal(pairs, w, 300, 1, sweeps=5)              # one colour: nothing to do
    assert np.all(g == 0) and np.allclose(loss, w.sum()) and info["accepted"] == 0
    g, loss, _ = C.anneal(np.zeros((0, 2)), np.zeros(0), 10, 4, sweeps=3)    # no edges
    assert loss.shape == (4,) and np.all(loss == 0)


def test_temperature_schedule_geometric():
    T = C.temperature_schedule([0.0, 0.2, 0.4], 5, regularization=0.001)
    assert T[0] == pytest.approx(0.9) and T[-1] == pytest.approx(1e-4)
    assert np.allclose(T[1:] / T[:-1], T[1] / T[0])



def test_coloring_loss_eq7_and_eq8():
    pairs = np.array([[0, 1], [1, 2], [2, 3]])
    w = np.array([0.5, 2.0, 4.0])
    g = np.array([0, 0, 1, 1])                      # edges 0-1 and 2-3 same-coloured, 1-2 not
    assert C.coloring_loss(pairs, w, g, 0.1) == pytest.approx((4.5, 0.1))     # eq 7, eq 8: λ per cut edge
    assert C.coloring_loss(pairs, w, np.arange(4)) == (0.0, 0.0)


def test_random_loss_is_seeded_mean_of_random_colourings():
    pairs, w = _random_graph(3)
    a = C.random_loss(pairs, w, 300, 4, seed=1)
    assert a == C.random_loss(pairs, w, 300, 4, seed=1)
    assert a == pytest.approx(w.sum() / 4, rel=0.15)          # a random pair shares a colour 1 time in K


def test_validation_messages():
    theta, dc = random_field((3, 3, 3), 2)
    with pytest.raises(ValueError, match="theta must have shape"):
        C.edge_loss(theta[:-1], dc[:-1], (3, 3, 3), 2)
    with pytest.raises(ValueError, match="K must be"):
        C.anneal(np.zeros((0, 2)), np.zeros(0), 4, 0)
