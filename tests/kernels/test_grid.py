"""The regular probe grid (workers/kernels/grid.py: grid_layout, grid_positions): by counts or spacing, over the
bounds or a box."""
from __future__ import annotations

import numpy as np
import pytest

from proto.models import PlaceSection
from workers.kernels.grid import base_positions, grid_layout, grid_positions

BOUNDS = np.array([[-1.0, 0.0, 2.0], [3.0, 2.0, 4.0]])


def test_counts_span_the_bounds():
    counts, origin, spacing = grid_layout(BOUNDS, PlaceSection(counts=(5, 3, 2)))
    assert counts.tolist() == [5, 3, 2]
    p = grid_positions(counts, origin, spacing)
    assert p.shape == (2, 3, 5, 3) and p.dtype == np.float32
    assert np.allclose(p[0, 0, 0], BOUNDS[0]) and np.allclose(p[-1, -1, -1], BOUNDS[1])
    assert np.allclose(p[0, 0, 1] - p[0, 0, 0], [1, 0, 0])  # x fastest
    assert np.allclose(p[0, 1, 0] - p[0, 0, 0], [0, 1, 0])
    assert np.allclose(p[1, 0, 0] - p[0, 0, 0], [0, 0, 2])


@pytest.mark.parametrize("s", [0.3, 0.5, 1.0, 7.0])
def test_spacing_covers_and_centres(s):
    counts, origin, spacing = grid_layout(BOUNDS, PlaceSection(spacing=s))
    ext = BOUNDS[1] - BOUNDS[0]
    assert np.all((counts - 1) * s >= ext - 1e-9)  # covers the box
    assert np.all((counts - 2) * s < ext)           # with no spare row
    centre = origin + spacing * (counts - 1) / 2
    assert np.allclose(centre, BOUNDS.mean(axis=0))


def test_box_padding_and_flat_axes():
    sec = PlaceSection(counts=(3, 3, 3), box={"min": (0, 0, 0), "max": (2, 2, 2)}, padding=0.5)
    counts, origin, spacing = grid_layout(BOUNDS, sec)
    assert np.allclose(origin, [-1, -1, -1]) and np.allclose(spacing, [2, 2, 2])
    flat = np.array([[0.0, 1.0, 0.0], [4.0, 1.0, 4.0]])
    counts, origin, spacing = grid_layout(flat, PlaceSection(spacing=1.0))
    assert counts.tolist() == [5, 1, 5] and origin[1] == 1.0
    counts, origin, spacing = grid_layout(flat, PlaceSection(counts=(2, 4, 2)))
    p = grid_positions(counts, origin, spacing)
    assert np.all(p[..., 1] == 1.0)


def test_grid_positions_are_base_positions_as_a_volume():
    counts, origin, spacing = np.array([4, 3, 2]), np.array([0.5, -1.0, 2.0]), np.array([0.25, 0.5, 1.0])
    p = grid_positions(counts, origin, spacing)
    np.testing.assert_array_equal(p.reshape(-1, 3), base_positions(counts, origin, spacing).astype(np.float32))
    assert p[1, 2, 3].tolist() == [0.5 + 3 * 0.25, -1.0 + 2 * 0.5, 2.0 + 1 * 1.0]   # texel (i, j, k) = (3, 2, 1)
