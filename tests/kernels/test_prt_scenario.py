"""PRT's scenario and measurement points (workers/kernels/prt_scenario.py): sampling, sample elimination, lights."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels import prt_scenario as k

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


def test_a_share_of_the_lights_stands_near_a_surface():
    """near_surface s: about s of the point/spot lights are near_distance off the floor (along its normal), the
    rest uniform in the box; near points outside the box are drawn again; s = 0 draws as before."""
    sc = {"types": ["point", "spot"], "count": 1, "color_min": (1, 1, 1), "color_max": (1, 1, 1),
          "intensity_min": 1.0, "intensity_max": 1.0}
    near = k.near_surface_sampler(_floor(), np.random.default_rng(2), (0.02, 0.1))
    box = ((0, 0, 0), (2, 2, 2))                                             # the floor's 2 m², not the black patch
    plain = k.random_light_configurations(np.random.default_rng(3), sc, 400, *box)
    assert k.random_light_configurations(np.random.default_rng(3), {**sc, "near_surface": 0.0}, 400, *box,
                                         near=near) == plain
    cfgs = k.random_light_configurations(np.random.default_rng(3), {**sc, "near_surface": 0.5}, 400, *box, near=near)
    p = np.array([c[0]["position"] for c in cfgs])
    assert np.all(p >= 0) and np.all(p <= 2)
    close = p[:, 1] <= 0.1
    assert (p[:, 1] < 0.02).mean() < 0.03                                    # only uniform ones (1 % of them)
    # near points above the black patch (x > 3, outside the box) are drawn again; uniform ones: 5 % below 10 cm
    assert close.mean() == pytest.approx(0.5 + 0.5 * 0.05, abs=0.07)
    plain_p = np.array([c[0]["position"] for c in plain])
    assert (plain_p[:, 1] <= 0.1).mean() < 0.1                               # uniform: 5 % below 10 cm


# -------------------------------------------------------------------------------- measurement points
def _floor(size=2.0, albedo=(0.5, 0.25, 1.0)):
    """A size x size floor at y = 0 facing up, and a 1 m² patch of zero albedo beside it."""
    from workers.scene import NormalizedScene

    f = np.array([[(0, 0, 0), (0, 0, size), (size, 0, size)], [(0, 0, 0), (size, 0, size), (size, 0, 0)]], np.float32)
    dark = f / size + np.float32([size + 1, 0, 0])
    mats = [{"name": n, "base_color": list(a) + [1.0], "base_color_texture": None, "emissive": [0, 0, 0],
             "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 1.0}
            for n, a in (("floor", albedo), ("black", (0, 0, 0)))]
    return NormalizedScene(triangles=np.concatenate([f, dark]), normals=np.tile(np.float32([0, 1, 0]), (4, 3, 1)),
                           uv0=np.zeros((4, 3, 2), np.float32), material=np.array([0, 0, 1, 1], np.int32),
                           materials=mats)


def test_triangle_areas():
    assert np.allclose(k.triangle_areas(UNIT_SQUARE), [0.5, 0.5])
    assert np.allclose(k.triangle_areas(_floor(3.0).triangles), [4.5, 4.5, 0.5, 0.5])


def test_measurement_points_keep_usable_surfaces_and_group_supersamples():
    scene = _floor()
    lit = lambda pos, nrm, alb: np.any(alb > 0, axis=1)                    # noqa: E731 - the black patch is out
    pts = k.measurement_points(scene, 16, 4, np.random.default_rng(0), usable=lit)
    assert pts["position"].shape == (64, 3)
    off = pts["offsets"]
    assert off.shape == (17,) and off[0] == 0 and off[-1] == 64 and np.all(np.diff(off) > 0)
    assert np.all(pts["position"][:, 0] <= 2.0)                            # all on the floor
    assert np.allclose(pts["albedo"], (0.5, 0.25, 1.0)) and np.allclose(pts["normal"], (0, 1, 0))
    assert pts["usable_fraction"] == pytest.approx(4 / 5, abs=0.1)         # 4 m² of the 5 (320 candidates)
    # each sample joins its nearest of 16 blue-noise points: a group is a small patch (Voronoi cell) of the floor
    p = pts["position"]
    spread = [np.linalg.norm(p[a:b, None] - p[None, a:b], axis=2).max() for a, b in zip(off[:-1], off[1:])]
    assert max(spread) < 1.2 and np.mean(spread) < 0.5 * np.linalg.norm(p[:, None] - p[None], axis=2).mean()
    one = k.measurement_points(scene, 16, 1, np.random.default_rng(0))
    assert np.array_equal(one["offsets"], np.arange(17)) and one["usable_fraction"] == 1.0


def test_measurement_direct_is_albedo_over_pi_times_the_inverse_square_law():
    # one point light 1 m above the floor, 2 cd: E = 2 cos θ / d², x = albedo/π · E averaged per point
    pts = {"position": np.float32([[1, 0, 1], [1, 0, 2], [2, 0, 1]]), "normal": np.float32([[0, 1, 0]] * 3),
           "albedo": np.float32([[0.5, 0.5, 0.5], [1, 1, 1], [0.2, 0.4, 0.6]]), "offsets": np.array([0, 2, 3])}
    light = [{"type": "point", "position": [1, 1, 1], "color": [1, 1, 1], "intensity": 2.0}]
    x = k.measurement_direct(pts, light, None, 1e-4)
    e = 2 * np.array([1.0, 1 / 2 ** 1.5, 1 / 2 ** 1.5])                       # cos θ / d² at the three samples
    want = pts["albedo"] / math.pi * e[:, None]
    assert x.shape == (2, 3) and np.allclose(x[0], want[:2].mean(axis=0), rtol=1e-5)
    assert np.allclose(x[1], want[2], rtol=1e-5)
