"""A point light's hot spot sampled from the light (workers/kernels/light_spots.py): the split is exact, the spot's
virtual lights add the light the probe rays no longer carry, and a light without a spot changes nothing."""
from __future__ import annotations

import math

import numpy as np

from workers.kernels import light_spots as LS
from workers.kernels.materials import double_sided_triangles
from workers.kernels.octahedral import oct_texel_directions
from workers.kernels.shading import direct_irradiance
from workers.raycast import RayCaster
from workers.scene import NormalizedScene

ALBEDO = 0.5


def _floor(half=30.0):
    """A floor [-half, half]² at z = 0 facing +z, albedo 0.5."""
    h = half
    q = np.array([[(-h, -h, 0), (h, -h, 0), (h, h, 0)], [(-h, -h, 0), (h, h, 0), (-h, h, 0)]], np.float32)
    mat = {"name": "m", "base_color": [ALBEDO] * 3 + [1.0], "base_color_texture": None, "emissive": [0.0] * 3,
           "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 1.0}
    return NormalizedScene(triangles=q, normals=np.tile(np.float32([0, 0, 1]), (2, 3, 1)),
                           uv0=np.zeros((2, 3, 2), np.float32), material=np.zeros(2, np.int32), materials=[mat])


def _truth(x, n, h, c):
    """E(n) at x of the floor lit by a 1 cd point light at height h, reflected (albedo ρ): ∫ ρ/π·E_l(y)·max(0, n·ω)
    cos θ_y / d² dA by polar quadrature about the light's foot; with c, only the excess E_l·max(0, 1 − c/E_l)."""
    r = np.concatenate([np.geomspace(1e-5, 0.5, 3000), np.linspace(0.5, 30.0, 3000)[1:]])
    a = np.linspace(0.0, 2.0 * np.pi, 721)[:-1] + np.pi / 720
    rr, aa = np.meshgrid(0.5 * (r[1:] + r[:-1]), a, indexing="ij")
    dA = (np.diff(r)[:, None] * rr) * (2.0 * np.pi / a.size)
    y = np.stack([rr * np.cos(aa), rr * np.sin(aa), np.zeros_like(rr)], -1)
    e = h / (rr ** 2 + h ** 2) ** 1.5                                            # I cos θ / d², I = 1
    if c is not None:
        e = e * np.maximum(0.0, 1.0 - c / e)
    w = y - x
    d = np.linalg.norm(w, axis=-1)
    om = w / d[..., None]
    g = np.maximum(om @ n, 0.0) * (x[2] / d) / d ** 2                           # cos θ_x, cos θ_y / d²
    return float((ALBEDO / np.pi * e * g * dA).sum())


def test_excess_plus_bounded_part_is_the_reflected_light():
    """Light 1 cm above the floor (the Cornell box's case: ~10⁴ lux under it), probe 0.4 m up: the probe rays' bounded
    part (R = 2¹⁸ rays, many more than a bake's) plus the spot's virtual lights give the path-integral's irradiance
    for every texel facing the floor within 2%; the virtual lights alone give the excess within 2%."""
    scene = _floor()
    caster = RayCaster(scene.triangles)
    h, c = 0.01, 20.0
    light = {"type": "point", "position": [0.0, 0.0, h], "intensity": 1.0, "color": [1.0, 1.0, 1.0]}
    x = np.array([[0.3, 0.1, 0.4]], np.float32)
    n = 4
    dmaps, dsh, nv, rays = LS.spot_correction(scene, caster, x, np.ones(1, bool), [light], [c],
                                              double_sided_triangles(scene), [0.2, 0.2, 0.2], n, 1e-5)
    assert nv > 0 and 0 < rays <= nv                     # the faint cells' pairs go through the roulette
    from workers.kernels.sampling import fibonacci_sphere
    R = 1 << 18
    dirs = fibonacci_sphere(R).astype(np.float64)
    down = dirs[:, 2] < 0
    t = -x[0, 2] / dirs[down, 2]
    y = x[0] + t[:, None] * dirs[down]
    e = direct_irradiance(y, np.tile([0.0, 0.0, 1.0], (len(y), 1)), [light], None, 0.0)
    bounded = LS.split_direct([e], [c])
    assert np.all(bounded.mean(1) <= c * 1.0001)
    texel = oct_texel_directions(n).reshape(-1, 3)
    facing = np.flatnonzero(texel[:, 2] < -0.5)
    assert facing.size >= 2
    for k in facing:
        nt = texel[k].astype(np.float64)
        cosn = np.maximum(dirs[down] @ nt, 0.0)
        e_rays = np.pi * (cosn * ALBEDO / np.pi * bounded[:, 0]).sum() / np.maximum(dirs @ nt, 0.0).sum()
        spot = float(dmaps[0, 1:-1, 1:-1].reshape(-1, 3)[k, 0])
        want_spot = _truth(x[0].astype(np.float64), nt, h, c)
        want = _truth(x[0].astype(np.float64), nt, h, None)
        assert abs(spot / want_spot - 1) < 0.02, (k, spot, want_spot)
        assert abs((e_rays + spot) / want - 1) < 0.02, (k, e_rays + spot, want)
        assert spot > 0.3 * want                                               # the spot is a large share


def test_a_light_without_a_spot_changes_nothing():
    """Light 1 m above the floor: no hit is 32x the median, so no excess, no virtual light, no correction."""
    scene = _floor()
    caster = RayCaster(scene.triangles)
    light = {"type": "point", "position": [0.0, 0.0, 1.0], "intensity": 1.0, "color": [1.0, 1.0, 1.0]}
    from workers.kernels.sampling import fibonacci_sphere
    dirs = fibonacci_sphere(256).astype(np.float64)
    x = np.array([0.3, 0.1, 0.4])
    down = dirs[:, 2] < 0
    y = x + (-x[2] / dirs[down, 2])[:, None] * dirs[down]
    e = direct_irradiance(y, np.tile([0.0, 0.0, 1.0], (len(y), 1)), [light], None, 0.0)
    c = LS.spot_thresholds([e], [light])
    assert math.isfinite(c[0]) and np.array_equal(LS.split_direct([e], c), e)
    dmaps, dsh, nv, rays = LS.spot_correction(scene, caster, x[None].astype(np.float32), np.ones(1, bool), [light], c,
                                              double_sided_triangles(scene), [0.2, 0.2, 0.2], 4, 1e-5)
    assert nv == 0 and rays == 0 and not dmaps.any() and not dsh.any()
    sun = {"type": "directional", "direction": [0.0, 0.0, -1.0], "intensity": 1.0, "color": [1.0, 1.0, 1.0]}
    assert LS.spot_thresholds([e], [sun]) == [math.inf]


def test_virtual_lights_are_capped_keeping_their_power(monkeypatch):
    """More cells than MAX_VIRTUAL_LIGHTS: the cells double until they fit; the probe's spot light (L0 of its SH)
    stays within 5% of the fine cells'."""
    scene = _floor()
    caster = RayCaster(scene.triangles)
    light = {"type": "point", "position": [0.0, 0.0, 0.01], "intensity": 1.0, "color": [1.0, 1.0, 1.0]}
    x = np.array([[0.3, 0.1, 0.4]], np.float32)
    args = (scene, caster, x, np.ones(1, bool), [light], [20.0], double_sided_triangles(scene), [0.2] * 3, 4, 1e-5)
    _, fine, n_fine, _ = LS.spot_correction(*args)
    monkeypatch.setattr(LS, "MAX_VIRTUAL_LIGHTS", 4)
    _, coarse, n_coarse, _ = LS.spot_correction(*args)
    assert n_fine > 4 >= n_coarse > 0
    assert abs(coarse[0, 0, 0] / fine[0, 0, 0] - 1) < 0.05


def test_pair_and_delta_kernels_equal_the_vectorized_sums():
    """The compiled pairs (:func:`LS._spot_pairs`) and deltas (:func:`LS._add_deltas`, the SH basis per pair) give
    the sums of the vectorized form they replaced: per virtual light the probes with cos θ_y > 0, their shadow rays,
    a·max(0, texel·ω) into the maps and a·Y_k(ω) (:func:`workers.kernels.sh._sh_basis`) into the SH, blocked pairs
    skipped. Random lights and probes; a probe standing at a light's lifted origin gets a zero-length ray."""
    from workers.kernels.sh import _sh_basis

    rng = np.random.default_rng(5)
    V, N, n, eps, dmin = 7, 300, 8, 1e-3, 0.05
    vy, x = rng.uniform(-2, 2, (V, 3)), rng.uniform(-2, 2, (N, 3))
    vn = rng.normal(size=(V, 3))
    vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    vp = rng.uniform(0, 3, (V, 3))
    x[17] = vy[2] + eps * vn[2]                         # at the origin of virtual light 2's rays
    texel = oct_texel_directions(n).reshape(-1, 3).astype(np.float64)
    o, dirs, om, a = (np.full((V * N, 3), np.nan) for _ in range(4))
    tfar, probe = np.full(V * N, np.nan), np.full(V * N, -1, np.int64)
    k = LS._spot_pairs(vy, vn, vp, x, eps, dmin, o, dirs, tfar, probe, om, a, LS._luma(vp), np.zeros(N),
                       np.uint64(0), 0)                 # bound 0: no roulette, every pair
    ref = {f: [] for f in ("o", "dirs", "tfar", "probe", "om", "a")}
    for y, ny, pw in zip(vy, vn, vp):                   # the vectorized form (light stage 12)
        w = y - x
        d = np.sqrt(np.einsum("ij,ij->i", w, w))
        omj = w / np.maximum(d, 1e-12)[:, None]
        ok = np.flatnonzero(-(omj @ ny) > 0)
        oj = (y + eps * ny)[None].repeat(ok.size, 0)
        back = x[ok] - oj
        dist = np.sqrt(np.einsum("ij,ij->i", back, back))
        with np.errstate(invalid="ignore"):
            ref["dirs"].append(back / dist[:, None])
        ref["o"].append(oj)
        ref["tfar"].append(np.maximum(dist - 2 * eps, 0.0))
        ref["probe"].append(ok)
        ref["om"].append(omj[ok])
        ref["a"].append((-(omj @ ny))[ok, None] / np.maximum(d[ok], dmin)[:, None] ** 2 * pw[None])
    ref = {f: np.concatenate(v) for f, v in ref.items()}
    assert k == ref["probe"].size and 0 < k < V * N
    np.testing.assert_array_equal(probe[:k], ref["probe"])
    for f, got in (("o", o), ("tfar", tfar), ("om", om), ("a", a)):
        np.testing.assert_allclose(got[:k], ref[f], rtol=1e-13, atol=0, err_msg=f)
    zero = np.flatnonzero(np.isnan(ref["dirs"][:, 0]))
    assert zero.size == 1 and tfar[zero[0]] == 0.0 and np.array_equal(dirs[zero[0]], [0, 0, 1])
    rest = np.setdiff1d(np.arange(k), zero)
    np.testing.assert_allclose(dirs[rest], ref["dirs"][rest], rtol=1e-13, atol=1e-15)

    free = rng.uniform(size=k) < 0.7
    for K in (4, 9):
        dmaps, dsh = np.zeros((N, n * n, 3)), np.zeros((N, K, 3))
        LS._add_deltas(dmaps, dsh, probe[:k], free, om[:k], a[:k], texel)
        want_maps, want_sh = np.zeros_like(dmaps), np.zeros_like(dsh)
        p, om_f, a_f = probe[:k][free], om[:k][free], a[:k][free]
        np.add.at(want_maps, p, np.maximum(om_f @ texel.T, 0.0)[:, :, None] * a_f[:, None, :])
        np.add.at(want_sh, p, _sh_basis(om_f, K)[:, :, None] * a_f[:, None, :])
        np.testing.assert_allclose(dmaps, want_maps, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(dsh, want_sh, rtol=1e-12, atol=1e-15)
        assert np.count_nonzero(dsh) > 0


def test_split_direct_equals_the_vectorized_split():
    """:func:`LS.split_direct`'s compiled row loop gives the floats of ``Σ_l E_l·min(1, c_l/max(Y(E_l), 1e-30))``
    written with numpy (its former form), NaN and inf rows and an infinite threshold included."""
    rng = np.random.default_rng(1)
    per = [rng.gamma(0.3, 5, (5000, 3)).astype(np.float32) for _ in range(3)]
    per[0][:100] = 0
    per[1][5], per[2][7] = np.nan, np.inf
    th = [2.0, math.inf, 0.5]
    want = np.zeros((5000, 3))
    for e, c in zip(per, th):
        with np.errstate(all="ignore"):
            want += e.astype(np.float64) * np.minimum(1.0, c / np.maximum(LS._luma(e), 1e-30))[:, None]
    got = LS.split_direct(per, th)
    assert got.dtype == np.float32 and np.array_equal(got, want.astype(np.float32), equal_nan=True)
    assert np.isnan(got[5]).all() and np.isnan(got[7]).all() and (got[8:] < per[0][8:] + per[1][8:] + per[2][8:] + 1).all()


def test_roulette_keeps_the_expectation_with_fewer_rays():
    """Four lights 2 cm over a 60 m floor, 49 probes 7 m apart: most (virtual light, probe) pairs are faint. With the
    roulette the shadow rays fall to under a third; the mean over seeds of every probe's spot irradiance (L0 of its
    SH) and map is the exact sum's (within 4 standard errors; the seeds are fixed, so this cannot flake); a seed gives
    the same floats twice, another seed others."""
    scene = _floor()
    caster = RayCaster(scene.triangles)
    lights = [{"type": "point", "position": [px, py, 0.02], "intensity": 1.0, "color": [1.0, 0.8, 0.6]}
              for px, py in ((-12.0, -9.0), (3.0, 14.0), (17.0, -4.0), (-20.0, 21.0))]
    g = np.linspace(-21.0, 21.0, 7)
    x = np.stack(np.meshgrid(g, g, [0.6], indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    args = (scene, caster, x, np.ones(len(x), bool), lights, [20.0] * 4, double_sided_triangles(scene),
            [0.5, 0.5, 0.5], 4, 1e-5)               # cells of 6 cm: many virtual lights
    m0, sh0, nv, rays0 = LS.spot_correction(*args, roulette=0.0)
    assert nv > 40 and rays0 == nv * len(x)
    runs = [LS.spot_correction(*args, roulette=1.0 / 64, seed=s) for s in range(64)]
    rays = np.array([r[3] for r in runs])
    assert rays.max() < rays0 / 3
    l0 = np.array([r[1][:, 0, :] for r in runs])                   # (seeds, P, 3)
    mean, se = l0.mean(0), l0.std(0, ddof=1) / math.sqrt(len(runs))
    assert np.all(np.abs(mean - sh0[:, 0, :]) <= 4 * se + 1e-12 * np.abs(sh0[:, 0, :]).max())
    assert (se > 0).any()                                           # the roulette did draw
    maps = np.array([r[0] for r in runs], np.float64)
    np.testing.assert_allclose(maps.mean(0), m0, rtol=0.05, atol=1e-3 * float(m0.max()))
    again = LS.spot_correction(*args, roulette=1.0 / 64, seed=0)
    assert np.array_equal(again[1], runs[0][1]) and np.array_equal(again[0], runs[0][0])
    assert not np.array_equal(runs[1][1], runs[0][1])
