"""The material model on the GPU side: proto/glsl/material.glsl (the viewer's) equals
workers.kernels.materials.gi_albedo, and the evaluate G-buffer reads COLOR_0, metallic and cutouts as the ray
stages do (Embree hits through the cutout caster, albedo from surface_at_hits)."""
from __future__ import annotations

import numpy as np
import pytest

from proto.glsl_preprocess import load_sources, preprocess
from tests.gltf_build import GltfBuilder, quad
from workers.gltf import ingest_file
from workers.kernels.materials import gi_albedo
from workers.kernels.shading import surface_at_hits
from workers.raycast import caster_for_scene
from workers.render.cameras import Camera


_FRAG = '''
#include "material.glsl"
uniform vec4 uIn[32];      // base rgb, metallic
uniform float uRough[32];
out vec4 fragColor;
void main() {
  int i = int(gl_FragCoord.x);
  fragColor = vec4(giAlbedo(uIn[i].rgb, uIn[i].a, uRough[i]), 1.0);
}
'''
_VERT = '''
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
'''


@pytest.mark.parametrize("mode, code, clamp", [("metals", 1, 0.0), ("all", 2, 0.0), ("none", 0, 0.0),
                                               ("metals", 1, 0.45)])
def test_glsl_gi_albedo_equals_python(ctx, mode, code, clamp):
    rng = np.random.default_rng(3)
    base = rng.uniform(0, 1, (32, 3))
    metal = np.r_[0.0, 1.0, rng.uniform(0, 1, 30)]
    rough = np.r_[1.0, 0.0, rng.uniform(0, 1, 30)]
    src = dict(load_sources())
    src["test_material.frag.glsl"] = _FRAG
    src["test_material.vert.glsl"] = _VERT
    prog = ctx.program(vertex_shader=preprocess("test_material.vert.glsl", src).code,
                       fragment_shader=preprocess("test_material.frag.glsl", src).code)
    prog["uIn"].write(np.c_[base, metal].astype("f4").tobytes())
    prog["uRough"].write(rough.astype("f4").tobytes())
    prog["uSpecularGI"].value = code
    prog["uMaxAlbedo"].value = clamp
    vbo = ctx.buffer(np.array([[-1, -1], [3, -1], [-1, 3]], "f4").tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "2f", "in_pos")])
    tex = ctx.texture((32, 1), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[tex])
    fbo.use()
    vao.render()
    got = np.frombuffer(fbo.read(components=4, dtype="f4"), "f4").reshape(32, 4)[:, :3]
    want = gi_albedo(base, metal, rough, mode)
    if clamp:
        want = np.minimum(want, clamp)
    for o in (fbo, tex, vao, vbo, prog):
        o.release()
    np.testing.assert_allclose(got, want, atol=2e-6)


def test_gbuffer_reads_colors_metallic_and_cutouts(ctx, tmp_path):
    b = GltfBuilder()
    # a back wall with vertex colours, metallic 0.5, roughness 0.8
    wall = b.material(pbrMetallicRoughness={"baseColorFactor": [0.9, 0.8, 0.7, 1], "metallicFactor": 0.5,
                                            "roughnessFactor": 0.8})
    p, n, uv, idx = quad([-2, 0, -1], [4, 0, 0], [0, 3, 0], [0, 0, 1])
    col = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1], [1, 1, 1, 1]], np.float32) * 0.8
    b.mesh(p, idx, normals=n, uv=uv, material=wall, colors=col)
    # a cutout screen in front of it: a 4x4 checker of alpha 0 / 1
    a = np.full((4, 4, 4), 255, np.uint8)
    a[::2, ::2, 3] = a[1::2, 1::2, 3] = 0
    tex = b.image(a)
    screen = b.material(alphaMode="MASK", doubleSided=True, pbrMetallicRoughness={
        "baseColorFactor": [0.2, 0.2, 0.2, 1], "baseColorTexture": {"index": tex}, "metallicFactor": 0.0})
    p, n, uv, idx = quad([-1, 0.5, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1])
    b.mesh(p, idx, normals=n, uv=uv, material=screen)
    (tmp_path / "s.glb").write_bytes(b.glb())
    scene = ingest_file(tmp_path / "s.glb")
    caster = caster_for_scene(scene)
    from workers.render.gbuffer import GBufferRenderer

    cam = Camera((0.0, 1.5, 3.0), (0.0, 1.5, 0.0), fov_y=60, width=96, height=72)
    with GBufferRenderer(scene, ctx, caster=caster) as r:
        g = r.render(cam)
    o, d = g.camera.pixel_rays()
    h = caster.intersect(o, d)
    hit = h.hit.reshape(g.shape)
    tri = h.tri.reshape(g.shape)
    # coverage and which surface each pixel sees agree with the cutout caster (edges of holes aside)
    assert (hit == g.mask).mean() > 0.999
    same = (tri == g.tri) | ((scene.material[np.maximum(tri, 0)] == scene.material[np.maximum(g.tri, 0)]) & hit)
    assert same.mean() > 0.97
    on_screen = g.mask & (scene.material[np.maximum(g.tri, 0)] == 1)
    behind = g.mask & (scene.material[np.maximum(g.tri, 0)] == 0)
    # inside the screen's silhouette about half the pixels see the wall through the holes
    sil = (np.abs(g.position[..., 0]) < 0.95) & (g.position[..., 1] > 0.55) & (g.position[..., 1] < 2.45)
    frac = behind[sil].sum() / max(1, (sil & g.mask).sum())
    assert 0.35 < frac < 0.65, frac
    # albedo at every covered pixel = the ray stages' (COLOR_0 x base x (1 - m) + m x base x r^2 / 2)
    ref = surface_at_hits(scene, h.tri, h.u, h.v)["albedo"].reshape(g.albedo.shape)
    both = (tri == g.tri) & g.mask
    np.testing.assert_allclose(g.albedo[both], ref[both], atol=0.02)
    wall_px = both & (scene.material[np.maximum(g.tri, 0)] == 0)
    assert wall_px.sum() > 100 and on_screen.sum() > 100
    assert g.albedo[wall_px].max() < 0.9 * 0.8 * (0.5 + 0.5 * 0.64 / 2) + 0.02
