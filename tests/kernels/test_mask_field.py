"""The refined sample grid shared by the Mask Decomposition kernels (workers/kernels/mask_field.py)."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from workers.kernels import mask_field as MF
from workers.kernels.grid import ACTIVE, OFF

from tests.kernels.mask_fields import random_field


def test_check_counts():
    assert MF.check_counts([4, 1, 2]).tolist() == [4, 1, 2]
    with pytest.raises(ValueError, match="counts must be >= 1"):
        MF.check_counts((3, 0, 2))


def test_check_field_shapes_and_messages():
    theta, dc = random_field((3, 2, 4), 2)
    th, d, counts, S, cells = MF.check_field(theta, dc[..., None].astype(np.uint8), (3, 2, 4), 2)
    assert th.dtype == np.uint8 and d.dtype == bool and d.shape == dc.shape and np.array_equal(d, dc)
    assert counts.tolist() == [3, 2, 4] and S == 2 and cells.tolist() == [2, 1, 3]
    with pytest.raises(ValueError, match="theta must have shape"):
        MF.check_field(theta[:-1], dc[:-1], (3, 2, 4), 2)
    with pytest.raises(ValueError, match="dont_care must have shape"):
        MF.check_field(theta, dc[:-1], (3, 2, 4), 2)
    with pytest.raises(ValueError, match="S must be"):
        MF.check_field(theta, dc, (3, 2, 4), 0)


def test_off_flags_and_labels():
    states = np.array([ACTIVE, OFF, ACTIVE])
    assert MF.off_flags(states, 3).tolist() == [False, True, False]
    assert MF.off_flags(None, 2).tolist() == [False, False]
    with pytest.raises(ValueError, match="states must hold 4"):
        MF.off_flags(states, 4)
    assert MF.check_labels([0, 2, 1], 3, 3).dtype == np.int64
    with pytest.raises(ValueError, match="g must be in"):
        MF.check_labels([0, 3, 1], 3, 3)
    with pytest.raises(ValueError, match="g must hold 3"):
        MF.check_labels([0, 1], 3, 3)


def test_join_theta():
    rng = np.random.default_rng(0)
    a, b = (rng.integers(0, 256, (2, 3, 4, 4)).astype(np.uint8) for _ in range(2))
    t = MF.join_theta(a, b)
    assert t.shape == (2, 3, 4, 8) and np.array_equal(t[..., :4], a) and np.array_equal(t[..., 4:], b)
    with pytest.raises(ValueError, match="theta volumes"):
        MF.join_theta(a, b[:1])


def test_field_fractions():
    cx, cy, cz, tx, ty, tz = MF.field_fractions((3, 1, 2), 2)
    assert cx.tolist() == [0, 0, 1, 1] and cy.tolist() == [0, 0] and cz.tolist() == [0, 0]
    assert tx.tolist() == [0.25, 0.75, 0.25, 0.75] and ty.tolist() == [0.0, 0.0]   # one-probe axis: t = 0
    assert tz.tolist() == [0.25, 0.75]


def test_corner_weights_are_trilinear():
    rng = np.random.default_rng(1)
    for f in rng.random((20, 3)):
        w = [MF.corner_weight(c, *f) for c in range(8)]
        assert sum(w) == pytest.approx(1.0)                       # a partition of unity
        # the weights reproduce a linear function of the corner offsets (trilinear interpolation)
        pos = sum(wc * np.array([c & 1, c >> 1 & 1, c >> 2 & 1]) for c, wc in enumerate(w))
        assert np.allclose(pos, f)
    assert MF.corner_weight(0, 0.0, 0.0, 0.0) == 1.0 and MF.corner_weight(7, 0.0, 0.0, 0.0) == 0.0


def test_corner_probe_clamps_one_probe_axes():
    nx, ny, nz = 3, 1, 2
    for c in range(8):
        i, j, k = 1 + (c & 1), 0, c >> 2 & 1
        assert MF.corner_probe(1, 0, 0, c, nx, ny, nz) == i + nx * (j + ny * k)
    corners = {MF.corner_probe(0, 0, 0, c, nx, ny, nz) for c in range(8)}
    assert corners == {p for p in itertools.chain((0, 1), (3, 4))}   # y has one probe: 4 distinct corners
