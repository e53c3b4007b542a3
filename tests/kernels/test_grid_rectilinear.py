"""A rectilinear probe grid (workers/kernels/grid.py module doc): per-axis layer coordinates, read by every sampler
through the continuous grid index alone. Trilinear interpolation at that index is the rectilinear grid's trilinear
interpolation: a field linear in each coordinate is reproduced exactly, whatever the gaps."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import samplers as SM
from workers.kernels.autogrid import fill_layers, thin_wall_layers
from workers.kernels.compress import mask_lookups
from workers.kernels.ddgi import cage_probes
from workers.kernels.grid import (axis_coord, axis_position, base_positions, cell_coords, check_layers, grid_coord,
                                  grid_point, layers_table)

LAYERS = [np.array([0.0, 0.1, 1.0, 2.0]), np.array([0.0, 0.5, 0.6, 1.5, 3.0]), np.array([-1.0, 2.0, 2.05])]
COUNTS = np.array([4, 5, 3])
ORIGIN = np.array([L[0] for L in LAYERS])
SPACING = np.array([(L[-1] - L[0]) / (len(L) - 1) for L in LAYERS])


def test_layer_coordinate_between_and_beyond_the_layers():
    L = LAYERS[0]
    x = np.array([0.0, 0.05, 0.1, 0.55, 1.5, 2.0, -0.1, 2.5])
    assert np.allclose(axis_coord(x, L), [0.0, 0.5, 1.0, 1.5, 2.5, 3.0, -1.0, 3.5])   # ends extrapolate linearly
    assert np.allclose(axis_position(axis_coord(x, L), L), x)
    assert np.allclose(axis_coord([5.0], [2.0]), [0.0])                                # one layer: index 0


def test_uniform_layers_read_as_the_uniform_grid():
    counts, origin, spacing = np.array([5, 3, 4]), np.array([0.5, -1.0, 2.0]), np.array([0.3, 0.7, 0.45])
    layers = [origin[a] + spacing[a] * np.arange(counts[a]) for a in range(3)]
    p = np.random.default_rng(1).uniform(-2, 4, (500, 3))
    assert np.allclose(grid_coord(p, counts, origin, spacing, layers), grid_coord(p, counts, origin, spacing))
    b0, a0 = cell_coords(p, counts, origin, spacing)
    b1, a1 = cell_coords(p, counts, origin, spacing, layers)
    assert np.array_equal(b0, b1) and np.allclose(a0, a1)
    assert np.allclose(base_positions(counts, origin, spacing, layers), base_positions(counts, origin, spacing))


def test_rectilinear_trilinear_reproduces_a_multilinear_field_exactly():
    """f = (1 + x)(2 + y)(3 + z) at the probes, read by the leaking sampler (L0 only, constant radiance L gives π·L) at
    points inside the grid box: exactly f there — with the uniform index at the same counts it is far off."""
    pos = base_positions(COUNTS, ORIGIN, SPACING, LAYERS)
    f = (1 + pos[:, 0]) * (2 + pos[:, 1]) * (3 + pos[:, 2])
    vol = np.zeros((COUNTS[2], COUNTS[1], COUNTS[0], 4))
    vol[..., 0] = f.reshape(COUNTS[2], COUNTS[1], COUNTS[0])
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    p = np.random.default_rng(2).uniform(lo, hi, (400, 3))
    n = np.tile([0.0, 1.0, 0.0], (400, 1))
    grid = {"counts": COUNTS, "origin": ORIGIN, "spacing": SPACING, "layers": LAYERS}
    e = SM.leaking(p, n, vol, vol, vol, grid, linear=True)[:, 0] / (np.pi * 0.282095)
    want = (1 + p[:, 0]) * (2 + p[:, 1]) * (3 + p[:, 2])
    assert np.allclose(e, want, rtol=1e-5)                       # the SH constants hold 6 digits
    e_uniform = SM.leaking(p, n, vol, vol, vol, {**grid, "layers": None}, linear=True)[:, 0] / (np.pi * 0.282095)
    assert np.abs(e_uniform / want - 1).max() > 0.2


def test_the_samplers_agree_on_the_cell_of_a_point():
    """ddgi's cage (numba), the mask lookup's cell and cell_coords pick the same cell of a rectilinear grid."""
    rng = np.random.default_rng(3)
    pos = base_positions(COUNTS, ORIGIN, SPACING, LAYERS)
    p = rng.uniform(pos.min(axis=0), pos.max(axis=0), (300, 3))
    n = np.tile([0.0, 0.0, 1.0], (300, 1))
    base, _ = cell_coords(p, COUNTS, ORIGIN, SPACING, LAYERS)
    _, cage = cage_probes(p, n, n, COUNTS, ORIGIN, SPACING, 0.0, layers=LAYERS)
    flat = base[:, 0] + COUNTS[0] * (base[:, 1] + COUNTS[1] * base[:, 2])
    assert np.array_equal(cage[:, 0], flat)
    _, cell = mask_lookups(p, COUNTS, ORIGIN, SPACING, 4, dtype=np.float64, layers=LAYERS)
    assert np.array_equal(cell.astype(np.int64), base)
    assert np.allclose(grid_point(grid_coord(p, COUNTS, ORIGIN, SPACING, LAYERS), COUNTS, ORIGIN, SPACING, LAYERS), p)


def test_layers_are_checked_and_tabled():
    with pytest.raises(ValueError, match="increasing"):
        check_layers([[0, 1, 1, 2], [0, 1, 2, 3, 4], [0, 1, 2]], COUNTS)
    with pytest.raises(ValueError, match="values for"):
        check_layers([[0, 1], [0, 1, 2, 3, 4], [0, 1, 2]], COUNTS)
    t = layers_table(COUNTS, ORIGIN, SPACING, LAYERS)
    assert t.shape == (3, 5) and t[0, 4] == 2.0 and t[2, 3:].tolist() == [2.05, 2.05]


def test_a_thin_wall_gets_a_layer_in_front_of_each_face():
    """A 10 cm wall at x = 2 (faces: looking -x at 1.95, +x at 2.05) in a box [0, 4], fill 0.5 m: a layer
    0.2 x 0.5 = 10 cm in front of each face, the rest at most 0.5 m apart. A lone face (a thick wall's, at x = 3.3)
    gets none, and no layer nearer than s/4 to it; a small face (a shelf) does not count."""
    pos = np.array([1.95, 2.05, 3.3, 1.0, 1.02])
    area, sign = np.array([9.0, 9.0, 9.0, 0.1, 0.1]), np.array([-1.0, 1.0, 1.0, -1.0, 1.0])
    anchors, lone = thin_wall_layers(pos, area, sign, 0.0, 4.0, 0.5, cross=9.0)
    assert np.allclose(anchors, [1.85, 2.15]) and np.allclose(lone, [3.3])
    L = fill_layers(anchors, lone, 0.0, 4.0, 0.5)
    assert np.any(np.isclose(L, 1.85)) and np.any(np.isclose(L, 2.15))
    assert L[0] == 0.0 and L[-1] == 4.0 and (np.diff(L) > 0).all() and np.diff(L).max() <= 0.5 + 0.125 + 1e-12
    assert np.abs(L - 3.3).min() >= 0.125 - 1e-12
    # the wall's cell: the two layers either side of it, 30 cm apart (the visibility field's S samples span it)
    i = np.searchsorted(L, 2.0)
    assert np.isclose(L[i] - L[i - 1], 0.3)
