"""G-buffer rasterization of a normalized scene with moderngl (DESIGN stage 7 "evaluate").

One pass draws every triangle of a :class:`workers.scene.NormalizedScene` (no culling by default,
one sample per pixel at the pixel centre, depth test) into float32 targets, read back as numpy
arrays with row 0 at the top of the image:

==============  ===============  ===================================================================
field           shape, dtype     content
==============  ===============  ===================================================================
``position``    (H, W, 3) f32    world-space surface point, metres (0 where uncovered)
``normal``      (H, W, 3) f32    shading normal: interpolated vertex normal, unit, flipped so that
                                 ``n · (eye - position) >= 0`` (facing the camera)
``geo_normal``  (H, W, 3) f32    unit geometric normal ``(v1 - v0) × (v2 - v0)``, flipped toward the
                                 camera (the side the pixel sees; offset shadow rays along it)
``albedo``      (H, W, 3) f32    the diffuse GI albedo of :mod:`workers.kernels.materials` (base colour
                                 × texture × COLOR_0, metallic, the specular GI term) at the pixel
``emission``    (H, W, 3) f32    linear emissive factor (× strength) × emissive texture
``tri``         (H, W) int32     triangle index into ``scene.triangles``, -1 where uncovered
``mask``        (H, W) bool      coverage: a triangle is visible at the pixel centre
``backface``    (H, W) bool      the pixel sees the back side of its triangle (``dir · n_geo > 0``,
                                 the convention of :class:`workers.raycast.Hits`)
``double_sided`` (H, W) bool     the material is double-sided
==============  ===============  ===================================================================

``GBuffer.shaded`` = ``mask & (~backface | double_sided)``: the pixels that reflect light. A pixel
showing the back face of a single-sided surface carries zero radiance, as a probe ray hitting
one does in the light stage (DDGI-P §4.1); with ``cull_single_sided=True`` those faces are
discarded instead, as a glTF viewer does (you see what lies behind them).

Textures are the scene's sRGB-encoded RGBA8 images, uploaded as ``GL_SRGB8_ALPHA8``, so the
sampler decodes each texel to linear before bilinear filtering — the same sampling as
:func:`workers.kernels.shading.sample_texture` (REPEAT wrap, texel centres at ``(i + 0.5)/size``,
glTF v = 0 on the image's first row, which is the first row uploaded: no flip). No mipmaps by
default (``mipmaps=True`` for previews of finely textured scenes).

The shaders are GLSL 3.30 core strings in this module (the runtime GI modes live in
``proto/glsl``; this pass only produces their inputs).

Consumers: the evaluate stage (mode shaders read these arrays as textures; the reference path
tracer shades the same pixels, :func:`workers.kernels.pathtrace.reference_at_gbuffer`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .cameras import Camera, fit_clip_planes
from .context import create_context

__all__ = ["GBuffer", "GBufferRenderer", "render_gbuffer", "VERTEX_SHADER", "FRAGMENT_SHADER"]

GL_SRGB8_ALPHA8 = 0x8C43

VERTEX_SHADER = """
#version 330 core
uniform mat4 u_view_proj;
in vec3 in_pos;
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_color;
in vec3 in_ngeo;
in int in_tri;
out vec3 v_pos;
out vec3 v_normal;
out vec2 v_uv;
out float v_alpha;
flat out vec3 v_ngeo;
flat out int v_tri;
void main() {
    v_pos = in_pos;
    v_normal = in_normal;
    v_uv = in_uv;
    v_alpha = in_color.a;
    v_ngeo = in_ngeo;
    v_tri = in_tri;
    gl_Position = u_view_proj * vec4(in_pos, 1.0);
}
"""

FRAGMENT_SHADER = """
#version 330 core
uniform vec3 u_eye;
uniform vec3 u_base_color;
uniform vec3 u_emissive;
uniform bool u_has_base_tex;
uniform bool u_has_emissive_tex;
uniform bool u_double_sided;
uniform bool u_cull_single_sided;
uniform float u_base_alpha;
uniform float u_alpha_cutoff;      // < 0: opaque; else alphaMode MASK ([glTF] 3.9.6)
uniform sampler2D u_base_tex;      // GL_SRGB8_ALPHA8: texels decoded to linear before filtering
uniform sampler2D u_emissive_tex;
in vec3 v_pos;
in vec3 v_normal;
in vec2 v_uv;
in float v_alpha;
flat in vec3 v_ngeo;
flat in int v_tri;
layout(location = 0) out vec4 o_position;   // xyz, w = 1 (coverage)
layout(location = 1) out vec4 o_normal;     // shading normal facing the camera, w = backface
layout(location = 2) out vec4 o_geo;        // geometric normal facing the camera, w = double sided
layout(location = 3) out vec4 o_albedo;
layout(location = 4) out vec4 o_emission;
layout(location = 5) out int o_tri;         // triangle index + 1 (0 = uncovered)
void main() {
    vec3 view = v_pos - u_eye;                   // eye -> surface
    bool back = dot(v_ngeo, view) > 0.0;
    if (back && u_cull_single_sided && !u_double_sided) discard;
    if (u_alpha_cutoff >= 0.0) {               // a cutout's hole: rays and the camera see through it
        float alpha = u_base_alpha * v_alpha;
        if (u_has_base_tex) alpha *= texture(u_base_tex, v_uv).a;
        if (alpha < u_alpha_cutoff) discard;
    }
    float ln = length(v_normal);
    vec3 n = ln > 1e-12 ? v_normal / ln : v_ngeo;
    if (dot(n, view) > 0.0) n = -n;              // face the camera
    vec3 albedo = u_base_color;
    if (u_has_base_tex) albedo *= texture(u_base_tex, v_uv).rgb;
    vec3 emission = u_emissive;
    if (u_has_emissive_tex) emission *= texture(u_emissive_tex, v_uv).rgb;
    o_position = vec4(v_pos, 1.0);
    o_normal = vec4(n, back ? 1.0 : 0.0);
    o_geo = vec4(back ? -v_ngeo : v_ngeo, u_double_sided ? 1.0 : 0.0);
    o_albedo = vec4(albedo, 1.0);
    o_emission = vec4(emission, 1.0);
    o_tri = v_tri + 1;
}
"""


@dataclass
class GBuffer:
    """Per-pixel surface attributes of one camera view (see the module doc for each field)."""

    position: np.ndarray
    normal: np.ndarray
    geo_normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    tri: np.ndarray
    mask: np.ndarray
    backface: np.ndarray
    double_sided: np.ndarray
    camera: Camera
    timings: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape

    @property
    def shaded(self) -> np.ndarray:
        """(H, W) bool: covered pixels that reflect light (front faces, or double-sided back faces)."""
        return self.mask & (~self.backface | self.double_sided)

    def view_dirs(self) -> np.ndarray:
        """(H, W, 3) float32 unit directions from the eye to each pixel's surface point (0 where uncovered)."""
        d = self.position - np.asarray(self.camera.position, np.float32)
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        return np.divide(d, n, out=np.zeros_like(d), where=n > 0).astype(np.float32)


def _scene_vertices(scene) -> tuple[np.ndarray, np.ndarray]:
    """Interleaved per-vertex records (3T,) of the triangles sorted by material, and that order."""
    tri = np.asarray(scene.triangles, np.float32)
    T = tri.shape[0]
    order = np.argsort(np.asarray(scene.material), kind="stable")
    t64 = tri.astype(np.float64)
    ng = np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0])
    ln = np.linalg.norm(ng, axis=1, keepdims=True)
    ng = np.divide(ng, ln, out=np.zeros_like(ng), where=ln > 0).astype(np.float32)
    rec = np.dtype([("pos", "<f4", 3), ("normal", "<f4", 3), ("uv", "<f4", 2), ("color", "<f4", 4),
                    ("ngeo", "<f4", 3), ("tri", "<i4")])
    v = np.zeros((T, 3), rec)
    v["pos"] = tri
    v["normal"] = np.asarray(scene.normals, np.float32)
    v["uv"] = np.asarray(scene.uv0, np.float32)
    v["color"] = 1.0 if getattr(scene, "colors", None) is None else np.asarray(scene.colors, np.float32)
    v["ngeo"] = ng[:, None, :]
    v["tri"] = np.arange(T, dtype=np.int32)[:, None]
    return v[order].reshape(-1), order


class GBufferRenderer:
    """Uploads a scene once and renders G-buffers for any number of cameras.

    Parameters
    ----------
    scene : workers.scene.NormalizedScene
    ctx : moderngl.Context, optional
        A context to use (not released by :meth:`release`); default: a new headless one
        (:func:`workers.render.context.create_context`).
    cull_single_sided : bool
        Discard back faces of single-sided materials (as a glTF viewer does) instead of drawing
        them as opaque, unlit surfaces (as the probe bake and the path tracer see them).
    mipmaps : bool
        Trilinear mipmapped texture sampling instead of plain bilinear.
    caster : RayCaster, optional
        Used to fit near/far planes of cameras that have none (else the scene bounds).
    """

    def __init__(self, scene, ctx=None, *, cull_single_sided: bool = False, mipmaps: bool = False, caster=None):
        self._own_ctx = ctx is None
        self.ctx = create_context() if ctx is None else ctx
        import moderngl as mgl  # importable: create_context succeeded or a context was given

        self._mgl = mgl
        self.scene = scene
        self.cull_single_sided = bool(cull_single_sided)
        self.caster = caster
        self.bounds = np.asarray(scene.bounds, np.float64) if scene.n_triangles else np.zeros((2, 3))
        ctx = self.ctx
        self.program = ctx.program(vertex_shader=VERTEX_SHADER, fragment_shader=FRAGMENT_SHADER)
        verts, order = _scene_vertices(scene)
        self.vbo = ctx.buffer(verts.tobytes()) if len(verts) else None
        self.vao = (ctx.vertex_array(self.program, [(self.vbo, "3f 3f 2f 4f 3f 1i", "in_pos", "in_normal",
                                                     "in_uv", "in_color", "in_ngeo", "in_tri")]) if self.vbo is not None else None)
        # draw ranges: one per material (uniforms + textures per draw)
        mats = np.asarray(scene.material)[order]
        self.ranges = []
        if len(mats):
            starts = np.flatnonzero(np.r_[True, mats[1:] != mats[:-1]])
            ends = np.r_[starts[1:], len(mats)]
            self.ranges = [(int(mats[s]), int(s), int(e - s)) for s, e in zip(starts, ends)]
        self.textures = []
        for img in scene.textures:
            a = np.asarray(img, np.uint8)
            if a.ndim == 2:
                a = a[:, :, None]
            if a.shape[2] == 1:
                a = np.concatenate([np.repeat(a, 3, axis=2), np.full(a.shape[:2] + (1,), 255, np.uint8)], axis=2)
            elif a.shape[2] == 2:  # grey + alpha
                a = np.concatenate([np.repeat(a[:, :, :1], 3, axis=2), a[:, :, 1:2]], axis=2)
            elif a.shape[2] == 3:
                a = np.concatenate([a, np.full(a.shape[:2] + (1,), 255, np.uint8)], axis=2)
            a = np.ascontiguousarray(a[:, :, :4])
            tex = ctx.texture((a.shape[1], a.shape[0]), 4, a.tobytes(), internal_format=GL_SRGB8_ALPHA8)
            tex.repeat_x = tex.repeat_y = True
            if mipmaps:
                tex.build_mipmaps()
                tex.filter = (mgl.LINEAR_MIPMAP_LINEAR, mgl.LINEAR)
            else:
                tex.filter = (mgl.LINEAR, mgl.LINEAR)
            self.textures.append(tex)
        self._white = ctx.texture((1, 1), 4, bytes([255, 255, 255, 255]), internal_format=GL_SRGB8_ALPHA8)
        self._targets: dict[tuple[int, int], tuple] = {}

    # ------------------------------------------------------------------ lifecycle
    def release(self) -> None:
        for fbo, texs, depth in self._targets.values():
            fbo.release()
            for t in texs:
                t.release()
            depth.release()
        self._targets.clear()
        for t in self.textures:
            t.release()
        self._white.release()
        if self.vao is not None:
            self.vao.release()
            self.vbo.release()
        self.program.release()
        if self._own_ctx:
            self.ctx.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()

    # ------------------------------------------------------------------ rendering
    def _target(self, w: int, h: int):
        key = (w, h)
        if key not in self._targets:
            ctx = self.ctx
            texs = [ctx.texture((w, h), 4, dtype="f4") for _ in range(5)]
            texs.append(ctx.texture((w, h), 1, dtype="i4"))
            for t in texs:
                t.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
            depth = ctx.depth_texture((w, h))
            self._targets[key] = (ctx.framebuffer(color_attachments=texs, depth_attachment=depth), texs, depth)
        return self._targets[key]

    def draw(self, camera: Camera):
        """Rasterize into the camera's framebuffer (no readback); returns (framebuffer, textures)."""
        if camera.near is None or camera.far is None:
            camera = fit_clip_planes(camera, self.caster, self.bounds)
        ctx = self.ctx
        fbo, texs, _ = self._target(camera.width, camera.height)
        fbo.use()
        fbo.viewport = (0, 0, camera.width, camera.height)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)  # 0 bits also clear the int target to 0 (= uncovered)
        mgl = self._mgl
        ctx.enable(mgl.DEPTH_TEST)
        ctx.disable(mgl.CULL_FACE | mgl.BLEND)
        ctx.depth_func = "<"
        if self.vao is None:
            return camera, fbo, texs
        p = self.program
        p["u_view_proj"].write(camera.view_projection().T.astype("f4").tobytes())
        if "u_eye" in p:
            p["u_eye"].value = tuple(camera.position)
        p["u_cull_single_sided"].value = self.cull_single_sided
        if "u_base_tex" in p:
            p["u_base_tex"].value = 0
        if "u_emissive_tex" in p:
            p["u_emissive_tex"].value = 1
        mats = self.scene.materials
        for m, start, count in self.ranges:
            mat = mats[m]
            bt, et = mat.get("base_color_texture"), mat.get("emissive_texture")
            p["u_base_color"].value = tuple(float(x) for x in mat["base_color"][:3])
            p["u_base_alpha"].value = float(mat["base_color"][3]) if len(mat["base_color"]) > 3 else 1.0
            mode = mat.get("alpha_mode", "OPAQUE")
            p["u_alpha_cutoff"].value = (float(mat.get("alpha_cutoff", 0.5)) if mode == "MASK"
                                         else 0.5 if mode == "BLEND" else -1.0)
            if "u_emissive" in p:
                p["u_emissive"].value = tuple(float(x) for x in mat.get("emissive", [0, 0, 0])[:3])
            p["u_has_base_tex"].value = bt is not None
            if "u_has_emissive_tex" in p:
                p["u_has_emissive_tex"].value = et is not None
            p["u_double_sided"].value = bool(mat.get("double_sided", False))
            (self.textures[bt] if bt is not None else self._white).use(0)
            (self.textures[et] if et is not None else self._white).use(1)
            self.vao.render(mgl.TRIANGLES, vertices=3 * count, first=3 * start)
        return camera, fbo, texs

    def render(self, camera: Camera) -> GBuffer:
        """The G-buffer of one camera (see the module doc). ``timings``: draw_s (draw + finish), read_s."""
        t0 = time.perf_counter()
        camera, fbo, texs = self.draw(camera)
        self.ctx.finish()
        t1 = time.perf_counter()
        w, h = camera.width, camera.height

        def read(t, comps, dtype):
            return np.frombuffer(t.read(), dtype).reshape(h, w, comps)[::-1]  # GL row 0 = bottom

        pos, nrm, geo, alb, emi = (read(t, 4, np.float32) for t in texs[:5])
        tri = read(texs[5], 1, np.int32)[..., 0].astype(np.int32) - 1
        mask = tri >= 0
        albedo, emission = surface_colors(self.scene, tri, pos[..., :3], alb[..., :3], emi[..., :3])
        t2 = time.perf_counter()
        return GBuffer(
            position=np.ascontiguousarray(pos[..., :3]), normal=np.ascontiguousarray(nrm[..., :3]),
            geo_normal=np.ascontiguousarray(geo[..., :3]), albedo=albedo,
            emission=emission, tri=np.ascontiguousarray(tri), mask=mask,
            backface=(nrm[..., 3] > 0.5) & mask, double_sided=(geo[..., 3] > 0.5) & mask, camera=camera,
            timings={"draw_s": t1 - t0, "read_s": t2 - t1},
        )


def surface_colors(scene, tri, position, albedo_gl, emission_gl):
    """(H, W, 3) albedo and emission of the covered pixels from the material model every ray stage uses
    (:func:`workers.kernels.materials.surface_materials`: COLOR_0, metallic-roughness, the specular GI
    term), at the pixel's surface point: barycentrics from the rasterized position on its triangle.
    Scenes whose materials are plain base colour × texture keep the rasterizer's values."""
    from workers.kernels.materials import surface_materials

    plain = (getattr(scene, "colors", None) is None and getattr(scene, "max_albedo", None) is None
             and all(float(m.get("metallic", 0.0)) == 0.0 and m.get("metallic_roughness_texture") is None
                     for m in scene.materials))
    alb = np.ascontiguousarray(albedo_gl, np.float32)
    emi = np.ascontiguousarray(emission_gl, np.float32)
    if plain:
        return alb, emi
    idx = np.flatnonzero(tri.reshape(-1) >= 0)
    t = tri.reshape(-1)[idx].astype(np.int64)
    tv = np.asarray(scene.triangles, np.float64)[t]                      # (N, 3, 3)
    p = np.asarray(position, np.float64).reshape(-1, 3)[idx]
    e1, e2, w = tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0], p - tv[:, 0]
    d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d20, d21 = (w * e1).sum(1), (w * e2).sum(1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 0, den, 1.0)
    u = np.clip((d11 * d20 - d01 * d21) / den, 0.0, 1.0)
    v = np.clip((d00 * d21 - d01 * d20) / den, 0.0, 1.0 - u)
    m = surface_materials(scene, t, u, v, specular_gi=getattr(scene, "specular_gi", "metals"),
                          max_albedo=getattr(scene, "max_albedo", None))
    alb = alb.reshape(-1, 3).copy()
    emi = emi.reshape(-1, 3).copy()
    alb[idx] = m["albedo"]
    emi[idx] = m["emission"]
    return alb.reshape(albedo_gl.shape), emi.reshape(emission_gl.shape)


def render_gbuffer(scene, camera: Camera, ctx=None, **kwargs) -> GBuffer:
    """One-shot :class:`GBufferRenderer` render (creates and releases the renderer)."""
    r = GBufferRenderer(scene, ctx, **kwargs)
    try:
        return r.render(camera)
    finally:
        r.release()
