"""G-buffer rasterization (workers/render) against Embree ray casts, known scenes and closed forms."""
from __future__ import annotations

import zipfile

import numpy as np
import pytest

from tests.conftest import shared_path
from workers.gltf import ingest_file
from workers.kernels.reference import reference_at_gbuffer
from workers.kernels.shading import surface_at_hits
from workers.raycast import RayCaster
from workers.render.cameras import Camera, auto_cameras, default_camera, fit_clip_planes


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    from workers.procedural import write_scene

    d = tmp_path_factory.mktemp("gb")
    out = {}
    for name in ("cornell", "two-rooms", "sealed-box", "furnace"):
        write_scene(name, d / f"{name}.glb")
        out[name] = ingest_file(d / f"{name}.glb")
    return out


def _render(ctx, scene, camera, **kw):
    from workers.render.gbuffer import GBufferRenderer

    with GBufferRenderer(scene, ctx, caster=RayCaster(scene.triangles), **kw) as r:
        return r.render(camera)


def _compare_with_embree(scene, g):
    """Fractions of pixels where coverage agrees, and of covered pixels whose position matches the Embree hit."""
    caster = RayCaster(scene.triangles)
    o, d = g.camera.pixel_rays()
    h = caster.intersect(o, d)
    hit = h.hit.reshape(g.shape)
    size = float(np.linalg.norm(scene.bounds[1] - scene.bounds[0]))
    both = hit & g.mask
    err = np.linalg.norm(h.points(o, d).reshape(g.position.shape)[both] - g.position[both], axis=-1)
    return float((hit == g.mask).mean()), float((err <= 1e-3 * size).mean()), h


# ----------------------------------------------------------------------------------- cameras
def test_camera_matrices_and_pixel_rays():
    cam = fit_clip_planes(Camera((1.0, 2.0, 3.0), (0.0, 0.5, -1.0), fov_y=50, width=64, height=48),
                          bounds=np.array([[-5, -5, -5], [5, 5, 5.0]]))
    V, P = cam.view_matrix(), cam.projection_matrix()
    assert np.allclose(V[:3, :3] @ V[:3, :3].T, np.eye(3))
    assert np.allclose(V @ np.r_[cam.position, 1.0], [0, 0, 0, 1])
    # the target lies on the camera's -Z axis, and projects to the image centre
    t = V @ np.r_[cam.target, 1.0]
    assert t[2] < 0 and np.allclose(t[:2], 0, atol=1e-12)
    # a ray through pixel (row i, col j) projects back to that pixel's centre; row 0 is the top
    d = cam.pixel_directions(np.array([0.5, 30.5]), np.array([0.5, 10.5]))
    for (i, j), dd in zip([(0, 0), (30, 10)], d):
        clip = P @ V @ np.r_[np.asarray(cam.position) + 2.0 * dd, 1.0]
        ndc = clip[:3] / clip[3]
        col = (ndc[0] + 1) / 2 * cam.width - 0.5
        row = (1 - ndc[1]) / 2 * cam.height - 0.5
        assert np.allclose([row, col], [i, j], atol=1e-9)
    assert Camera.from_dict(cam.to_dict()) == cam
    with pytest.raises(ValueError):
        Camera((0, 0, 0), (0, 0, 0))
    # looking straight down still gives an orthonormal frame
    down = Camera((0, 5, 0), (0, 0, 0))
    assert np.allclose(down.basis() @ down.basis().T, np.eye(3))


def test_auto_cameras_in_free_space_looking_at_geometry(scenes):
    for name in ("cornell", "two-rooms"):
        s = scenes[name]
        caster = RayCaster(s.triangles)
        cams = auto_cameras(caster, s.bounds, 3)
        assert len(cams) == 3, name
        assert [c.to_dict() for c in cams] == [c.to_dict() for c in auto_cameras(caster, s.bounds, 3)]  # deterministic
        pos = np.array([c.position for c in cams])
        assert np.all((pos >= s.bounds[0]) & (pos <= s.bounds[1]))
        assert not caster.inside_parity(pos.astype(np.float32)).any()
        assert len({tuple(np.round(p, 6)) for p in pos}) == 3
        for c in cams:
            assert c.score["coverage"] > 0.5 and c.near > 0 and c.far > c.near
    # open space: no candidate sees geometry; the fallback camera looks at the bounds
    f = scenes["furnace"]
    assert auto_cameras(RayCaster(f.triangles), np.array([[-2, -2, -2], [2, 2, 2.0]]), 3) == []
    d = default_camera(f.bounds)
    assert d.near < d.far


# ----------------------------------------------------------------------------------- G-buffer
def test_positions_match_embree_hits(ctx, scenes):
    for name, cams in (("cornell", [Camera((0.5, 0.5, 2.2), (0.5, 0.5, 0.5), fov_y=45)]),
                       ("two-rooms", None), ("sealed-box", None)):
        s = scenes[name]
        caster = RayCaster(s.triangles)
        if cams is None:
            cams = auto_cameras(caster, s.bounds, 2) or [default_camera(s.bounds)]
        for cam in cams:
            g = _render(ctx, s, cam)
            assert g.position.shape == (384, 512, 3) and g.position.dtype == np.float32
            assert g.tri.shape == (384, 512) and g.mask.dtype == bool
            cover, match, h = _compare_with_embree(s, g)
            assert g.mask.mean() > 0.3, name
            assert cover >= 0.99, (name, cover)
            assert match >= 0.99, (name, match)
            same_tri = (h.tri.reshape(g.shape) == g.tri)[g.mask].mean()
            assert same_tri >= 0.98, (name, same_tri)   # shared edges of coplanar triangles may differ
            assert np.all(g.tri[~g.mask] == -1)


def test_cornell_walls_normals_albedo(ctx, scenes):
    s = scenes["cornell"]
    g = _render(ctx, s, Camera((0.5, 0.5, 2.2), (0.5, 0.5, 0.5), fov_y=45))
    n = g.normal
    np.testing.assert_allclose(np.linalg.norm(n[g.mask], axis=-1), 1.0, atol=1e-5)
    eye = np.asarray(g.camera.position, np.float32)
    assert np.all(np.einsum("ij,ij->i", n[g.mask], eye - g.position[g.mask]) >= 0)   # facing the camera
    red = g.mask & (np.abs(g.position[..., 0] - 0.02) < 1e-4) & (n[..., 0] > 0.999)
    green = g.mask & (np.abs(g.position[..., 0] - 0.98) < 1e-4) & (n[..., 0] < -0.999)
    assert red.sum() > 5000 and green.sum() > 5000
    np.testing.assert_allclose(g.albedo[red], np.tile([0.63, 0.065, 0.05], (red.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(g.albedo[green], np.tile([0.14, 0.45, 0.091], (green.sum(), 1)), atol=1e-6)
    assert np.all(g.emission[red] == 0)
    # red is on the left of the image, green on the right (+x is the camera's right)
    assert np.nonzero(red)[1].mean() < 256 < np.nonzero(green)[1].mean()
    # the emitter panel (seen from below) carries emission 10
    cam = Camera((0.5, 0.3, 0.5), (0.5, 1.0, 0.5001), fov_y=40, width=64, height=48)
    g2 = _render(ctx, s, cam)
    assert np.allclose(g2.emission[g2.mask].max(axis=0), 10.0)
    assert not g2.backface.any()


def test_textured_albedo_matches_surface_at_hits(ctx, tmp_path):
    """The vinc3r Cornell box has sRGB checker textures: the rasterizer's sRGB sampler equals
    shading.sample_texture (decode per texel, then bilinear) at the Embree hits."""
    d = shared_path("scenes", "cornell-box-vinc3r")
    z = tmp_path / "v.zip"
    with zipfile.ZipFile(z, "w") as f:
        for n in ("cornellBox-2.80-Eevee-gltf.gltf", "cornellBox-2.80-Eevee-gltf.bin", "checkerBJS.png",
                  "checker-meter.png"):
            f.write(d / n, n)
    s = ingest_file(z)
    assert s.textures
    g = _render(ctx, s, Camera((0.0, 1.5, 4.5), (0.0, 1.2, 0.0), fov_y=50))
    cover, match, h = _compare_with_embree(s, g)
    assert cover >= 0.99 and match >= 0.99
    ok = g.mask & (h.tri.reshape(g.shape) == g.tri)
    ref = surface_at_hits(s, h.tri, h.u, h.v)
    albedo = ref["albedo"].reshape(g.albedo.shape)
    diff = np.abs(albedo - g.albedo).max(axis=-1)[ok]
    textured = np.array([m["base_color_texture"] is not None for m in s.materials])[s.material[g.tri[ok]]]
    assert textured.sum() > 10000
    # GPU filtering runs at 8-bit sub-texel precision: allow a small difference, mostly exact
    assert np.mean(diff < 0.02) >= 0.99, np.percentile(diff, [50, 99, 100])


def test_direct_light_closed_form_and_sealed_box_shadow(ctx, scenes):
    """Direct light at G-buffer pixels: the floor of room A under its 20 cd point light (nothing in
    between) gets E = I·h/d³; inside the sealed box nothing is lit, directly or indirectly."""
    s = scenes["two-rooms"]
    cam = Camera((3.5, 2.5, 3.5), (1.0, 0.0, 1.0), fov_y=60, width=128, height=96)
    g = _render(ctx, s, cam)
    ref = reference_at_gbuffer(s, g, s.lights, spp=1, bounces=1)
    light = np.asarray(s.lights[0]["position"])
    floor = g.mask & (np.abs(g.position[..., 1]) < 1e-5) & (g.position[..., 0] < 3.9) & (g.normal[..., 1] > 0.999)
    assert floor.sum() > 2000
    p = g.position[floor].astype(np.float64)
    dist = np.linalg.norm(light - p, axis=1)
    expect = s.lights[0]["intensity"] * (light[1] - p[:, 1]) / dist ** 3
    np.testing.assert_allclose(ref["e_direct"][floor][:, 0], expect, rtol=1e-5)

    box = scenes["sealed-box"]
    inside = Camera((0.0, 0.5, 0.3), (0.1, 0.3, -0.45), fov_y=80, width=96, height=72)
    gb = _render(ctx, box, inside)
    assert gb.mask.all() and not gb.backface.any()
    r = reference_at_gbuffer(box, gb, box.lights, sky=(1, 1, 1), spp=8, bounces=2)
    assert np.all(r["e_direct"] == 0) and np.all(r["e_indirect"] == 0)
    assert np.all(r["radiance"] == 0)


def test_backfaces_single_sided(ctx, scenes):
    """Looking at the cornell shell from behind its back wall (outside) shows front faces of the shell;
    from inside the tall box's solid, only back faces: they are drawn unlit, or culled on request."""
    s = scenes["cornell"]
    cam = Camera((0.2, 0.3, 0.2), (0.5, 0.3, 0.9), fov_y=60, width=64, height=48)   # inside the tall box
    g = _render(ctx, s, cam)
    assert g.mask.all() and g.backface.all() and not g.shaded.any()
    np.testing.assert_allclose(np.linalg.norm(g.geo_normal[g.mask], axis=-1), 1.0, atol=1e-5)
    culled = _render(ctx, s, cam, cull_single_sided=True)
    assert not culled.backface.any()
    assert (culled.tri != g.tri).mean() > 0.5   # what lay behind the box's walls shows through


def test_renderer_reuse_and_timing(ctx, scenes):
    from workers.render.context import renderer_info, timed
    from workers.render.gbuffer import GBufferRenderer

    s = scenes["cornell"]
    cam = Camera((0.5, 0.5, 2.2), (0.5, 0.5, 0.5), fov_y=45, width=160, height=120)
    with GBufferRenderer(s, ctx) as r:
        a = r.render(cam)
        (_, _, _), seconds = timed(ctx, lambda: r.draw(cam), repeats=3)
        b = r.render(cam)
        c = r.render(Camera((0.5, 0.5, 2.2), (0.5, 0.5, 0.5), fov_y=45, width=80, height=60))
    assert seconds > 0 and renderer_info(ctx)["version_code"] >= 330
    assert np.array_equal(a.position, b.position) and np.array_equal(a.tri, b.tri)   # deterministic
    assert c.shape == (60, 80)
    assert a.camera.near is not None and a.camera.far > a.camera.near              # fitted from the scene
