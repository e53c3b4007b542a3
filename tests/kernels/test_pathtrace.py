"""The path tracer (workers/kernels/pathtrace.py) against closed forms, and against Cycles."""
from __future__ import annotations

import json
import math
import zipfile

import numpy as np
import pytest

from tests.conftest import shared_path
from workers.kernels.pathtrace import indirect_irradiance, scene_eps
from workers.kernels.shading import SRGB_TO_LINEAR_LUT, direct_irradiance, surface_at_hits
from workers.kernels.texels import texel_surfaces
from workers.raycast import RayCaster
from workers.scene import NormalizedScene


def _material(albedo, emission=0.0, double_sided=False):
    a = [albedo] * 3 if np.isscalar(albedo) else list(albedo)
    e = [emission] * 3 if np.isscalar(emission) else list(emission)
    return {"name": "m", "base_color": a + [1.0], "base_color_texture": None, "emissive": e,
            "emissive_texture": None, "double_sided": double_sided}


def _scene(tris, materials, material=None) -> NormalizedScene:
    tris = np.asarray(tris, np.float32)
    T = len(tris)
    ng = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    return NormalizedScene(triangles=tris, normals=np.repeat(ng[:, None], 3, axis=1).astype(np.float32),
                           uv0=np.zeros((T, 3, 2), np.float32),
                           material=np.zeros(T, np.int32) if material is None else np.asarray(material, np.int32),
                           materials=materials)


def closed_box(albedo: float, emission: float, size: float = 1.0) -> NormalizedScene:
    """A closed cube [0, size]^3 whose 12 triangles all face inward."""
    L = size
    c = np.array([[0, 0, 0], [L, 0, 0], [L, L, 0], [0, L, 0], [0, 0, L], [L, 0, L], [L, L, L], [0, L, L]], float)
    quads = [(0, 1, 2, 3), (5, 4, 7, 6), (4, 0, 3, 7), (1, 5, 6, 2), (3, 2, 6, 7), (4, 5, 1, 0)]
    tris = np.array([[c[q[0]], c[q[i]], c[q[i + 1]]] for q in quads for i in (1, 2)])
    ng = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    outward = np.einsum("ij,ij->i", ng, tris.mean(axis=1) - L / 2) > 0
    tris[outward] = tris[outward][:, ::-1]
    return _scene(tris, [_material(albedo, emission)])


BOX_POINTS = np.array([[0.5, 0.0, 0.5], [0.2, 0.3, 0.0], [1.0, 0.7, 0.4], [0.5, 1.0, 0.9]])
BOX_NORMALS = np.array([[0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)


# ----------------------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("bounces", [1, 2, 5])
def test_closed_furnace_truncated_series_exact(bounces):
    """Closed box, walls albedo a emitting Le: vertex k adds a^(k-1)·Le on every path, so without
    emitter sampling the estimate is exact: E_indirect = π·Le·(1 - a^B)/(1 - a)."""
    a, le = 0.6, 0.8
    s = closed_box(a, le)
    r = indirect_irradiance(s, BOX_POINTS, BOX_NORMALS, spp=16, bounces=bounces, seed=1, emitter_sampling=False)
    expect = math.pi * le * (1 - a ** bounces) / (1 - a)
    np.testing.assert_allclose(r.irradiance, expect, rtol=1e-5)
    assert r.stats["backface_ends"] == 0 and r.stats["below_surface"] == 0


@pytest.mark.parametrize("emitter_sampling", [False, True])
def test_closed_furnace_converges_to_geometric_series(emitter_sampling):
    """With Russian roulette and many bounces: E_indirect → π·Le/(1 - a), i.e. exitant radiance
    L = Le + a/π·E = Le/(1 - a) (the geometric series Le·Σ a^k)."""
    a, le = 0.5, 1.0
    s = closed_box(a, le)
    r = indirect_irradiance(s, BOX_POINTS, BOX_NORMALS, spp=2048, bounces=64, rr_depth=2, seed=3,
                            emitter_sampling=emitter_sampling)
    expect = math.pi * le / (1 - a)
    np.testing.assert_allclose(r.irradiance, expect, rtol=0.03)
    assert np.all(np.abs(r.irradiance - expect) < 5 * r.stderr + 1e-3 * expect)
    radiance = le + a / math.pi * r.irradiance
    np.testing.assert_allclose(radiance, le / (1 - a), rtol=0.03)
    assert r.stats["rr_kills"] > 0
    if emitter_sampling:
        assert r.stats["emitters"] == 12 and r.stats["shadow_rays"] > 0


def test_russian_roulette_control_variate_exact_and_unbiased():
    """Russian roulette with a control variate (module doc): in the closed furnace every path gathers Le/(1 − a)
    per unit throughput after any vertex, so with that tail guess a killed path adds exactly what it would have
    gathered: the estimate is exact (no roulette noise left, where plain roulette's is visible). A wrong guess (3x,
    a fifth, a different one per point) leaves the estimate unbiased: within 5 standard errors of the closed form,
    with and without emitter sampling."""
    a, le = 0.5, 1.0
    s = closed_box(a, le)
    expect = math.pi * le / (1 - a)
    kw = dict(spp=256, bounces=64, rr_depth=2, seed=3)
    exact = np.full((4, 3), le / (1 - a))
    r = indirect_irradiance(s, BOX_POINTS, BOX_NORMALS, tail=exact, emitter_sampling=False, **kw)
    np.testing.assert_allclose(r.irradiance, expect, rtol=1e-6)
    assert np.all(r.stderr < 1e-5 * expect) and r.stats["rr_kills"] > 0
    plain = indirect_irradiance(s, BOX_POINTS, BOX_NORMALS, emitter_sampling=False, **kw)
    assert np.all(plain.stderr > 0.01 * expect)
    rng = np.random.default_rng(1)
    for nee in (False, True):
        for tail in (3 * exact, 0.2 * exact, exact * rng.uniform(0, 3, (4, 1))):
            r = indirect_irradiance(s, BOX_POINTS, BOX_NORMALS, tail=tail, emitter_sampling=nee, **kw)
            assert np.all(np.abs(r.irradiance - expect) < 5 * r.stderr + 1e-6), (nee, tail[:, 0], r.irradiance)
    # sharper: 2000 estimates of 16 paths with a guess 3x too high, their mean within 4 standard errors of it
    many = indirect_irradiance(s, np.tile(BOX_POINTS[:1], (2000, 1)), np.tile(BOX_NORMALS[:1], (2000, 1)),
                               tail=np.full((2000, 3), 3 * le / (1 - a)), emitter_sampling=False,
                               **{**kw, "spp": 16})
    e = many.irradiance[:, 0].astype(np.float64)
    assert abs(e.mean() - expect) < 4 * e.std() / math.sqrt(e.size) and e.std() > 0.01 * expect
    with pytest.raises(ValueError, match="tail"):
        indirect_irradiance(s, BOX_POINTS, BOX_NORMALS, tail=np.zeros((3, 3)))


def test_open_furnace_sky(scene_files):
    """Open space under a uniform sky L: E_indirect = π·L for any normal, any bounce count."""
    from workers.gltf import ingest_file

    s = ingest_file(scene_files["furnace"])
    sky = np.array([0.2, 0.5, 1.0])
    dirs = np.array([[0, 1, 0], [0, -1, 0], [1, 0, 0], [0.3, 0.4, -0.866]], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = np.zeros((4, 3))
    for bounces in (1, 3):
        r = indirect_irradiance(s, pts, dirs, sky=sky, spp=64, bounces=bounces, seed=0)
        np.testing.assert_allclose(r.irradiance, np.tile(math.pi * sky, (4, 1)), rtol=1e-6)


def test_half_space_floor_under_sky():
    """An (effectively) infinite floor of albedo a under sky L: the floor's radiance is a·L, so at a
    point above it E = π·L facing up, π·a·L facing down and π·L·(1 + a)/2 facing sideways."""
    a, L, R = 0.6, 1.0, 1e4
    floor = [[[-R, 0, -R], [-R, 0, R], [R, 0, R]], [[-R, 0, -R], [R, 0, R], [R, 0, -R]]]
    s = _scene(floor, [_material(a)])
    pts = np.array([[0, 1, 0]] * 3 + [[3, 0.5, -2]], float)
    nrm = np.array([[0, 1, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1]], float)
    kw = dict(sky=(L, L, L), seed=5, eps=1e-4)   # the default offset, 1e-4 x the 28 km diagonal, is too coarse
    r = indirect_irradiance(s, pts, nrm, spp=8192, bounces=2, **kw)
    expect = math.pi * L * np.array([1.0, a, (1 + a) / 2, (1 + a) / 2])
    np.testing.assert_allclose(r.irradiance[:, 1], expect, rtol=0.02)
    side = r.stderr[2:, 1]
    assert np.all(side > 0) and np.all(side < 0.01 * expect[2:])     # σ/√n ≈ π(1-a)/2/√8192
    # one bounce: the floor is not lit yet (its radiance would need a second vertex)
    r1 = indirect_irradiance(s, pts[:2], nrm[:2], spp=256, bounces=1, **kw)
    np.testing.assert_allclose(r1.irradiance[:, 1], [math.pi * L, 0.0], atol=1e-6)


@pytest.mark.parametrize("half_width", [0.4, 1.0, 5.0])
def test_square_emitter_closed_form(half_width):
    """Irradiance under the centre of a square emitter of half-width w at distance 1, facing it:
    E = 4·Le·w/√(1+w²)·atan(w/√(1+w²)) (the form factor of a square to a parallel differential area).
    Emitter sampling with MIS and cosine sampling alone agree with it."""
    w, le = half_width, 2.0
    quad = [[[-w, -w, 0], [w, -w, 0], [w, w, 0]], [[-w, -w, 0], [w, w, 0], [-w, w, 0]]]  # faces +z
    s = _scene(quad, [_material(0.5, le)])
    k = w / math.sqrt(1 + w * w)
    expect = 4 * le * k * math.atan(k)
    for nee in (True, False):
        r = indirect_irradiance(s, np.array([[0, 0, 1.0]]), np.array([[0, 0, -1.0]]), spp=8192, bounces=1,
                                seed=2, emitter_sampling=nee)
        assert abs(r.irradiance[0, 0] - expect) < max(4 * r.stderr[0, 0], 1e-4 * expect), (nee, r.irradiance, expect)
        assert abs(r.irradiance[0, 0] - expect) < 0.03 * expect


@pytest.mark.parametrize("nee", [False, True])
def test_stratified_estimates_and_their_standard_errors_are_unbiased(nee):
    """Stratified first directions (module doc): 4000 points at the same place under a square emitter (half-width
    0.4 at distance 1; closed form above), each an independent estimate of 32 paths in G = 8 replicates. The mean of
    the estimates is the closed form; the mean of the squared standard errors equals the variance of the
    estimates across points (the standard errors are unbiased, within ~4% sampling noise); stratification cuts
    that variance well below plain paths (G = 32: one path per replicate is an independent uniform direction,
    whose sample standard error is the textbook one); and G = 1 (one net of 32, the paths' sample variance)
    overstates the error of a stratified estimate."""
    w, le, n_pts, spp = 0.4, 2.0, 4000, 32
    quad = [[[-w, -w, 0], [w, -w, 0], [w, w, 0]], [[-w, -w, 0], [w, w, 0], [-w, w, 0]]]
    s = _scene(quad, [_material(0.5, le)])
    k = w / math.sqrt(1 + w * w)
    expect = 4 * le * k * math.atan(k)
    pts, nrm = np.tile([0, 0, 1.0], (n_pts, 1)), np.tile([0, 0, -1.0], (n_pts, 1))
    out = {}
    for G in (8, 32, 1):
        r = indirect_irradiance(s, pts, nrm, spp=spp, bounces=1, seed=4, emitter_sampling=nee, replicates=G)
        e, err = r.irradiance[:, 0].astype(np.float64), r.stderr[:, 0].astype(np.float64)
        out[G] = (e.var(ddof=1), float(np.mean(err ** 2)))
        assert abs(e.mean() - expect) < 4 * math.sqrt(out[G][0] / n_pts), (G, e.mean(), expect)
        assert r.stats["replicates"] == G
    var8, s2_8 = out[8]
    assert abs(s2_8 / var8 - 1) < 0.12, out
    assert abs(out[32][1] / out[32][0] - 1) < 0.12, out
    assert var8 < 0.7 * out[32][0], out                  # stratified vs plain paths
    assert out[1][1] > 1.5 * out[1][0], out              # a net's sample variance overstates its error


def test_single_sided_back_faces_carry_nothing():
    """An emitting quad seen from behind: 0 when single-sided (as probe rays see it), Le when double-sided."""
    quad = [[[-50, -50, 0], [50, -50, 0], [50, 50, 0]], [[-50, -50, 0], [50, 50, 0], [-50, 50, 0]]]  # faces +z
    pts = np.array([[0, 0, 1.0], [0, 0, -1.0]])
    nrm = np.array([[0, 0, -1.0], [0, 0, 1.0]])   # looking at the front, looking at the back
    for nee in (False, True):
        single = indirect_irradiance(_scene(quad, [_material(0.5, 2.0)]), pts, nrm, spp=256, bounces=2, seed=1,
                                     emitter_sampling=nee)
        both = indirect_irradiance(_scene(quad, [_material(0.5, 2.0, double_sided=True)]), pts, nrm, spp=256,
                                   bounces=2, seed=1, emitter_sampling=nee)
        np.testing.assert_allclose(single.irradiance[0], math.pi * 2.0, rtol=0.01)
        np.testing.assert_allclose(single.irradiance[1], 0.0, atol=1e-9)
        np.testing.assert_allclose(both.irradiance[1], math.pi * 2.0, rtol=0.01)


def test_deterministic_and_independent_of_chunking():
    s = closed_box(0.7, 0.3)
    pts = np.array([[0.5, 0.0, 0.5], [0.1, 0.2, 0.0], [0.5, 0.5, 1.0]])
    nrm = np.array([[0, 1, 0], [0, 0, 1], [0, 0, -1]], float)
    kw = dict(spp=64, bounces=6, rr_depth=2)
    a = indirect_irradiance(s, pts, nrm, seed=11, **kw)
    b = indirect_irradiance(s, pts, nrm, seed=11, max_paths=64, **kw)   # one point per chunk
    c = indirect_irradiance(s, pts, nrm, seed=12, **kw)
    np.testing.assert_array_equal(a.irradiance, b.irradiance)
    assert not np.array_equal(a.irradiance, c.irradiance)
    # a point's estimate depends on its index and the seed only, not on the other points
    e = indirect_irradiance(s, pts[:2], nrm[:2], seed=11, **kw)
    np.testing.assert_array_equal(e.irradiance, a.irradiance[:2])


def test_validation():
    s = closed_box(0.5, 0.0)
    with pytest.raises(ValueError):
        indirect_irradiance(s, np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        indirect_irradiance(s, np.zeros((1, 3)), np.array([[0, 1.0, 0]]), spp=0)
    with pytest.raises(ValueError):
        indirect_irradiance(s, np.full((1, 3), np.nan), np.array([[0, 1.0, 0]]))
    r = indirect_irradiance(s, np.zeros((1, 3)), np.zeros((1, 3)))   # zero normal: nothing arrives
    assert np.all(r.irradiance == 0)


# ----------------------------------------------------------------------------------- shadows
def test_sealed_box_cavity_gets_no_light(scene_files):
    """sealed-box: the sun, the lamp and the sky cannot reach the cavity; the slab outside is lit."""
    from workers.gltf import ingest_file

    s = ingest_file(scene_files["sealed-box"])
    caster = RayCaster(s.triangles)
    eps = scene_eps(s)
    g = np.linspace(-0.4, 0.4, 5)
    inside = np.array([[x, 0.05, z] for x in g for z in g])            # the cavity floor, facing up
    outside = np.array([[x, 0.0, z] for x in (-3.0, 2.0, 4.0) for z in (-3.0, 1.5, 4.0)])  # the slab
    up = np.tile([0.0, 1.0, 0.0], (len(inside), 1))
    e_in = direct_irradiance(inside + eps * up, up, s.lights, caster, eps)
    assert np.all(e_in == 0)
    e_out = direct_irradiance(outside + eps * up[:9], up[:9], s.lights, caster, eps)
    assert np.all(e_out.sum(axis=1) > 0)
    r = indirect_irradiance(s, inside, up, s.lights, sky=(1, 1, 1), spp=32, bounces=3, seed=0, caster=caster)
    assert np.all(r.irradiance == 0)
    r_out = indirect_irradiance(s, outside, up[:9], s.lights, sky=(1, 1, 1), spp=32, bounces=3, seed=0,
                                caster=caster)
    assert np.all(r_out.irradiance > 1.0)   # mostly open sky: close to π


def _vinc3r_zip(tmp_path):
    d = shared_path("scenes", "cornell-box-vinc3r")
    z = tmp_path / "vinc3r.zip"
    with zipfile.ZipFile(z, "w") as f:
        for name in ("cornellBox-2.80-Eevee-gltf.gltf", "cornellBox-2.80-Eevee-gltf.bin", "checkerBJS.png",
                     "checker-meter.png"):
            f.write(d / name, name)
    return d, z


@pytest.mark.slow
def test_cycles_lightmaps_correlate(tmp_path):
    """Outside check against the Cycles-baked lightmaps of the vinc3r Cornell box.

    The maps (lightmaps-cycles-reference/<node>.LM.png, one per node, in its TEXCOORD_1 space) hold light
    only — the red and green walls show up as bleeding on the white ones, not in their own colour — so
    they are compared with irradiance (no albedo). Exposure is unknown: one gain per map (least squares
    through 0, on sRGB-decoded texels, saturated ones left out), then the Pearson correlation. The scene has
    no punctual lights; the emissive lamp panel lights it. Measured (256 spp, all maps): r ≈ 0.80.
    """
    from PIL import Image

    from workers.gltf import ingest_file

    d, z = _vinc3r_zip(tmp_path)
    s = ingest_file(z)
    tc = s.texcoord1() if hasattr(s, "texcoord1") else ((s.uv1, np.zeros(s.n_triangles, np.int32))
                                                         if s.uv1 is not None else None)
    if tc is None:
        pytest.skip("the normalized scene has no TEXCOORD_1 (ingest keeps uv1 only when every primitive has it)")
    uv, chart = tc
    gltf = json.loads((d / "cornellBox-2.80-Eevee-gltf.gltf").read_text())
    caster = RayCaster(s.triangles)
    xs, ys, per_map = [], [], {}
    for node, step in ((0, 3), (1, 3), (3, 8)):
        name = gltf["nodes"][node]["name"]
        img = np.asarray(Image.open(d / "lightmaps-cycles-reference" / f"{name}.LM.png").convert("RGB"))
        ids = np.flatnonzero(chart == node)
        assert ids.size, f"no triangle in node {node}'s UV1 chart"
        tx = texel_surfaces(uv[ids], img.shape[1], img.shape[0], triangle_ids=ids)
        sel = np.flatnonzero((tx["rows"] % step == 0) & (tx["cols"] % step == 0))
        sa = surface_at_hits(s, tx["tri"][sel], tx["u"][sel], tx["v"][sel])
        n = sa["normal"].astype(np.float64)
        ng = sa["geo_normal"].astype(np.float64)
        ng = np.where((np.einsum("ij,ij->i", ng, n) < 0)[:, None], -ng, ng)
        r = indirect_irradiance(s, sa["position"], n, s.lights, spp=128, bounces=5, seed=1, caster=caster,
                                geo_normals=ng)
        e = r.irradiance.astype(np.float64)
        lm8 = img[tx["rows"][sel], tx["cols"][sel]]
        ok = np.all(lm8 < 255, axis=1)
        x, y = e[ok].ravel(), SRGB_TO_LINEAR_LUT[lm8[ok]].ravel()
        gain = float(x @ y / (x @ x))
        per_map[name] = (float(np.corrcoef(x, y)[0, 1]), gain, int(ok.sum()))
        xs.append(x * gain)
        ys.append(y)
    r_all = float(np.corrcoef(np.concatenate(xs), np.concatenate(ys))[0, 1])
    print("Cycles lightmap correlation (r, gain, texels):", per_map, "all:", round(r_all, 3))
    assert r_all > 0.6, per_map
    gains = [g for _, g, _ in per_map.values()]
    assert max(gains) < 1.6 * min(gains), per_map   # one exposure explains all three maps


def _cosine_grid(n, nr=64, nphi=128):
    """Midpoint cells of equal probability of the cosine lobe about unit n: (nr·nphi, 3) directions."""
    from workers.kernels.path_rng import _cosine_dir
    u1 = (np.arange(nr) + 0.5) / nr
    u2 = (np.arange(nphi) + 0.5) / nphi
    return np.array([_cosine_dir(n[0], n[1], n[2], a, b)[:3] for a in u1 for b in u2])


def _bent_floor(a, tilt):
    """An infinite floor (albedo a, geometric normal +y) whose vertex normals all lean tilt° toward +x."""
    R = 1e4
    floor = [[[-R, 0, -R], [-R, 0, R], [R, 0, R]], [[-R, 0, -R], [R, 0, R], [R, 0, -R]]]
    s = _scene(floor, [_material(a)])
    t = math.radians(tilt)
    s.normals[:] = np.array([math.sin(t), math.cos(t), 0.0], np.float32)
    return s, s.normals[0, 0].astype(np.float64)


def _cycles_frames(views, nb):
    """Cycles 3.4's closure normal N' and bent flag at the floor for arriving views I (rows), smooth normal nb."""
    from workers.kernels.shading import ensure_valid_reflection
    m = len(views)
    ng = np.tile([0.0, 1.0, 0.0], (m, 1))
    n_c, bent = ensure_valid_reflection(ng, views, np.tile(nb, (m, 1)))
    return ng, n_c, bent


@pytest.mark.parametrize("tilt", [50.0, 25.0])
def test_bent_shading_normals_under_a_sky_match_cycles(tilt):
    """The bent floor (:func:`_bent_floor`) under a sky L, seen from points above it facing +x, 2 vertices. Cycles 3.4
    shades each floor hit with N' = ensure_valid_reflection(Ng, I, N) for the arriving direction I, samples cosine
    about N', drops directions below the floor, and on bent hits multiplies by the bump shadowing term: the floor's
    radiance toward I is a·L·h(I), h the horizon factor (:func:`shading.horizon_factor`), so
    E/π = P(up)·L + a·L·E[h(I); down] over the query's cosine lobe. The rays toward +x reach the floor from the side
    away from the lean, where Cycles bends N. Sampling about the raw N (the old tracer) gives h = (1 + N·Ng)/2:
    1.4% higher at 50°, 0.7% at 25°."""
    from workers.kernels.shading import horizon_factor
    a, L = 0.5, 1.0
    s, nb = _bent_floor(a, tilt)
    pts = np.array([[0, 1, 0], [3, 0.5, -2], [-40, 2, 7], [5, 0.3, 5], [1, 1, 1], [-2, 0.7, 3], [9, 1.5, -4],
                    [0, 0.2, 0]], float)
    nrm = np.tile([1.0, 0.0, 0.0], (len(pts), 1))
    r = indirect_irradiance(s, pts, nrm, sky=(L, L, L), spp=32768, bounces=2, seed=3, eps=1e-4)
    d = _cosine_grid(np.array([1.0, 0.0, 0.0]))
    down = d[:, 1] < 0
    ng, n_c, bent = _cycles_frames(-d[down], nb)
    h = horizon_factor(n_c, ng, np.tile(nb, (len(ng), 1)), bent)
    expect = math.pi * L * (np.sum(~down) + a * h.sum()) / len(d)
    old = math.pi * L * (np.sum(~down) + a * len(h) * (1 + nb[1]) / 2) / len(d)
    assert bent.mean() > 0.7 and expect < old * (1 - 0.006)
    est = r.irradiance[:, 1].astype(np.float64).mean()
    err = math.sqrt(np.sum(r.stderr[:, 1].astype(np.float64) ** 2)) / len(pts)
    assert abs(est - expect) < 4 * err + 0.001 * expect, (est, err, expect, old)
    assert err < 0.0015 * expect
    assert r.stats["bent_vertices"] > 0


@pytest.mark.parametrize("tilt", [54.7, 40.0])
def test_bent_shading_normals_under_a_directional_light_match_cycles(tilt):
    """The bent floor (:func:`_bent_floor`) lit by a directional light of S lux from 20° above the horizon on the side
    of the lean (+x), seen from points above it facing down, one vertex. The floor's radiance toward I is
    a/π · S · max(0, N'·l) · [Ng·l > 0] · (bump shadowing term where bent) (Cycles 3.4 bsdf_eval), so
    E = a·S·E_I[max(0, N'·l)·S(I)], I cosine-distributed about +y. The old tracer's max(0, N·l) reads high where N'
    leans less than N: 14% at 54.7° (a cube corner's averaged normal), 8% at 40°."""
    from workers.kernels.shading import bump_shadowing_term
    a, S = 0.5, 3.0
    s, nb = _bent_floor(a, tilt)
    e = math.radians(20)
    l = np.array([math.cos(e), math.sin(e), 0.0])
    sun = {"type": "directional", "color": [1.0, 1.0, 1.0], "intensity": S, "direction": list(-l), "range": None,
           "position": None, "inner_cone_angle": None, "outer_cone_angle": None, "name": "sun"}
    pts = np.array([[0, 1, 0], [3, 0.5, -2], [-40, 2, 7], [5, 0.3, 5]], float)
    nrm = np.tile([0.0, -1.0, 0.0], (len(pts), 1))
    r = indirect_irradiance(s, pts, nrm, [sun], spp=8192, bounces=1, seed=4, eps=1e-4)
    views = _cosine_grid(np.array([0.0, 1.0, 0.0]))
    ng, n_c, bent = _cycles_frames(views, nb)
    ll = np.tile(l, (len(views), 1))
    f = np.maximum(n_c @ l, 0) * np.where(bent, bump_shadowing_term(np.tile(nb, (len(views), 1)), n_c, ll), 1.0)
    expect = a * S * f.mean()
    old = a * S * max(nb @ l, 0.0)
    assert bent.any() and expect < 0.95 * old
    est = r.irradiance[:, 1].astype(np.float64).mean()
    err = math.sqrt(np.sum(r.stderr[:, 1].astype(np.float64) ** 2)) / len(pts)
    assert abs(est - expect) < 4 * err + 0.002 * expect, (est, err, expect, old)
