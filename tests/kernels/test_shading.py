"""Surface attributes at hits and direct light (workers/kernels/shading.py): known answers."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels import shading
from workers.kernels.shading import direct_irradiance, sample_texture, srgb_to_linear, surface_at_hits
from workers.raycast import EmbreeRayCaster
from workers.scene import NormalizedScene

EPS = 1e-4


def _srgb(code):
    """Independent sRGB decode of 8-bit codes (IEC 61966-2-1)."""
    c = np.asarray(code, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _quad(x0, x1, z0, z1, y):
    """Two CCW triangles of the horizontal rectangle [x0, x1] x [z0, z1] at height y, facing +y."""
    a, b, c, d = (x0, y, z0), (x0, y, z1), (x1, y, z1), (x1, y, z0)
    return [[a, b, c], [a, c, d]]


@pytest.fixture(scope="module")
def ground():
    tris = np.array(_quad(-20, 20, -20, 20, 0.0), np.float32)
    return tris, EmbreeRayCaster(tris)


@pytest.fixture(scope="module")
def ground_and_blocker():
    tris = np.array(_quad(-20, 20, -20, 20, 0.0) + _quad(-0.5, 0.5, -0.5, 0.5, 1.0), np.float32)
    return tris, EmbreeRayCaster(tris)


def _ground_points(xz):
    xz = np.asarray(xz, np.float64)
    pts = np.stack([xz[:, 0], np.zeros(len(xz)), xz[:, 1]], axis=1)
    return pts, np.tile([0.0, 1.0, 0.0], (len(xz), 1))


def _point(pos, intensity=10.0, color=(1.0, 0.5, 0.25), rng=None):
    return {"type": "point", "color": list(color), "intensity": intensity, "range": rng, "position": list(pos),
            "direction": None, "inner_cone_angle": None, "outer_cone_angle": None, "name": "p"}


# ------------------------------------------------------------------------------------ direct light
def test_ground_plane_normal_faces_up(ground):
    tris, _ = ground
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    assert np.all(n[:, 1] > 0)


def test_point_light_above_plane_is_inverse_square_cosine(ground):
    _, caster = ground
    rng = np.random.default_rng(0)
    pts, nrm = _ground_points(rng.uniform(-5, 5, (500, 2)))
    light = _point([0.3, 2.0, -0.4])
    e = direct_irradiance(pts, nrm, [light], caster, EPS)
    assert e.dtype == np.float32 and e.shape == (500, 3)
    to = np.array(light["position"]) - pts
    d = np.linalg.norm(to, axis=1)
    cos = to[:, 1] / d
    expected = (10.0 * cos / d**2)[:, None] * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(e, expected, rtol=1e-6)


def test_light_below_surface_gives_zero(ground):
    _, caster = ground
    pts, nrm = _ground_points([[0, 0], [1, 1]])
    e = direct_irradiance(pts, nrm, [_point([0, -1, 0])], caster, EPS)
    assert np.all(e == 0)


def test_blocker_casts_a_shadow(ground_and_blocker):
    _, caster = ground_and_blocker
    # light at height 2 over a 1x1 blocker at height 1: the umbra on the ground is [-1, 1]²
    inside = [[0, 0], [0.8, -0.8], [-0.5, 0.9], [0.95, 0.0]]
    outside = [[1.1, 0], [0, -1.3], [3, 3], [-1.05, 1.05]]
    pts, nrm = _ground_points(inside + outside)
    e = direct_irradiance(pts, nrm, [_point([0, 2, 0])], caster, EPS)
    assert np.all(e[:4] == 0)
    d = np.linalg.norm(np.array([0, 2, 0]) - pts[4:], axis=1)
    np.testing.assert_allclose(e[4:, 0], 10.0 * (2.0 / d) / d**2, rtol=1e-6)
    # without a caster nothing is shadowed
    e_free = direct_irradiance(pts, nrm, [_point([0, 2, 0])], None, EPS)
    assert np.all(e_free[:, 0] > 0)


def test_point_light_beneath_blocker_is_not_shadowed_by_it(ground_and_blocker):
    _, caster = ground_and_blocker
    pts, nrm = _ground_points([[0, 0], [0.3, 0.2]])
    e = direct_irradiance(pts, nrm, [_point([0, 0.9, 0])], caster, EPS)  # light between ground and blocker
    d = np.linalg.norm(np.array([0, 0.9, 0]) - pts, axis=1)
    np.testing.assert_allclose(e[:, 0], 10.0 * (0.9 / d) / d**2, rtol=1e-6)


def test_spot_cone_edges(ground):
    _, caster = ground
    inner, outer, h = math.radians(20), math.radians(40), 2.0
    spot = {"type": "spot", "color": [1, 1, 1], "intensity": 50.0, "range": None, "position": [0, h, 0],
            "direction": [0, -1, 0], "inner_cone_angle": inner, "outer_cone_angle": outer, "name": "s"}
    theta = np.radians([0, 10, 19.9, 20.1, 25, 30, 35, 39.9, 40.1, 50, 70])
    phi = np.linspace(0, 2 * np.pi, len(theta), endpoint=False)
    r = h * np.tan(theta)
    pts, nrm = _ground_points(np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1))
    e = direct_irradiance(pts, nrm, [spot], caster, EPS)[:, 0]
    d = h / np.cos(theta)
    t = np.clip((np.cos(theta) - math.cos(outer)) / (math.cos(inner) - math.cos(outer)), 0, 1)
    expected = 50.0 * np.cos(theta) / d**2 * t**2
    np.testing.assert_allclose(e, expected, rtol=1e-5, atol=1e-7)
    assert np.all(e[theta < inner] == pytest.approx(50.0 * np.cos(theta[theta < inner]) ** 3 / h**2, rel=1e-6))
    assert np.all(e[theta > outer] == 0)
    assert 0 < e[5] < 50.0 * np.cos(theta[5]) ** 3 / h**2


def test_directional_light_and_its_shadow(ground_and_blocker):
    _, caster = ground_and_blocker
    w = np.array([0.6, -0.8, 0.0])  # direction the light travels
    sun = {"type": "directional", "color": [0.5, 1.0, 2.0], "intensity": 3.0, "range": None, "position": None,
           "direction": w.tolist(), "inner_cone_angle": None, "outer_cone_angle": None, "name": "sun"}
    # the blocker at height 1 shifts its shadow by +0.75 in x on the ground
    pts, nrm = _ground_points([[0.75, 0.0], [5, 5], [-4, 2]])
    e = direct_irradiance(pts, nrm, [sun], caster, EPS)
    assert np.all(e[0] == 0)
    np.testing.assert_allclose(e[1:], np.tile(3.0 * 0.8 * np.array([0.5, 1.0, 2.0]), (2, 1)), rtol=1e-6)
    # a surface facing away from the sun gets nothing
    e_back = direct_irradiance(pts[1:2] + [0, 5, 0], -nrm[1:2], [sun], caster, EPS)
    assert np.all(e_back == 0)
    # a tilted normal: E = I·max(0, n·(-w))
    n2 = np.array([[1.0, 1.0, 0.0]]) / math.sqrt(2)
    e_tilt = direct_irradiance(np.array([[10.0, 0.0, 10.0]]), n2, [sun], caster, EPS)
    np.testing.assert_allclose(e_tilt[0], 3.0 * (n2[0] @ -w) * np.array([0.5, 1.0, 2.0]), rtol=1e-6)


def test_range_window(ground):
    _, caster = ground
    R, h = 4.0, 1.0
    light = _point([0, h, 0], intensity=7.0, color=(1, 1, 1), rng=R)
    x = np.array([0.0, 1.0, 2.0, 3.0, 3.8, 3.9, 5.0, 8.0])
    pts, nrm = _ground_points(np.stack([x, np.zeros_like(x)], axis=1))
    e = direct_irradiance(pts, nrm, [light], caster, EPS)[:, 0]
    d = np.sqrt(x**2 + h**2)
    win = np.clip(1 - (d / R) ** 4, 0, 1) ** 2
    np.testing.assert_allclose(e, 7.0 * (h / d) / d**2 * win, rtol=1e-6, atol=1e-9)
    assert np.all(e[d >= R] == 0) and np.all(e[d < R] > 0)


def test_lights_add_and_chunking_does_not_change_results(ground_and_blocker, monkeypatch):
    _, caster = ground_and_blocker
    rng = np.random.default_rng(3)
    pts, nrm = _ground_points(rng.uniform(-3, 3, (1000, 2)))
    lights = [_point([0, 2, 0]), _point([1, 3, -1], intensity=4.0, color=(0.2, 0.9, 0.1), rng=5.0)]
    both = direct_irradiance(pts, nrm, lights, caster, EPS)
    parts = sum(direct_irradiance(pts, nrm, [lt], caster, EPS).astype(np.float64) for lt in lights)
    np.testing.assert_allclose(both, parts, rtol=1e-6)
    monkeypatch.setattr(shading, "DIRECT_CHUNK", 77)
    np.testing.assert_array_equal(direct_irradiance(pts, nrm, lights, caster, EPS), both)


def test_direct_irradiance_empty_and_bad_shapes(ground):
    _, caster = ground
    assert direct_irradiance(np.zeros((0, 3)), np.zeros((0, 3)), [_point([0, 1, 0])], caster, EPS).shape == (0, 3)
    assert np.all(direct_irradiance(np.zeros((2, 3)), np.zeros((2, 3)), [_point([0, 1, 0])], caster, EPS) == 0)
    with pytest.raises(ValueError):
        direct_irradiance(np.zeros((2, 3)), np.zeros((3, 3)), [], caster, EPS)


# ------------------------------------------------------------------------------------ surfaces
TEX = np.array(
    [[[255, 0, 0, 255], [0, 128, 255, 255]],
     [[64, 200, 10, 255], [255, 255, 255, 0]]], np.uint8)  # row 0 is v in [0, 0.5)
EMIT_TEX = np.array([[[10, 20, 30, 255], [40, 50, 60, 255]], [[70, 80, 90, 255], [250, 240, 230, 255]]], np.uint8)


def _unit_square_scene():
    """Unit square in z = 0 (CCW, facing +z), uv0 = (x, y); tri 0: x >= y, tri 1: y >= x.

    Triangles 2-3 repeat the square at z = 1 with material 1 (emissive, untextured base colour).
    """
    sq = [[(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 0, 0), (1, 1, 0), (0, 1, 0)]]
    tris = np.array(sq + [[(x, y, 1) for x, y, _ in t] for t in sq], np.float32)
    uv = tris[:, :, :2].copy()
    normals = np.zeros_like(tris)
    normals[:] = (0, 0, 1)
    normals[0, 1] = (1, 0, 1)  # a bent vertex normal on tri 0 (not unit on purpose)
    materials = [
        {"name": "tex", "base_color": [0.5, 1.0, 0.8, 1.0], "base_color_texture": 0, "emissive": [0, 0, 0],
         "emissive_texture": None, "double_sided": False},
        {"name": "glow", "base_color": [0.2, 0.3, 0.4, 1.0], "base_color_texture": None, "emissive": [2.0, 3.0, 4.0],
         "emissive_texture": 1, "double_sided": True},
    ]
    return NormalizedScene(triangles=tris, normals=normals, uv0=uv, material=np.array([0, 0, 1, 1], np.int32),
                           materials=materials, textures=[TEX, EMIT_TEX])


def _bary(tri, x, y):
    """(u, v) of point (x, y) in triangle 0/2 (x >= y) or 1/3 (y >= x) of the unit square."""
    if tri % 2 == 0:
        return x - y, y  # (1-u-v)(0,0) + u(1,0) + v(1,1)
    return x, y - x  # (1-u-v)(0,0) + u(1,1) + v(0,1)


def _query(points_xy, base_tri=0):
    tri, u, v = [], [], []
    for x, y in points_xy:
        t = base_tri + (0 if x >= y else 1)
        a, b = _bary(t, x, y)
        tri.append(t)
        u.append(a)
        v.append(b)
    return np.array(tri), np.array(u), np.array(v)


def test_srgb_decode():
    np.testing.assert_allclose(srgb_to_linear([0.0, 0.04045, 0.5, 1.0]),
                               [0.0, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0], rtol=1e-12)
    np.testing.assert_allclose(shading.SRGB_TO_LINEAR_LUT, _srgb(np.arange(256)), rtol=1e-12)


def test_albedo_is_exact_texel_colour_at_texel_centres():
    scene = _unit_square_scene()
    centres = [((c + 0.5) / 2, (r + 0.5) / 2) for r in range(2) for c in range(2)]
    s = surface_at_hits(scene, *_query(centres))
    expected = np.array([_srgb(TEX[r, c, :3]) for r in range(2) for c in range(2)]) * [0.5, 1.0, 0.8]
    np.testing.assert_allclose(s["albedo"], expected, rtol=1e-6, atol=1e-9)
    assert s["albedo"].dtype == np.float32
    assert np.all(s["emission"] == 0) and not s["double_sided"].any()


def test_albedo_filters_linear_values_and_wraps():
    scene = _unit_square_scene()
    s = surface_at_hits(scene, *_query([(0.5, 0.5), (0.0, 0.0), (0.25, 0.0)]))
    lin = _srgb(TEX[:, :, :3])  # (2, 2, 3) decoded
    mean4 = lin.reshape(4, 3).mean(axis=0)  # decode first, then average (sRGB texture filtering)
    # (0.5, 0.5) sits between all four texel centres; (0, 0) too, by REPEAT wrapping
    np.testing.assert_allclose(s["albedo"][0], mean4 * [0.5, 1.0, 0.8], rtol=1e-6)
    np.testing.assert_allclose(s["albedo"][1], mean4 * [0.5, 1.0, 0.8], rtol=1e-6)
    # (0.25, 0): between rows 1 (wrapped) and 0 of column 0
    np.testing.assert_allclose(s["albedo"][2], 0.5 * (lin[0, 0] + lin[1, 0]) * [0.5, 1.0, 0.8], rtol=1e-6)
    # integer uv offsets change nothing (REPEAT)
    uv = np.array([[0.25, 0.25], [0.75, 0.6], [0.1, 0.9]])
    np.testing.assert_allclose(sample_texture(TEX, uv + [3.0, -2.0]), sample_texture(TEX, uv), rtol=1e-12, atol=1e-15)


def test_emission_texture_and_untextured_base_colour():
    scene = _unit_square_scene()
    centres = [((c + 0.5) / 2, (r + 0.5) / 2) for r in range(2) for c in range(2)]
    s = surface_at_hits(scene, *_query(centres, base_tri=2))
    expected = np.array([_srgb(EMIT_TEX[r, c, :3]) for r in range(2) for c in range(2)]) * [2.0, 3.0, 4.0]
    np.testing.assert_allclose(s["emission"], expected, rtol=1e-6)
    np.testing.assert_allclose(s["albedo"], np.tile([0.2, 0.3, 0.4], (4, 1)), rtol=1e-7)
    assert s["double_sided"].all()
    np.testing.assert_allclose(s["position"][:, 2], 1.0)


def test_geometry_normals_positions_and_misses():
    scene = _unit_square_scene()
    tri = np.array([0, -1, 1, 0, 3])
    u = np.array([0.2, 0.5, 0.3, 0.0, 0.1])
    v = np.array([0.3, 0.5, 0.3, 0.0, 0.6])
    s = surface_at_hits(scene, tri, u, v)
    tris = scene.triangles.astype(np.float64)
    for i in (0, 2, 3, 4):
        t = tri[i]
        x = (1 - u[i] - v[i]) * tris[t, 0] + u[i] * tris[t, 1] + v[i] * tris[t, 2]
        np.testing.assert_allclose(s["position"][i], x, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(s["geo_normal"][i], [0, 0, 1], atol=1e-7)
    for key in ("position", "normal", "geo_normal", "albedo", "emission"):
        assert np.all(s[key][1] == 0), key
    assert not s["double_sided"][1]
    # interpolated vertex normal, normalized: tri 0 has vertex 1's normal bent toward +x
    nv = scene.normals.astype(np.float64)[0]
    n0 = (1 - 0.2 - 0.3) * nv[0] + 0.2 * nv[1] + 0.3 * nv[2]
    np.testing.assert_allclose(s["normal"][0], n0 / np.linalg.norm(n0), rtol=1e-6)
    np.testing.assert_allclose(s["normal"][3], [0, 0, 1], atol=1e-7)  # at vertex 0
    np.testing.assert_allclose(np.linalg.norm(s["normal"][[0, 2, 3, 4]], axis=1), 1.0, rtol=1e-6)


def test_surface_at_real_hits_matches_hit_points():
    scene = _unit_square_scene()
    caster = EmbreeRayCaster(scene.triangles)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.2, 1.2, (300, 2))
    o = np.concatenate([xy, np.full((300, 1), -1.0)], axis=1)
    d = np.tile([0.0, 0.0, 1.0], (300, 1))
    h = caster.intersect(o, d)
    s = surface_at_hits(scene, h.tri, h.u, h.v)
    hit = h.hit
    assert hit.any() and (~hit).any()
    np.testing.assert_allclose(s["position"][hit], h.points(o, d)[hit], atol=1e-6)
    np.testing.assert_allclose(s["position"][hit][:, :2], xy[hit], atol=1e-6)
    # hits on the textured square at z = 0 get the texture at uv = (x, y)
    expected = sample_texture(TEX, xy[hit]) * [0.5, 1.0, 0.8]
    np.testing.assert_allclose(s["albedo"][hit], expected, rtol=1e-5, atol=1e-7)
    assert np.all(s["albedo"][~hit] == 0)


def test_surface_at_hits_empty_and_bad_index():
    scene = _unit_square_scene()
    s = surface_at_hits(scene, np.zeros(0, int), np.zeros(0), np.zeros(0))
    assert s["albedo"].shape == (0, 3)
    with pytest.raises(ValueError):
        surface_at_hits(scene, np.array([4]), np.zeros(1), np.zeros(1))


# ------------------------------------------------------------------- bent shading normals (Cycles 3.4)
def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tilted(deg, axis=0):
    """Unit normal tilted by deg from +z toward +x (axis 0) or +y (axis 1)."""
    a = math.radians(deg)
    v = np.zeros(3)
    v[axis], v[2] = math.sin(a), math.cos(a)
    return v


def test_ensure_valid_reflection_keeps_normals_whose_reflection_is_above_the_surface():
    ng = np.tile([0.0, 0.0, 1.0], (4, 1))
    views = _unit([[0, 0, 1], [0.9, 0, 0.1], [-0.3, 0.5, 0.8], [0.99, 0, 0.02]])
    n, bent = shading.ensure_valid_reflection(ng, views, ng)                    # N == Ng: unchanged
    assert not bent.any() and np.array_equal(n, ng)
    # a bent normal whose mirror reflection of the viewer stays above the threshold: unchanged, bit for bit
    nb = np.tile(_tilted(30), (2, 1))
    v = _unit([[0, 0, 1], [0.5, 0, 0.5]])
    n, bent = shading.ensure_valid_reflection(ng[:2], v, nb)
    assert not bent.any() and np.array_equal(n, nb)


def _reflection_height(n, i):
    return float(np.dot(2 * np.dot(n, i) * n - i, [0, 0, 1]))


@pytest.mark.parametrize("view_deg", [3.0, 10.0, 30.0])
def test_ensure_valid_reflection_lifts_a_grazing_reflection_just_above_the_surface(view_deg):
    """N tilted 50° toward +x, the viewer on the other side (toward −x) at view_deg above the plane: R = 2(N·I)N − I
    points below the surface, so Cycles rotates N toward Ng, in the plane of N and Ng, until R·Ng equals the
    threshold t = min(0.9 Ng·I, 0.01). The answer is checked against the smallest such rotation found by bisection."""
    ng, nb = np.array([0.0, 0.0, 1.0]), _tilted(50)
    b = math.radians(view_deg)
    i = np.array([-math.cos(b), 0.0, math.sin(b)])
    assert _reflection_height(nb, i) < 0
    n, bent = shading.ensure_valid_reflection(ng[None], i[None], nb[None])
    n = n[0]
    t = min(0.9 * math.sin(b), 0.01)
    assert bent[0] and abs(np.linalg.norm(n) - 1) < 1e-12 and abs(n[1]) < 1e-12    # unit, in the N-Ng plane
    assert abs(_reflection_height(n, i) - t) < 1e-9                                 # just above: at the threshold
    lo, hi = 0.0, 50.0                # tilt of N (toward +x): R·Ng decreases with the tilt for this viewer
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _reflection_height(_tilted(mid), i) >= t else (lo, mid)
    np.testing.assert_allclose(n, _tilted(lo), atol=1e-8)


def test_bump_shadowing_term_hand_values():
    s, n = _tilted(40), _tilted(10)                  # smooth normal, closure normal
    w = _unit([[0, 0, 1], [-0.9, 0, 0.2], [0.6, 0, 0.8]])
    f = shading.bump_shadowing_term(np.tile(s, (3, 1)), np.tile(n, (3, 1)), w)
    g = np.dot(s, w[0]) / (np.dot(n, w[0]) * np.dot(s, n))          # 0 < g < 1: the smoothed cubic
    assert 0 < g < 1 and f[0] == pytest.approx(-g ** 3 + g ** 2 + g, rel=1e-12)
    assert f[1] == 0.0                               # below the smooth normal: black
    assert f[2] == 1.0                               # g >= 1: full brightness
    same = shading.bump_shadowing_term(np.tile(n, (3, 1)), np.tile(n, (3, 1)), w[[0, 2, 2]])
    assert np.all(same == 1.0)                       # s = N': g = 1/(N'·N') >= 1


def _sphere(m, seed):
    w = np.random.default_rng(seed).normal(size=(m, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


@pytest.mark.parametrize("tilt", [0.0, 20.0, 54.7, 80.0])
def test_horizon_factor_closed_form_matches_monte_carlo(tilt):
    """h = (1/π)∫ max(0, N'·ω)[Ng·ω > 0] dω = (1 + N'·Ng)/2: a uniform-sphere Monte Carlo integral."""
    ng, n = np.array([0.0, 0.0, 1.0]), _tilted(tilt, axis=1)
    h = shading.horizon_factor(n[None], ng[None])[0]
    assert h == pytest.approx(1.0 if tilt == 0 else (1 + math.cos(math.radians(tilt))) / 2, abs=1e-12)
    w = _sphere(1 << 20, 7)
    f = np.maximum(w @ n, 0) * (w @ ng > 0) * 4.0      # 4π/π × the uniform-sphere mean
    assert abs(f.mean() - h) < 4 * f.std() / math.sqrt(w.shape[0]) + 1e-4


@pytest.mark.parametrize("smooth_tilt, tilt", [(54.7, 10.0), (54.7, 40.0), (30.0, 5.0)])
def test_horizon_factor_of_bent_normals_matches_monte_carlo(smooth_tilt, tilt):
    """Where Cycles bent N (bent rows): h = (1/π)∫ max(0, N'·ω)[Ng·ω > 0]·S(s, N', ω) dω with S the bump shadowing
    term: the quadrature against a uniform-sphere Monte Carlo integral; well below the unbent (1 + N'·Ng)/2."""
    ng, s, n = np.array([0.0, 0.0, 1.0]), _tilted(smooth_tilt), _tilted(tilt)
    h = shading.horizon_factor(n[None], ng[None], s[None], np.array([True]))[0]
    w = _sphere(1 << 20, 11)
    f = np.maximum(w @ n, 0) * (w @ ng > 0) * shading.bump_shadowing_term(np.tile(s, (len(w), 1)),
                                                                           np.tile(n, (len(w), 1)), w) * 4.0
    assert abs(f.mean() - h) < 4 * f.std() / math.sqrt(w.shape[0]) + 2e-3
    assert h < (1 + n @ ng) / 2 - 0.03


def test_direct_irradiance_with_bent_normals(ground):
    """Lights below the geometric plane give 0 with geo_normals; bent rows are multiplied by the bump term; a
    flat frame (N = Ng, nothing bent) changes nothing, bit for bit."""
    _, caster = ground
    pts, up = _ground_points([[0.0, 0.0], [1.0, 2.0]])
    n = np.tile(_tilted(60)[[0, 2, 1]], (2, 1))           # tilted toward +x, about the ground's +y normal
    below = _point([3.0, -0.5, 0.0])                       # under the ground plane, in front of N
    e_n = direct_irradiance(pts, n, [below], None, EPS)                    # unshadowed, about N only: lit
    assert np.all(e_n[:, 0] > 0)
    e_g = direct_irradiance(pts, n, [below], None, EPS, geo_normals=up)     # below Ng: 0
    assert np.all(e_g == 0)
    above = _point([-0.6, 2.0, 0.0])
    e0 = direct_irradiance(pts, up, [above], caster, EPS)
    e1 = direct_irradiance(pts, up, [above], caster, EPS, geo_normals=up, smooth_normals=up, bent=np.zeros(2, bool))
    assert np.array_equal(e0, e1)
    s = np.tile(_tilted(60)[[0, 2, 1]], (2, 1))            # bent: N' = n10 differs from the smooth normal s
    n10 = np.tile(_tilted(10)[[0, 2, 1]], (2, 1))
    bent = np.array([True, False])
    e2 = direct_irradiance(pts, n10, [above], caster, EPS, geo_normals=up, smooth_normals=s, bent=bent)
    plain = direct_irradiance(pts, n10, [above], caster, EPS)
    l = _unit(np.asarray(above["position"]) - pts)
    f = shading.bump_shadowing_term(s, n10, l)
    assert 0 < f[0] < 0.99                                 # the term matters for this light
    np.testing.assert_allclose(e2[0], plain[0] * f[0], rtol=1e-6)
    np.testing.assert_array_equal(e2[1], plain[1])


def test_point_light_pass_equals_the_numpy_form(ground_and_blocker):
    """shading._add_point_light (one compiled pass) gives the numpy form's floats (shading._add_local_light) bit for
    bit: random points and normals around a blocker, some lit from below the geometric normal (rejected), zero
    geometric normals, bent rows with the bump term, a point at the light (d = 0) and one within 2·eps of it (no ray)."""
    tris, caster = ground_and_blocker
    rng = np.random.default_rng(12)
    m = 5000
    x = rng.uniform([-3, 0, -3], [3, 3, 3], (m, 3))
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    ng = n + 0.3 * rng.normal(size=(m, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ng[::97] = 0.0
    sm = n + 0.2 * rng.normal(size=(m, 3))
    sm /= np.linalg.norm(sm, axis=1, keepdims=True)
    bent = rng.random(m) < 0.3
    light = _point([0.3, 2.2, -0.4], 25.0)
    x[10] = light["position"]
    x[11] = np.asarray(light["position"]) + [1e-5, 0, 0]
    for frame in (None, (ng, None, None), (ng, sm, bent)):
        p = np.asarray(light["position"], np.float64)
        color = np.asarray(light["color"], np.float64) * light["intensity"]
        want, got = np.zeros_like(x), np.zeros_like(x)
        shading._add_local_light(want, x, n, light, p, color, None, caster, 1e-4, frame)     # the numpy form
        shading._add_point_light(got, x, n, p, color, caster, 1e-4, frame)
        assert np.array_equal(got, want)
        assert (want > 0).any() and (want == 0).any()
