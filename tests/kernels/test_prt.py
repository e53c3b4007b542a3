"""PRT kernels (workers/kernels/prt.py): sample elimination, the fit (PRT eq 7-10, 14), packing, lightmap layout."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels import prt as k

UNIT_SQUARE = np.array([[[0, 0, 0], [1, 0, 0], [1, 0, 1]], [[0, 0, 0], [1, 0, 1], [0, 0, 1]]], np.float64)


# ------------------------------------------------------------------------------------- sampling
def test_area_samples_are_uniform_by_area():
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [3, 0, 0], [0, 2, 0]]], np.float64)
    rng = np.random.default_rng(0)
    tri, u, v = k.area_samples(tris, 40000, rng)
    assert np.all((u >= 0) & (v >= 0) & (u + v <= 1))
    frac = np.mean(tri == 1)
    assert abs(frac - 6 / 7) < 0.01                       # areas 0.5 and 3
    b = np.stack([1 - u - v, u, v], 1)[tri == 0]
    assert np.allclose(b.mean(axis=0), 1 / 3, atol=0.01)  # uniform on the triangle: mean barycentrics 1/3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sample_elimination_spreads_points_more_than_a_random_pick(seed):
    rng = np.random.default_rng(seed)
    tri, u, v = k.area_samples(UNIT_SQUARE, 5 * 256, rng)
    t = UNIT_SQUARE[tri]
    pts = (1 - u - v)[:, None] * t[:, 0] + u[:, None] * t[:, 1] + v[:, None] * t[:, 2]
    keep = k.sample_elimination(pts, 256, area=1.0)
    assert keep.shape == (256,) and np.unique(keep).size == 256 and np.all(np.diff(keep) > 0)
    random_pick = rng.choice(len(pts), 256, replace=False)
    d_elim, d_rand = k.min_spacing(pts[keep]), k.min_spacing(pts[random_pick])
    assert d_elim > 2 * d_rand
    # Yuksel reports ~0.75 x the maximal Poisson-disk radius; allow some slack for 5x candidates
    r_max = math.sqrt(1.0 / (2 * math.sqrt(3) * 256))
    assert d_elim > 0.5 * r_max


def test_sample_elimination_is_deterministic_and_keeps_all_when_asked():
    pts = np.random.default_rng(3).random((500, 3))
    assert np.array_equal(k.sample_elimination(pts, 100, 3.0), k.sample_elimination(pts, 100, 3.0))
    assert np.array_equal(k.sample_elimination(pts, 500, 3.0), np.arange(500))
    with pytest.raises(ValueError):
        k.sample_elimination(pts, 501, 3.0)


def test_group_mean():
    v = np.arange(12, dtype=float).reshape(6, 2)
    out = k.group_mean(v, np.array([0, 1, 4, 6]))
    assert np.allclose(out, [[0, 1], [4, 5], [9, 10]])


def test_random_light_configurations_follow_the_scenario():
    sc = {"types": ["point", "spot", "directional"], "count": 3, "color_min": (0.2, 0.5, 0.0),
          "color_max": (0.4, 0.5, 1.0), "intensity_min": 2.0, "intensity_max": 4.0}
    cfgs = k.random_light_configurations(np.random.default_rng(5), sc, 50, (0, 0, 0), (1, 2, 3))
    again = k.random_light_configurations(np.random.default_rng(5), sc, 50, (0, 0, 0), (1, 2, 3))
    assert cfgs == again and len(cfgs) == 50 and all(len(c) == 3 for c in cfgs)
    lights = [light for c in cfgs for light in c]
    assert {light["type"] for light in lights} == {"point", "spot", "directional"}
    for light in lights:
        assert 2 <= light["intensity"] <= 4
        c = np.array(light["color"])
        assert np.all(c >= [0.2, 0.5, 0.0]) and np.all(c <= [0.4, 0.5, 1.0])
        if light["type"] in ("point", "spot"):
            assert np.all(np.array(light["position"]) >= 0) and np.all(np.array(light["position"]) <= [1, 2, 3])
        if light["type"] in ("spot", "directional"):
            assert abs(np.linalg.norm(light["direction"]) - 1) < 1e-9
        if light["type"] == "spot":
            assert light["inner_cone_angle"] < light["outer_cone_angle"]


def test_random_lights_are_redrawn_inside_geometry():
    sc = {"types": ["point"], "count": 1, "color_min": (1, 1, 1), "color_max": (1, 1, 1),
          "intensity_min": 1.0, "intensity_max": 1.0}

    def inside(p):  # a solid filling x < 0.5
        return p[:, 0] < 0.5

    cfgs = k.random_light_configurations(np.random.default_rng(1), sc, 40, (0, 0, 0), (1, 1, 1), inside=inside)
    assert all(c[0]["position"][0] >= 0.5 for c in cfgs)


# ------------------------------------------------------------------------------------------ fit
def _linear_dataset(N=60, M=24, L=150, seed=0):
    """Exactly linear transport per channel (different per channel, as albedo makes it)."""
    rng = np.random.default_rng(seed)
    A = rng.random((3, L, M))
    x = rng.random((N, M, 3)) * rng.uniform(0.1, 10, (N, 1, 1))    # intensities over two decades
    y = np.einsum("clm,nmc->nlc", A, x)
    return x, y, A


@pytest.mark.parametrize("ridge", [0.0, 1e-8])
def test_mono_fit_reproduces_linear_transport_with_enough_basis(ridge):
    x, y, A = _linear_dataset()
    f = k.fit(x, y, 80, ridge=ridge)          # one basis for 3 channels: the data spans 3·24 (+ mean) dimensions
    assert f.slots.shape == (80, 150) and f.transfer.shape == (3, 80, 25)
    assert np.allclose(f.transfer[:, 0], np.r_[np.zeros(24), 1.0])   # u_0 = ‖x‖
    rng = np.random.default_rng(9)
    for _ in range(3):                        # held-out direct vectors
        xn = rng.random((24, 3)) * 5
        yn = np.einsum("clm,mc->lc", A, xn)
        assert np.allclose(k.reconstruct(f, xn), yn, rtol=1e-4, atol=1e-4 * np.abs(yn).max())
    U = f.slots[1:73].astype(np.float64)
    assert np.allclose(U @ U.T, np.eye(72), atol=1e-5)   # orthonormal basis vectors


def test_multi_channel_fit_and_projection():
    x, y, A = _linear_dataset(N=90, M=8, L=40)
    f = k.fit(x, y, 30, ridge=0.0, channels="multi")   # interleaved rgb: rank 3·8 = 24
    assert f.slots.shape == (30, 40, 3) and f.transfer.shape == (1, 30, 25)
    for i in range(3):
        assert np.allclose(k.reconstruct(f, x[i]), y[i], rtol=1e-4, atol=1e-5 * np.abs(y[i]).max())
        assert np.allclose(k.project(f, x[i], y[i]), y[i], atol=1e-5 * np.abs(y[i]).max())


def test_truncation_is_nested_and_projection_bounds_reconstruction():
    x, y, _ = _linear_dataset()
    f = k.fit(x, y, 16, ridge=1e-3)
    g = k.fit(x, y, 8, ridge=1e-3)
    assert np.allclose(f.truncated(8).slots, g.slots, atol=1e-6)
    assert np.allclose(f.truncated(8).transfer, g.transfer, atol=1e-4 * np.abs(g.transfer).max())
    errs = [np.sqrt(np.mean((k.project(f.truncated(n), x[0], y[0]) - y[0]) ** 2)) for n in (2, 4, 8, 16)]
    assert errs == sorted(errs, reverse=True)


@pytest.mark.parametrize("gamma", [None, 2.2])
@pytest.mark.parametrize("channels", ["mono", "multi"])
def test_relighting_is_homogeneous(gamma, channels):
    x, y, _ = _linear_dataset()
    f = k.fit(x, y, 8, ridge=1e-3, gamma=gamma, channels=channels)
    xn = np.random.default_rng(4).random((24, 3))
    assert np.allclose(k.reconstruct(f, 2 * xn), 2 * k.reconstruct(f, xn), rtol=1e-9, atol=1e-12)
    assert np.allclose(k.reconstruct(f, np.zeros((24, 3))), 0)


def test_gamma_round_trip_signed():
    v = np.array([-4.0, -0.25, 0.0, 0.5, 9.0])
    assert np.allclose(k.gamma_decode(k.gamma_encode(v, 2.2), 2.2), v)
    assert np.allclose(k.gamma_encode(v, 2.0), [-2, -0.5, 0, math.sqrt(0.5), 3])
    assert k.gamma_encode(v, None) is not None and np.array_equal(k.gamma_encode(v, None), v)


def test_outlier_columns_are_left_out():
    x, y, _ = _linear_dataset(N=40)
    x2, y2 = x.copy(), y.copy()
    x2[0] *= 1e-4   # a configuration the measurement points barely see: y/‖x‖ explodes
    f = k.fit(x2, y2, 8)
    assert f.dropped >= 1 and f.columns == 3 * 40 - f.dropped
    clean = k.fit(x[1:], y[1:], 8)
    assert np.allclose(np.abs(f.slots[0]), np.abs(clean.slots[0]), rtol=0.2)


def test_zero_direct_columns_are_ignored():
    x, y, _ = _linear_dataset(N=20)
    x[:, :, 2] = 0
    y[:, :, 2] = 0    # a blue-free scenario
    f = k.fit(x, y, 6)
    assert f.columns == 40
    assert np.allclose(k.reconstruct(f, x[0])[:, 2], 0)


# ---------------------------------------------------------------------------------------- packing
@pytest.mark.parametrize("n", [1, 4, 6, 16])
def test_pack_unpack_rgba(n):
    s = np.random.default_rng(n).random((n, 3, 5, 7)).astype(np.float32)
    p = k.pack_rgba(s)
    assert p.shape == (-(-n // 4), 3, 5, 7, 4)
    assert np.array_equal(p[0, ..., 0], s[0])
    if n > 1:
        assert np.array_equal(p[0, ..., 1], s[1])
    assert np.array_equal(k.unpack_rgba(p, n), s)


# --------------------------------------------------------------------------------------- lightmap
def test_chart_layout_uniform_density_and_no_overlap():
    # two charts with the same UV square but different world sizes, and a triangle without a chart
    big = UNIT_SQUARE * 2.0
    small = UNIT_SQUARE * 0.5 + [3, 0, 0]
    tris = np.concatenate([big, small, UNIT_SQUARE[:1] + [9, 0, 0]])
    uv = np.tile(np.array([[0, 0], [1, 0], [1, 1]], np.float64), (5, 1, 1))
    uv[1] = uv[3] = [[0, 0], [1, 1], [0, 1]]
    chart = np.array([0, 0, 5, 5, -1])
    atlas, rho = k.chart_layout(tris, uv, chart, 64, padding=2)
    assert rho > 0 and np.all(atlas[4] == 0)
    assert np.all(atlas[:4] >= 0) and np.all(atlas[:4] <= 1)
    box = lambda s: (atlas[s].reshape(-1, 2).min(0), atlas[s].reshape(-1, 2).max(0))  # noqa: E731
    (a0, a1), (b0, b1) = box(slice(0, 2)), box(slice(2, 4))
    assert np.any(a1 < b0) or np.any(b1 < a0)          # disjoint boxes
    assert np.allclose((a1 - a0) / (b1 - b0), 4.0, rtol=0.05)   # same texels per metre: 2 m vs 0.5 m
    tri_map, bary = k.rasterize(atlas, 64)
    covered = tri_map >= 0
    assert set(np.unique(tri_map[covered])) == {0, 1, 2, 3}
    # texel centres map back into their triangle: barycentric reconstruction of the atlas uv
    r, c = np.nonzero(covered)
    t = tri_map[r, c]
    b = np.stack([1 - bary[r, c, 0] - bary[r, c, 1], bary[r, c, 0], bary[r, c, 1]], 1)
    uvc = np.einsum("nk,nkd->nd", b, atlas[t].astype(np.float64)) * 64
    assert np.allclose(uvc, np.stack([c + 0.5, r + 0.5], 1), atol=1e-3)


def test_dilate_is_linear_and_fills_neighbours():
    mask = np.zeros((8, 8), bool)
    mask[3:5, 3:5] = True
    rng = np.random.default_rng(0)
    a, b = rng.random((8, 8)), rng.random((8, 8))
    da, m = k.dilate(a * mask, mask, 2)
    db, _ = k.dilate(b * mask, mask, 2)
    dab, _ = k.dilate((2 * a + 3 * b) * mask, mask, 2)
    assert np.allclose(dab, 2 * da + 3 * db, atol=1e-6)
    assert m[1:7, 1:7].all() and not m[0].any()
    assert np.allclose(da[mask], a[mask])
    assert np.isclose(da[2, 2], a[3, 3])                 # a corner neighbour sees one filled texel
