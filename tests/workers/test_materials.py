"""Materials as glTF defines them, at ingest and at every ray hit: COLOR_0, metallic-roughness, the default
material, alpha cutouts; the light stage's convergence and its warnings. Closed forms through the real
pipeline (Embree rays, the light stage's bounce iteration)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tests.gltf_build import GltfBuilder, box_inward, quad
from tests.workers.test_light import probe_irradiance
from tests.workers.test_probes import bake_until
from workers.gltf import ingest_file
from workers.kernels.materials import albedo_warnings, gi_albedo, opaque_at_hits, surface_materials
from workers.kernels.shading import direct_irradiance
from workers.raycast import CutoutRayCaster, caster_for_scene

BOX = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])
INNER = {"min": [-0.5, -0.5, -0.5], "max": [0.5, 0.5, 0.5]}


def _write(tmp_path, b: GltfBuilder, name="scene.glb"):
    tmp_path.mkdir(parents=True, exist_ok=True)
    p = tmp_path / name
    p.write_bytes(b.glb())
    return p


def emissive_enclosure(tmp_path, *, colors=None, normalized=False, **material):
    """A closed box whose inner walls all emit Le = 1 with the given material and COLOR_0."""
    b = GltfBuilder()
    pos, nrm, idx = box_inward(*BOX)
    m = b.material(emissiveFactor=[1.0, 1.0, 1.0], **material)
    col = None if colors is None else np.repeat(np.asarray(colors)[None], len(pos), axis=0)
    b.mesh(pos, idx, normals=nrm, material=m, colors=col, color_normalized=normalized)
    return _write(tmp_path, b)


def enclosure_irradiance(tmp_path, path, extra=None):
    cfg = {"place": {"counts": [2, 2, 2], "box": INNER}, "trace": {"rays_per_probe": 128}, **(extra or {})}
    _, s = bake_until(tmp_path, path, cfg, "light")
    return probe_irradiance(s, [2, 2, 2]), s["light"].stats


@pytest.mark.parametrize("colors, normalized, a", [
    ([0.5, 0.5, 0.5], False, 0.5),                                   # float VEC3
    (np.array([153, 153, 153, 255], np.uint8), True, 0.6),          # normalized ubyte RGBA (153/255 = 0.6)
    (np.array([45875, 45875, 45875], np.uint16), True, 45875 / 65535),  # normalized ushort
])
def test_color0_albedo_enclosure_converges_to_the_geometric_series(tmp_path, colors, normalized, a):
    # white base colour, metallic 0: the albedo is COLOR_0 alone. Every wall emits Le = 1 and reflects a:
    # L = Le / (1 - a) everywhere, E = π L (a reader ignoring COLOR_0 gets albedo 1 and no convergence)
    path = emissive_enclosure(tmp_path, colors=colors, normalized=normalized,
                              pbrMetallicRoughness={"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0})
    e, st = enclosure_irradiance(tmp_path, path)
    assert st["converged"] and st["residual"] < 0.005
    assert np.allclose(e, math.pi / (1.0 - a), rtol=0.01), (e.mean(), math.pi / (1 - a))
    assert "warnings" not in st


def test_metallic_wall_reflects_no_diffuse_light(tmp_path):
    # a mirror-smooth metal (metallic 1, roughness 0) has diffuse albedo 0 and no specular GI term: E = π Le
    path = emissive_enclosure(tmp_path, pbrMetallicRoughness={"baseColorFactor": [0.9, 0.9, 0.9, 1],
                                                              "metallicFactor": 1.0, "roughnessFactor": 0.0})
    e, st = enclosure_irradiance(tmp_path, path)
    assert np.allclose(e, math.pi, rtol=0.005)


def test_rough_metal_gi_albedo_follows_the_meta_pass(tmp_path):
    # metallic 1, roughness 1, base 0.8: albedo 0.8 x 1^2 / 2 = 0.4 -> E = π / 0.6; with specular_gi none: π
    mat = {"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1], "metallicFactor": 1.0,
                                    "roughnessFactor": 1.0}}
    path = emissive_enclosure(tmp_path, **mat)
    e, _ = enclosure_irradiance(tmp_path / "metals", path)
    assert np.allclose(e, math.pi / 0.6, rtol=0.01)
    e_none, _ = enclosure_irradiance(tmp_path / "none", path, {"scene": {"specular_gi": "none"}})
    assert np.allclose(e_none, math.pi, rtol=0.005)


def test_gi_albedo_formulas():
    base = np.array([[0.8, 0.5, 0.2]])
    # glTF Appendix B diffuse + Unity's meta pass on the metallic lobe
    assert np.allclose(gi_albedo(base, [0.0], [1.0]), base)
    assert np.allclose(gi_albedo(base, [1.0], [0.0]), 0.0)
    assert np.allclose(gi_albedo(base, [0.5], [0.6]), base * 0.5 + base * 0.5 * 0.36 / 2)
    assert np.allclose(gi_albedo(base, [0.0], [1.0], "all"), base + 0.04 / 2)
    assert np.allclose(gi_albedo(base, [1.0], [1.0], "none"), 0.0)


def test_default_material_and_metallic_roughness_texture(tmp_path):
    b = GltfBuilder()
    p, n, uv, idx = quad([0, 0, 0], [1, 0, 0], [0, 0, -1], [0, 1, 0])
    b.mesh(p, idx, normals=n, uv=uv)                                   # no material: glTF's default
    mr = np.zeros((2, 2, 4), np.uint8)
    mr[..., 1] = 255                                                   # G = roughness 1
    mr[:, 0, 2], mr[:, 1, 2] = 0, 255                                  # B = metallic: left 0, right 1
    mr[..., 3] = 255
    tex = b.image(mr)
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.6, 0.6, 0.6, 1], "metallicFactor": 1.0,
                                         "roughnessFactor": 1.0, "metallicRoughnessTexture": {"index": tex}})
    b.mesh(p + np.float32([0, 1, 0]), idx, normals=n, uv=uv, material=m)
    scene = ingest_file(_write(tmp_path, b))
    assert any("default material" in w for w in scene.warnings)
    dm = scene.materials[scene.material[0]]
    assert dm["metallic"] == 1.0 and dm["roughness"] == 1.0
    # the default material: a rough white metal -> GI albedo 1 x 1 x 1/2
    s = surface_materials(scene, np.array([0]), np.array([0.2]), np.array([0.2]))
    assert np.allclose(s["albedo"], 0.5)
    # texel centres u = 0.25 (metallic 0: albedo 0.6) and u = 0.75 (metallic 1: 0.6 x 1/2), linear texture
    t = np.flatnonzero(scene.material == m)
    hits_t, hits_u, hits_v = [], [], []
    for want_u in (0.25, 0.75):
        for k in t:      # find barycentrics of the point with uv = (want_u, 0.5) on one of the two triangles
            tuv = scene.uv0[k].astype(np.float64)
            A = np.array([tuv[1] - tuv[0], tuv[2] - tuv[0]]).T
            bu, bv = np.linalg.solve(A, np.array([want_u, 0.5]) - tuv[0])
            if bu >= 0 and bv >= 0 and bu + bv <= 1:
                hits_t.append(k)
                hits_u.append(bu)
                hits_v.append(bv)
                break
    s = surface_materials(scene, np.array(hits_t), np.array(hits_u), np.array(hits_v))
    assert np.allclose(s["albedo"][0], 0.6, atol=1e-6)
    assert np.allclose(s["albedo"][1], 0.3, atol=1e-6)


def _screen_scene(tmp_path, alpha_mode="MASK", holes=0.25, vertex_alpha=None):
    """A 2x2 m screen at y = 1 with an alpha texture whose holes cover ``holes`` of it, over a floor."""
    b = GltfBuilder()
    n = 8
    a = np.full((n, n, 4), 255, np.uint8)
    k = int(round(n * math.sqrt(holes)))
    a[:k, :k, 3] = 0                                                    # one square hole block per tile
    tex = b.image(a)
    m = b.material(alphaMode=alpha_mode, alphaCutoff=0.5, doubleSided=True,
                   pbrMetallicRoughness={"baseColorTexture": {"index": tex}, "metallicFactor": 0.0})
    p, nr, uv, idx = quad([-1, 1, 1], [2, 0, 0], [0, 0, -2], [0, -1, 0])
    col = None if vertex_alpha is None else np.tile(np.float32([1, 1, 1, vertex_alpha]), (4, 1))
    b.mesh(p, idx, normals=nr, uv=uv * 4, material=m, colors=col)     # 4x4 tiles of the texture
    floor = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    p, nr, uv, idx = quad([-3, 0, 3], [6, 0, 0], [0, 0, -6], [0, 1, 0])
    b.mesh(p, idx, normals=nr, material=floor)
    return ingest_file(_write(tmp_path, b))


def test_mask_screen_passes_the_holes_fraction(tmp_path):
    scene = _screen_scene(tmp_path, holes=0.25)
    caster = caster_for_scene(scene)
    assert isinstance(caster, CutoutRayCaster)
    rng = np.random.default_rng(0)
    o = np.c_[rng.uniform(-0.99, 0.99, 40000), np.full(40000, 2.0), rng.uniform(-0.99, 0.99, 40000)]
    d = np.tile([0.0, -1.0, 0.0], (40000, 1))
    h = caster.intersect(o, d)
    through = np.isclose(h.t, 2.0, atol=1e-3)                          # hit the floor at y = 0
    on_screen = np.isclose(h.t, 1.0, atol=1e-3)
    assert np.all(through | on_screen)
    assert abs(through.mean() - 0.25) < 0.02, through.mean()
    occ = caster.occluded(o, d, tfar=1.5)                             # shadow rays that stop above the floor
    assert np.array_equal(occ, on_screen)
    # direct light from a point light above the screen reaches the floor through the holes only
    pts = np.c_[rng.uniform(-0.5, 0.5, 4000), np.zeros(4000), rng.uniform(-0.5, 0.5, 4000)]
    nrm = np.tile([0.0, 1.0, 0.0], (4000, 1))
    light = [{"type": "point", "position": [0.0, 50.0, 0.0], "intensity": 2500.0, "color": [1, 1, 1]}]
    e = direct_irradiance(pts, nrm, light, caster, 1e-4)[:, 0]
    assert abs((e > 0).mean() - 0.25) < 0.03
    # the same screen as OPAQUE blocks everything; COLOR_0 alpha 0 opens it entirely
    opaque = caster_for_scene(_screen_scene(tmp_path / "o", alpha_mode="OPAQUE"))
    assert opaque.occluded(o, d, tfar=1.5).all()
    open_ = _screen_scene(tmp_path / "v", vertex_alpha=0.0)
    assert not caster_for_scene(open_).occluded(o, d, tfar=1.5).any()


def test_blend_is_a_cutout_with_a_warning(tmp_path):
    scene = _screen_scene(tmp_path, alpha_mode="BLEND", holes=0.25)
    assert any("BLEND" in w and "cutout" in w for w in scene.warnings)
    t = np.flatnonzero(scene.material == 0)
    ok = opaque_at_hits(scene, t, np.full(t.size, 0.01), np.full(t.size, 0.01))
    assert ok.dtype == bool and ok.shape == t.shape


def test_mask_cutout_lets_light_into_the_probe_bake(tmp_path):
    # a sealed box whose top is a cutout screen with holes: light from above reaches the probes inside;
    # the same box with an opaque top stays dark
    def scene(mode):
        b = GltfBuilder()
        pos, nrm, idx = box_inward([-1, 0, -1], [1, 2, 1])
        keep = np.array([not np.allclose(pos[i[0]][1], 2.0) or not np.allclose(pos[i[1]][1], 2.0)
                         or not np.allclose(pos[i[2]][1], 2.0) for i in idx])
        wall = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
        b.mesh(pos, idx[keep], normals=nrm, material=wall)
        a = np.full((4, 4, 4), 255, np.uint8)
        a[:2, :2, 3] = 0
        tex = b.image(a)
        top = b.material(alphaMode=mode, doubleSided=True,
                         pbrMetallicRoughness={"baseColorTexture": {"index": tex}, "metallicFactor": 0.0})
        p, nr, uv, ix = quad([-1, 2, 1], [2, 0, 0], [0, 0, -2], [0, -1, 0])
        b.mesh(p, ix, normals=nr, uv=uv * 3, material=top)
        b.point_light([0.0, 6.0, 0.0], 200.0)
        return _write(tmp_path, b, f"{mode}.glb")

    cfg = {"place": {"counts": [2, 2, 2], "box": {"min": [-0.5, 0.4, -0.5], "max": [0.5, 1.4, 0.5]}},
           "trace": {"rays_per_probe": 256}}
    _, cut = bake_until(tmp_path / "m", scene("MASK"), cfg, "light")
    _, solid = bake_until(tmp_path / "s", scene("OPAQUE"), cfg, "light")
    e_cut, e_solid = probe_irradiance(cut, [2, 2, 2]), probe_irradiance(solid, [2, 2, 2])
    assert e_cut.mean() > 0.05
    assert e_solid.max() < 1e-6


def test_not_converged_and_albedo_warnings(tmp_path):
    # albedo 0.97 in a closed emissive room: the series converges slowly (r = 0.97); 4 bounces are short
    path = emissive_enclosure(tmp_path, pbrMetallicRoughness={"baseColorFactor": [0.97, 0.97, 0.97, 1],
                                                              "metallicFactor": 0.0})
    e, st = enclosure_irradiance(tmp_path / "short", path, {"light": {"max_bounces": 4}})
    codes = [w["code"] for w in st["warnings"]]
    assert codes == ["albedo_high", "not_converged"], st["warnings"]
    assert not st["converged"] and st["residual"] > 0.5
    # the residual is the light still to come (a tail that large is not added): E_4 + tail ≈ E_∞ = π / (1 - 0.97)
    assert e.mean() < 0.2 * math.pi / 0.03
    # clamped to 0.9: converges (E = π / 0.1) and says it clamped
    e, st = enclosure_irradiance(tmp_path / "clamp", path, {"scene": {"max_albedo": 0.9}})
    assert st["converged"]
    assert [w["code"] for w in st["warnings"]] == ["albedo_clamped"]
    assert np.allclose(e, math.pi / 0.1, rtol=0.01)


def test_albedo_warnings_read_textures_and_vertex_colours(tmp_path):
    b = GltfBuilder()
    p, n, uv, idx = quad([0, 0, 0], [1, 0, 0], [0, 0, -1], [0, 1, 0])
    m = b.material(name="bright", pbrMetallicRoughness={"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0})
    b.mesh(p, idx, normals=n, material=m, colors=np.tile(np.float32([0.5, 0.5, 0.5]), (4, 1)))
    scene = ingest_file(_write(tmp_path, b))
    assert albedo_warnings(scene, None) == []              # COLOR_0 0.5 x white: 0.5, fine
    scene.colors[:] = 1.0
    assert albedo_warnings(scene, None)[0]["code"] == "albedo_high"


def test_no_light_through_a_thin_wall_at_coarse_spacing(tmp_path):
    """Two sealed rooms sharing a 5 cm wall, probes 1 m apart straddling it: the bounce re-shading must carry no
    light into the dark room (closed form: no path from the light reaches it)."""
    b = GltfBuilder()
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.6, 0.6, 0.6, 1], "metallicFactor": 0.0})
    for lo, hi in (([0, 0, 0], [3.0, 2.5, 3.0]), ([3.05, 0, 0], [6.05, 2.5, 3.0])):
        pos, nrm, idx = box_inward(lo, hi)
        b.mesh(pos, idx, normals=nrm, material=m)
    outer_lo, outer_hi = np.array([-0.05, -0.05, -0.05]), np.array([6.1, 2.55, 3.05])
    pos, nrm, idx = box_inward(outer_lo, outer_hi)
    b.mesh(pos, idx[:, ::-1], normals=-nrm, material=m)                   # the shell, facing outward
    b.point_light([1.5, 2.0, 1.5], 100.0)
    path = _write(tmp_path, b)
    cfg = {"place": {"spacing": 1.0, "box": {"min": [0.2, 0.3, 0.3], "max": [5.9, 2.2, 2.7]}},
           "trace": {"rays_per_probe": 256}}
    _, s = bake_until(tmp_path, path, cfg, "light")
    counts = s["place"].stats["counts"]
    e = probe_irradiance(s, counts)
    pos = np.asarray(s["relocate"]["probe_positions_relocated"]).reshape(-1, 3)
    states = np.asarray(s["trace"]["probe_states"]).ravel()
    in_a = (pos[:, 0] < 2.95) & (states != 0)
    in_b = (pos[:, 0] > 3.1) & (states != 0)
    assert in_a.sum() >= 4 and in_b.sum() >= 4
    assert e[in_a].mean() > 1.0
    assert e[in_b].max() < 1e-6 * e[in_a].mean(), (e[in_b].max(), e[in_a].mean())
