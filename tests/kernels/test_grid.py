"""workers.kernels.grid: dilation of OFF probes."""
from __future__ import annotations

import numpy as np

from workers.kernels.grid import dilate_off


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
