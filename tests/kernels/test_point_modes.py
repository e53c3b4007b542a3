"""Which modes a bake has and their GI fetches per pixel (workers/kernels/point_modes.py)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from workers.kernels.point_modes import available_modes, gi_fetches

FULL = {"sh_l1_r", "sh_l1_g", "sh_l1_b", "irradiance", "depth_moments", "probe_positions_relocated", "probe_states",
        "mask_indirection", "mask_atlas", "cluster_sh_0_r", "cluster_weights_0123", "prt"}


def test_available_modes():
    assert available_modes(set()) == ["direct"]
    assert available_modes(FULL) == ["direct", "leaking", "ddgi", "mask", "mask_normalized", "prt"]
    assert available_modes(FULL - {"cluster_weights_0123"})[3:] == ["mask", "prt"]   # no weights: no normalized
    assert "mask" not in available_modes(FULL - {"mask_indirection"})
    assert available_modes(FULL - {"sh_l1_g"})[:2] == ["direct", "ddgi"]


def test_fetch_formulas():
    pts = np.zeros((3, 3))
    res = SimpleNamespace(info={"sh_order": 2, "coefficients": 9, "groups": 2}, uniforms={})
    np.testing.assert_array_equal(gi_fetches("direct", res, {}, {}, pts, pts, pts), 0.0)
    np.testing.assert_array_equal(gi_fetches("leaking", res, {}, {}, pts, pts, pts), 7.0)    # sh_l2: 7 sub-volumes
    res1 = SimpleNamespace(info={"sh_order": 1}, uniforms={})
    np.testing.assert_array_equal(gi_fetches("leaking", res1, {}, {}, pts, pts, pts), 3.0)   # sh_l1_{r,g,b}
    np.testing.assert_array_equal(gi_fetches("prt", res, {}, {}, pts, pts, pts), 18.0)       # 9 coefficients x 2
    assert gi_fetches("ddgi", res, {}, {}, np.zeros((0, 3)), pts[:0], pts[:0]).shape == (0,)
    with pytest.raises(ValueError):
        gi_fetches("nope", res, {}, {}, pts, pts, pts)


def test_ddgi_fetches_count_live_corners():
    """8 state/position fetches plus 2 (irradiance, depth) per corner probe that is not OFF."""
    grid = {"counts": [2, 2, 2], "origin": [0, 0, 0], "spacing": [1, 1, 1]}
    pts = np.array([[0.5, 0.5, 0.5]])
    n = np.array([[0, 1.0, 0]])
    res = SimpleNamespace(info={}, uniforms={})
    on = {"probe_states": np.ones((2, 2, 2, 1), np.uint8)}
    off = {"probe_states": np.zeros((2, 2, 2, 1), np.uint8)}
    assert gi_fetches("ddgi", res, on, grid, pts, n, n)[0] == 24.0
    assert gi_fetches("ddgi", res, off, grid, pts, n, n)[0] == 8.0


def test_mask_fetches_count_stored_channels_and_clusters():
    """2·G indirection fetches, 2 atlas reads per channel the cell stores in the atlas (code >= 2: not all 0 or all
    255), 7 (L2) per cluster with m_k > 0, plus A weight fetches in normalized mask GI (gi_mask.glsl)."""
    from workers.kernels.mask_atlas import compress_channels

    grid = {"counts": [2, 2, 2], "origin": [0, 0, 0], "spacing": [1, 1, 1]}
    S = 2
    v = np.zeros((S, S, S, 4), np.uint8)
    v[..., 0] = 255                                        # code 1: m = 1, no atlas fetch
    v[..., 1] = np.array([0, 200], np.uint8)[None, None, :]  # a ramp along x: stored, read twice
    ca = compress_channels(v, grid["counts"], S, 4)
    arrays = {"masks_0123": v, "mask_indirection": ca.indirection}
    pts, n = np.array([[0.5, 0.5, 0.5]]), np.array([[0, 1.0, 0]])
    res = SimpleNamespace(info={"sh_order": 2, "clusters": 4}, uniforms={"uMaskS": S, "uMaskOffset": 0.0})
    assert gi_fetches("mask", res, arrays, grid, pts, n, n)[0] == 2 + 2 * 1 + 7 * 2
    assert gi_fetches("mask_normalized", res, arrays, grid, pts, n, n)[0] == 2 + 2 * 1 + 7 * 2 + 1
