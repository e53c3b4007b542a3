"""The regular probe grid (workers/kernels/grid.py: grid_layout, grid_positions): by counts or spacing, over the
bounds or a box; dilation of OFF probes (dilate_off)."""
from __future__ import annotations

import numpy as np
import pytest

from proto.models import PlaceSection
from workers.kernels.grid import base_positions, dilate_off, grid_layout, grid_positions

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


def test_dilate_off_fills_layer_by_layer_from_live_neighbours():
    v = np.zeros((1, 1, 5, 2), np.float32)
    v[0, 0, 0] = [1.0, 10.0]
    v[0, 0, 4] = [3.0, 30.0]
    off = np.array([[[False, True, True, True, False]]])
    out, n = dilate_off(v, off)
    assert n == 3
    # layer 1: x = 1 from x = 0, x = 3 from x = 4; layer 2: x = 2 from both
    np.testing.assert_allclose(out[0, 0, :, 0], [1.0, 1.0, 2.0, 3.0, 3.0])
    np.testing.assert_allclose(out[0, 0, :, 1], [10.0, 10.0, 20.0, 30.0, 30.0])
    assert out.dtype == np.float32 and np.all(v[0, 0, 1:4] == 0)          # the input is not modified


def test_dilate_off_does_not_wrap_round_the_grid_and_leaves_all_off_alone():
    v = np.zeros((3, 1, 1), np.float64)
    v[0] = 5.0
    out, n = dilate_off(v, np.array([False, True, True]).reshape(3, 1, 1))
    np.testing.assert_allclose(out.ravel(), [5.0, 5.0, 5.0])             # from below only, never from the wrap
    assert n == 2
    same, n0 = dilate_off(v, np.ones((3, 1, 1), bool))
    assert n0 == 0 and np.array_equal(same, v)


def test_dilated_constant_field_reads_constant_where_the_volume_had_zeros():
    """Leaking SH interpolation next to a buried (OFF, 0) probe reads the field again after dilation."""
    from workers.kernels import samplers as SM

    g = SM.Grid((3, 3, 3), (0, 0, 0), (1, 1, 1))
    sh = np.zeros((3, 3, 3, 4), np.float32)
    sh[..., 0] = 1.0
    off = np.zeros((3, 3, 3), bool)
    off[0, :, :] = True                                     # the z = 0 layer buried in a solid
    sh[off] = 0.0
    p, n = np.array([[1.0, 1.0, 0.25]]), np.array([[0.0, 0.0, 1.0]])
    dark = SM.leaking(p, n, sh, sh, sh, g, linear=True)
    filled, _ = dilate_off(sh, off)
    e = SM.leaking(p, n, filled, filled, filled, g, linear=True)
    const = np.zeros_like(sh)
    const[..., 0] = 1.0
    full = SM.leaking(p, n, const, const, const, g, linear=True)
    assert dark[0, 0] < 0.8 * e[0, 0]
    np.testing.assert_allclose(e, full, rtol=1e-6)
