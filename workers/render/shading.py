"""Deferred shading pass of the evaluate stage: G-buffer + a GI mode's GLSL from ``proto/glsl`` → linear HDR.

The pass is ``proto/glsl/deferred.frag.glsl`` with the mode file bound to its ``@mode`` slot
(``mode_<name>.glsl``), preprocessed for GLSL 3.30 core by :mod:`proto.glsl_preprocess` — the same
files the WebGL2 viewer compiles. One full-screen triangle; per pixel

    L_out = emission + albedo/π · (E_direct + E_indirect)

- ``E_direct``: the punctual lights evaluated in GLSL (``lights.glsl``, the formulas of
  :func:`workers.kernels.shading.direct_irradiance`) times a per-pixel, per-light visibility computed
  with Embree shadow rays on the CPU (:func:`shadow_masks`) and uploaded as RGBA8 textures (lights 0-3,
  4-7). So the direct term is the reference's, exactly (the same rays, eps and normals), and the pass
  still does the lighting work a game's base pass does. A pass takes :data:`MAX_LIGHTS` lights (8); a scene
  with more is drawn in groups of 8, one pass each (:meth:`ShadingRenderer.render`: the first group's pass
  gives E_indirect and the radiance of its lights, each further group's E_direct adds ``albedo/π · E_direct``
  on the CPU), as a forward renderer's additive light passes do.
- ``E_indirect``: the mode's ``giIndirectIrradiance(p, n)``.

``uOutput`` selects radiance (0), E_indirect (1) or E_direct (2); targets are RGBA32F, read back as
(H, W, 3) float32 with row 0 at the top (the G-buffer's order: textures are uploaded row 0 first and the
pass reads texel ``gl_FragCoord.xy``, so no flip happens anywhere).

Modes and their textures (:func:`prepare_mode`, from the mode table ``proto/gi_modes.json`` that the viewer reads too;
the GLSL headers document each binding):

=================== ===========================================================================================
``direct``          none
``leaking``         ``sh_l2`` 3D RGBA32F, LINEAR (L2, ``KILN_SH_L2``; the default when the bake has it), else
                    ``sh_l1_{r,g,b}`` 3D RGBA32F, LINEAR (L1)
``ddgi``            ``uProbeData`` (relocated positions + non-OFF flag, 3D RGBA32F, NEAREST), ``irradiance`` and
                    ``depth_moments`` atlases (2D, LINEAR)
``mask``            ``mask_indirection`` (NEAREST), ``mask_atlas`` (R8, LINEAR), the cluster SH volumes stacked
``mask_normalized`` along z (3D, RGBA16F as stored, uploaded as float32; L2: the ``cluster_sh_l2_{k}`` volumes,
                    ``KILN_SH_L2``), cluster weights
                    stacked (normalized only)
``prt``             the PRT SH basis stacked along z (all 9 coefficients of an L2 bake, ``KILN_SH_L2``, else the 4
                    of L1); per-channel coefficients as uniforms
=================== ===========================================================================================

SH order (``prepare_mode(sh_order=...)``): None, the default, uses L2 wherever the bake has the L2 volumes
(docs/architecture.md "Runtime SH evaluation": measured better on every axis of an open lit floor), 1 forces L1,
2 requires L2. The mode's ``info["sh_order"]`` says which was bound.

Bake frame (``ShadingRenderer(frame=M)`` / :meth:`ShadingRenderer.set_frame`): the bake's probe artifacts are in the
bake frame, the world turned about +Y (the manifest's ``grid.frame.matrix`` M, row-major, p_bake = M · p_world; none
= identity). The G-buffer, ``eye`` and the lights stay world; the pass hands the mode ``M·p``, ``M·n`` and
``giViewDir = M·v`` through the uniform ``uGiFrame`` (proto/glsl/gi_view.glsl). Resources from :func:`prepare_mode`
need no change (their grid and arrays are the bake's); PRT lights must already be in the bake frame.

Timing (:meth:`ShadingRenderer.time_pass`): wall clock of ``render(); ctx.finish()``, median of repeats
after one warm-up (llvmpipe's timer queries are wrong).

Consumers: workers/stages/evaluate.py, tests/render/test_shading.py, tests/bench/bench_evaluate.py.
"""
from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field

import numpy as np

from proto import gi_modes
from proto.gi_modes import (KINDS, MASK_BLEND, MASK_OFFSET_SAMPLES, MASK_SEEN_THRESHOLD, MAX_3D_TEXTURE_DEPTH, MAX_LIGHTS, MAX_TEXTURE_SIZE, MODE_IDS,
                            PRT_MAX_GROUPS, SELF_SHADOW_BIAS)
from proto.glsl_preprocess import ShaderSourceError, format_compile_errors, load_sources, preprocess
from workers.kernels.ddgi import bias_scale
from workers.kernels.grid import OFF, layers_table
from workers.kernels.sh import sh_l2_atlas_depth
from workers.kernels.shading import direct_irradiance

from .context import create_context

__all__ = ["MODES", "MAX_LIGHTS", "ModeResources", "GBufferInputs", "ShadingRenderer", "prepare_mode",
           "shadow_masks", "light_uniforms", "stack_volumes", "wrap_atlas", "frame_matrix"]

MODES = MODE_IDS
"""The GI modes of ``proto/gi_modes.json``; its constants (MAX_LIGHTS, PRT_MAX_GROUPS, MAX_3D_TEXTURE_DEPTH: deeper L2
cluster stacks fall back to L1, MAX_TEXTURE_SIZE: wider DDGI atlases are re-packed by :func:`wrap_atlas`) are
:mod:`proto.gi_modes`'s."""
_SAMPLER_TYPES = {0x8B5E: "2d", 0x8B5F: "3d"}  # GL_SAMPLER_2D, GL_SAMPLER_3D


# ----------------------------------------------------------------------------------------- inputs
@dataclass
class GBufferInputs:
    """What the pass reads per pixel, (H, W, ...) float32 arrays, row 0 = top (any point set works:
    the GLSL = Python tests lay points out as an image)."""

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    shaded: np.ndarray             # (H, W) bool
    shadow: np.ndarray | None = None  # (H, W, L) visibility in [0, 1] per light (None: all visible)

    @classmethod
    def from_gbuffer(cls, gb, shadow=None) -> "GBufferInputs":
        return cls(gb.position, gb.normal, gb.albedo, gb.emission, gb.shaded, shadow)

    @property
    def shape(self) -> tuple[int, int]:
        return self.shaded.shape


def shadow_masks(points, normals, lights, caster, eps: float) -> np.ndarray:
    """(N, L) uint8 0/1: whether light l reaches point n, by the shadow rays of
    :func:`workers.kernels.shading.direct_irradiance` (same origins ``x + eps·n``, same tfar). Points a light
    does not reach anyway (facing away, out of the cone or range) get 1."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    out = np.ones((pts.shape[0], len(lights)), np.uint8)
    for i, light in enumerate(lights):
        lit = direct_irradiance(pts, nrm, [light], None, eps).sum(axis=1)
        sel = np.flatnonzero(lit > 0)
        if sel.size == 0 or caster is None:
            continue
        shadowed = direct_irradiance(pts[sel], nrm[sel], [light], caster, eps).sum(axis=1)
        out[sel, i] = (shadowed > 0).astype(np.uint8)
    return out


def light_uniforms(lights) -> dict[str, np.ndarray]:
    """lights.glsl uniforms from the scene's light dicts (at most :data:`MAX_LIGHTS`)."""
    lights = list(lights)
    if len(lights) > MAX_LIGHTS:
        raise ValueError(f"the shading pass takes at most {MAX_LIGHTS} lights, got {len(lights)}")
    pos = np.zeros((MAX_LIGHTS, 4), np.float32)
    dr = np.zeros((MAX_LIGHTS, 4), np.float32)
    col = np.zeros((MAX_LIGHTS, 4), np.float32)
    cone = np.zeros((MAX_LIGHTS, 4), np.float32)
    types = {"point": 0.0, "spot": 1.0, "directional": 2.0}
    for i, lt in enumerate(lights):
        pos[i, :3] = lt.get("position") or (0.0, 0.0, 0.0)
        pos[i, 3] = types[lt["type"]]
        d = np.asarray(lt.get("direction") or (0.0, 0.0, -1.0), np.float64)
        dr[i, :3] = d / max(np.linalg.norm(d), 1e-30)
        rng = lt.get("range")
        dr[i, 3] = float(rng) if rng is not None and math.isfinite(rng) and rng > 0 else 0.0
        col[i, :3] = np.asarray(lt.get("color", (1.0, 1.0, 1.0)), np.float64) * float(lt.get("intensity", 1.0))
        inner = lt.get("inner_cone_angle")
        outer = lt.get("outer_cone_angle")
        cone[i, 0] = math.cos(0.0 if inner is None else float(inner))
        cone[i, 1] = math.cos(math.pi / 4 if outer is None else float(outer))
    return {"uLightCount": len(lights), "uLightPosType": pos, "uLightDirRange": dr, "uLightColor": col,
            "uLightCone": cone}


# ----------------------------------------------------------------------------------------- modes
@dataclass
class ModeResources:
    """A mode's textures ``{uniform: (array, linear)}`` (3D when the array has 4 axes, else 2D), its other
    uniforms, and the bytes of the textures it samples (MD Table 2 style: as uploaded)."""

    mode: str
    textures: dict = field(default_factory=dict)
    uniforms: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    defines: dict = field(default_factory=dict)   # extra preprocessor #defines (KILN_MASK_CLUSTERS)

    @property
    def texture_bytes(self) -> int:
        return int(sum(np.asarray(a).nbytes for a, _ in self.textures.values()))


def stack_volumes(volumes) -> np.ndarray:
    """Probe volumes (nz, ny, nx, C) stacked along z (volume s at z texels [s·nz, (s+1)·nz)): gi_grid.glsl's
    giStackedUVW layout; the bytes of the volumes concatenated."""
    return np.ascontiguousarray(np.concatenate([np.asarray(v, np.float32) for v in volumes], axis=0))


def wrap_atlas(atlas, counts, max_width: int = MAX_TEXTURE_SIZE) -> tuple[np.ndarray, int]:
    """A DDGI octahedral atlas (ny·t, nz·nx·t, C) (proto/bundle.md 5.1) re-packed to at most ``max_width`` texels wide:
    ``(atlas, columns)``, tile c = k·nx + i at column c mod columns of row block c div columns, the blocks (ny tiles
    high) stacked downwards, unused tiles 0 (``octahedral.glsl`` ``octAtlasUVWrapped``). ``columns`` is 0 and the
    atlas returned as is when it fits. The tiles keep their borders, so bilinear filtering reads the same texels."""
    a = np.asarray(atlas)
    nx, ny, nz = (int(c) for c in counts)
    t = a.shape[0] // ny
    C = nx * nz
    if a.shape[1] <= max_width:
        return a, 0
    columns = max_width // t
    if columns < 1:
        raise ValueError(f"an atlas tile of {t} texels does not fit {max_width}")
    rows = -(-C // columns)
    tiles = a.reshape(ny, t, C, t, *a.shape[2:]).swapaxes(1, 2)                      # (ny, C, t, t, ...)
    pad = np.zeros((ny, rows * columns - C) + tiles.shape[2:], a.dtype)
    tiles = np.concatenate([tiles, pad], axis=1).reshape(ny, rows, columns, t, t, *a.shape[2:])
    out = tiles.transpose(1, 0, 3, 2, 4, *range(5, tiles.ndim))                     # (rows, ny, t, columns, t, ...)
    return np.ascontiguousarray(out.reshape(rows * ny * t, columns * t, *a.shape[2:])), columns


def _grid_uniforms(grid) -> dict:
    return {"uGridOrigin": tuple(float(x) for x in grid["origin"]),
            "uGridSpacing": tuple(float(x) for x in grid["spacing"]),
            "uGridCounts": tuple(float(x) for x in grid["counts"]),
            "uGridRectilinear": grid.get("layers") is not None}


def _grid_textures(grid) -> dict:
    """``uGridLayers`` of a rectilinear grid (``probe_grid.glsl``): R32F (3, max(counts)), texel (i, a) = layer i of
    axis a (:func:`workers.kernels.grid.layers_table`), NEAREST; none for a uniform grid (the shader does not read
    it; the draw binds a dummy)."""
    if grid.get("layers") is None:
        return {}
    table = layers_table(grid["counts"], grid["origin"], grid["spacing"], grid["layers"])
    return {"uGridLayers": (table.astype(np.float32), False)}


def _want_l2(sh_order, available: bool, mode: str) -> bool:
    if sh_order not in (None, 1, 2):
        raise ValueError(f"sh_order must be None, 1 or 2, got {sh_order!r}")
    if sh_order == 2 and not available:
        raise ValueError(f"sh_order=2: the bake has no L2 data for mode {mode!r} (light.sh_order = 1?)")
    return available and sh_order != 1


def _upload(kind: str, arrays, names: list[str], counts) -> np.ndarray:
    """The array a texture of ``kind`` (``proto/gi_modes.json`` kinds) holds for the artifacts ``names``: float
    arrays as float32, the others (RGBA8 masks, the indirection) as stored; ``probe-data`` (nz, ny, nx, 4) float32 =
    relocated position xyz and 1 unless OFF. ``atlas`` as stored (:func:`prepare_mode` re-packs a wide one)."""
    if kind == "stack":
        return stack_volumes([arrays[n] for n in names])
    if kind == "probe-data":
        nx, ny, nz = (int(c) for c in counts)
        pos = np.asarray(arrays[names[0]], np.float32).reshape(nz, ny, nx, 3)
        states = np.asarray(arrays[names[1]]).reshape(nz, ny, nx)
        return np.ascontiguousarray(np.concatenate([pos, (states != OFF)[..., None].astype(np.float32)], axis=-1))
    (name,) = names
    a = np.asarray(arrays[name])
    return np.ascontiguousarray(a, np.float32 if a.dtype.kind == "f" else None)


def _bind_textures(r: ModeResources, arrays, counts, sh_order: int, prt_basis=None) -> dict[str, np.ndarray]:
    """Fill ``r.textures`` with the mode's bindings of ``proto/gi_modes.json`` (:func:`proto.gi_modes.texture_bindings`)
    and ``r.defines`` with its #defines; returns the uploaded arrays by uniform."""
    out = {}
    for uniform, (names, kind) in gi_modes.texture_bindings(r.mode, arrays, sh_order, prt_basis).items():
        out[uniform] = _upload(kind, arrays, names, counts)
        r.textures[uniform] = (out[uniform], KINDS[kind]["filter"] == "linear")
    r.defines.update(gi_modes.mode_defines(r.mode, sh_order, gi_modes.cluster_count(arrays)))
    return out


def prepare_mode(mode: str, arrays, grid, *, self_shadow_bias: float = SELF_SHADOW_BIAS,
                 mask_meta: dict | None = None, mask_offset_samples: float = MASK_OFFSET_SAMPLES, prt_model=None,
                 prt_coefficients=None, sh_order: int | None = None) -> ModeResources:
    """Textures and uniforms of one mode from baked artifacts addressed by name (``arrays[name]``).

    Which artifact goes to which sampler, how it is uploaded, the mode's uniforms and #defines: ``proto/gi_modes.json``
    (one source with the viewer's ``web/src/state/modes.js``); the uniform values are computed here.
    grid : counts (nx, ny, nz), origin, spacing. ddgi: ``self_shadow_bias`` is B of DDGI-P eq 2, the bake's
    ``light.self_shadow_bias``. mask modes need ``mask_meta`` with ``samples_per_cell`` (S),
    ``block_size`` (T) and ``border_lo``; they read the masks ``mask_offset_samples`` refined samples along
    n + v (``uMaskOffset``; :func:`workers.kernels.samplers.mask_values`). prt needs ``prt_model``
    (:class:`workers.prt_relight.PrtModel`, mono, no gamma) and ``prt_coefficients`` (n, 3) (u of PRT eq 10 per colour channel).
    ``sh_order``: None = L2 where the bake has it (the default), 1 = L1, 2 = L2 required (module doc).
    """
    if mode not in gi_modes.MODES:
        raise ValueError(f"unknown mode {mode!r}; valid: {', '.join(MODES)}")
    r = ModeResources(mode, uniforms=_grid_uniforms(grid), textures=_grid_textures(grid))
    if grid.get("layers") is not None and mode != "direct":
        r.defines["KILN_GRID_RECTILINEAR"] = True     # probe_grid.glsl: the layer lookup, compiled only then
    nx, ny, nz = (int(c) for c in grid["counts"])
    if mode == "direct":
        return r
    if mode == "leaking":
        l2 = _want_l2(sh_order, gi_modes.has_l2(mode, arrays), mode)
        _bind_textures(r, arrays, grid["counts"], 2 if l2 else 1)
        r.info.update(sh_order=2 if l2 else 1)
        return r
    if mode == "ddgi":
        states = np.asarray(arrays["probe_states"]).reshape(nz, ny, nx)
        up = _bind_textures(r, arrays, grid["counts"], 1)
        t_irr = up["uIrradianceAtlas"].shape[0] // ny
        t_dep = up["uDepthAtlas"].shape[0] // ny
        # wider than MAX_TEXTURE_SIZE it would not upload: re-packed
        irr, irr_cols = wrap_atlas(up["uIrradianceAtlas"], grid["counts"])
        dep, dep_cols = wrap_atlas(up["uDepthAtlas"], grid["counts"])
        r.textures.update(uIrradianceAtlas=(irr, True), uDepthAtlas=(dep, True))
        r.uniforms.update(uDdgiBias=bias_scale(grid["spacing"], self_shadow_bias), uIrradianceTexels=t_irr - 2,
                          uDepthTexels=t_dep - 2, uIrradianceColumns=irr_cols, uDepthColumns=dep_cols)
        r.info.update(irradiance_texels=t_irr - 2, depth_texels=t_dep - 2, probes_off=int((states == OFF).sum()),
                      atlas_columns=[irr_cols, dep_cols])
        return r
    if mode in ("mask", "mask_normalized"):
        if mask_meta is None:
            raise ValueError("mask modes need mask_meta (samples_per_cell, block_size, border_lo)")
        K = gi_modes.cluster_count(arrays)
        if K < 1:
            raise ValueError("mask modes need cluster_sh_{k}_{r,g,b} volumes")
        l2 = _want_l2(sh_order, gi_modes.has_l2(mode, arrays), mode)
        if l2 and sh_order is None and sh_l2_atlas_depth(nz, K) > MAX_3D_TEXTURE_DEPTH:
            l2 = False                           # the stack would not fit one 3D texture: L1 (info says so)
            r.info.update(sh_l2_skipped=f"7·K·(nz + 2) = {sh_l2_atlas_depth(nz, K)} > {MAX_3D_TEXTURE_DEPTH}")
        _bind_textures(r, arrays, grid["counts"], 2 if l2 else 1)   # KILN_MASK_CLUSTERS = K: no code for absent ones
        r.info.update(sh_order=2 if l2 else 1)
        S = int(mask_meta["samples_per_cell"])
        r.uniforms.update(uClusterCount=K, uMaskS=float(S),
                          uMaskT=float(mask_meta["block_size"]), uMaskLo=float(mask_meta["border_lo"]),
                          uMaskOffset=float(mask_offset_samples), uMaskSeen=MASK_SEEN_THRESHOLD,
                          uMaskBlend=tuple(MASK_BLEND))
        r.info.update(clusters=K)
        return r
    # prt
    if prt_model is None or prt_coefficients is None:
        raise ValueError("prt mode needs prt_model and prt_coefficients")
    if prt_model.channels != "mono" or prt_model.gamma is not None:
        raise ValueError("the prt GLSL mode sums a mono, linear (gamma None) basis")
    u = np.asarray(prt_coefficients, np.float32)
    n = u.shape[0]
    G = -(-n // 4)
    if G > PRT_MAX_GROUPS:
        raise ValueError(f"prt mode: at most {4 * PRT_MAX_GROUPS} basis slots, got {n}")
    names = prt_model.section["sh"]["basis"]            # [k][g] artifact names
    l2 = _want_l2(sh_order, len(names) == 9, mode)      # an L2 bake's basis has all 9 coefficients
    C = 9 if l2 else 4
    _bind_textures(r, arrays, grid["counts"], 2 if l2 else 1, [row[:G] for row in names])
    coef = np.zeros((3, PRT_MAX_GROUPS, 4), np.float32)
    padded = np.zeros((4 * G, 3), np.float32)
    padded[:n] = u
    coef[:, :G, :] = padded.T.reshape(3, G, 4)
    r.uniforms.update(uPrtGroups=G, uPrtCoef=coef.reshape(-1, 4))
    r.info.update(basis=n, groups=G, sh_order=2 if l2 else 1, coefficients=C)
    return r


# ----------------------------------------------------------------------------------------- bake frame
def frame_matrix(frame) -> np.ndarray:
    """The bake frame as a (3, 3) float64 row-major rotation, world -> bake (p_bake = M @ p_world).

    ``frame``: None (identity: a bake without ``grid.frame``, or yaw 0), a (3, 3) array-like, the manifest's
    ``grid.frame`` dict (its ``matrix``) or a grid dict holding ``frame``. Raises ValueError unless M is a finite
    rotation (M Mᵀ = I within 1e-4, det +1): normals and view directions are mapped with M as well.
    """
    if isinstance(frame, dict) and "matrix" not in frame:  # a grid dict: its frame, if any
        frame = frame.get("frame")
    if isinstance(frame, dict):                            # grid.frame: {"yaw_deg", "matrix", ...}
        frame = frame["matrix"]
    if frame is None:
        return np.eye(3)
    m = np.asarray(frame, np.float64)
    if m.shape != (3, 3) or not np.isfinite(m).all():
        raise ValueError(f"bake frame: want a finite (3, 3) matrix, got shape {m.shape}")
    if not np.allclose(m @ m.T, np.eye(3), atol=1e-4) or np.linalg.det(m) < 0:
        raise ValueError(f"bake frame: {m.tolist()} is not a rotation (M Mᵀ ≠ I or det < 0)")
    return m


# ----------------------------------------------------------------------------------------- renderer
class ShadingRenderer:
    """Compiles the deferred pass per mode and renders G-buffers through it.

    Parameters
    ----------
    ctx : moderngl.Context, optional (default: a new headless one, released by :meth:`release`)
    lights : list of light dicts (the scene's resolved lights, world; any number: groups of :data:`MAX_LIGHTS`,
        one pass each, see :meth:`render`)
    frame : (3, 3) array-like, optional: the bake frame, row-major world -> bake (the manifest's
        ``grid.frame.matrix``; also its dict); None = identity. See :meth:`set_frame` and the module doc.
    """

    def __init__(self, ctx=None, lights=(), frame=None):
        self._own_ctx = ctx is None
        self.ctx = create_context() if ctx is None else ctx
        import moderngl as mgl

        self._mgl = mgl
        self.sources = load_sources()
        self.lights = list(lights)
        # groups of MAX_LIGHTS lights, a pass each (at least one group, empty for a scene without lights)
        self.light_groups = [self.lights[i:i + MAX_LIGHTS] for i in range(0, len(self.lights), MAX_LIGHTS)] or [[]]
        self._group_uniforms = [light_uniforms(g) for g in self.light_groups]
        self.light_uniforms = self._group_uniforms[0]
        self._shadow_textures: list[dict] = []       # per group: uShadowMask0 / uShadowMask1
        self._albedo = None                          # (H, W, 3) float32: the CPU sum of the groups' radiance
        self.vert = preprocess("fullscreen.vert.glsl", self.sources, target="desktop").code
        self.programs: dict[str, object] = {}
        self.modes: dict[str, ModeResources] = {}
        self.mode_textures: dict[str, dict] = {}
        self._gbuf: dict = {}
        self._fbo = None
        self._size = None
        self._vaos: dict = {}
        self._dummies: dict = {}
        self.set_frame(frame)

    # ------------------------------------------------------------------ setup
    def set_frame(self, frame=None) -> None:
        """Set the bake frame (:func:`frame_matrix`: (3, 3) row-major world -> bake, or None = identity) for the
        following draws: the mode is evaluated at (M·p, M·n, M·v) of the world G-buffer and eye."""
        self.frame = frame_matrix(frame)
        # GLSL mat3 is column-major: the bytes of Mᵀ in C order are M's columns, so uGiFrame * p == M @ p
        self._frame_uniform = np.ascontiguousarray(self.frame.T, np.float32)

    def _key(self, mode: str, defines: dict | None = None) -> tuple:
        """(mode, defines) of a compiled pass; defines default to those of the mode's resources."""
        if defines is None:
            defines = self.modes[mode].defines if mode in self.modes else {}
        return mode, tuple(sorted(defines.items()))

    def program(self, mode: str, defines: dict | None = None):
        """The compiled pass of ``mode`` with the extra ``defines`` (default: those of the mode's resources
        set by :meth:`set_mode`, else none); compiled once per (mode, defines)."""
        key = self._key(mode, defines)
        defines = dict(key[1])
        if key not in self.programs:
            pre = preprocess("deferred.frag.glsl", self.sources, target="desktop", slots={"mode": f"mode_{mode}.glsl"},
                             defines={"MAX_LIGHTS": MAX_LIGHTS, **defines})
            try:
                prog = self.ctx.program(vertex_shader=self.vert, fragment_shader=pre.code)
            except Exception as exc:  # moderngl raises plain Errors with the driver log
                raise ShaderSourceError(f"mode {mode}: GLSL compile failed:\n{format_compile_errors(str(exc), pre)}"
                                        ) from exc
            self.programs[key] = prog
            self._vaos[key] = self.ctx.vertex_array(prog, [])
        return self.programs[key]

    def _vao(self, mode: str):
        return self._vaos[self._key(mode)]

    def _texture(self, array: np.ndarray, linear: bool):
        a = np.ascontiguousarray(array)
        if a.dtype == np.float64:
            a = a.astype(np.float32)
        dtype = {np.dtype(np.float32): "f4", np.dtype(np.uint8): "f1", np.dtype(np.float16): "f2"}[a.dtype]
        if a.ndim == 4:
            D, H, W, C = a.shape
            tex = self.ctx.texture3d((W, H, D), C, a.tobytes(), dtype=dtype)
            tex.repeat_z = False
        else:
            if a.ndim == 2:
                a = a[..., None]
            H, W, C = a.shape
            tex = self.ctx.texture((W, H), C, a.tobytes(), dtype=dtype)
        tex.repeat_x = tex.repeat_y = False
        f = self._mgl.LINEAR if linear else self._mgl.NEAREST
        tex.filter = (f, f)
        return tex

    def set_mode(self, res: ModeResources) -> None:
        """Upload a mode's textures (replacing an earlier upload of the same mode) and compile its program."""
        for t in self.mode_textures.pop(res.mode, {}).values():
            t.release()
        self.program(res.mode, res.defines)
        self.modes[res.mode] = res
        self.mode_textures[res.mode] = {u: self._texture(a, lin) for u, (a, lin) in res.textures.items()}

    def set_gbuffer(self, g: GBufferInputs) -> None:
        """Upload a G-buffer (and its shadow masks) and size the target."""
        for t in list(self._gbuf.values()) + [t for d in self._shadow_textures for t in d.values()]:
            t.release()
        H, W = g.shape
        L = len(self.lights)
        pos = np.zeros((H, W, 4), np.float32)
        pos[..., :3] = g.position
        pos[..., 3] = np.asarray(g.shaded, np.float32)

        def rgba(a):
            out = np.zeros((H, W, 4), np.float32)
            out[..., :3] = a
            return out

        G = len(self.light_groups)
        sm = np.full((H, W, G * MAX_LIGHTS), 255, np.uint8)       # lights 8g .. 8g+7 in group g's two textures
        if g.shadow is not None and L:
            sm[..., :L] = np.round(np.clip(np.asarray(g.shadow, np.float64).reshape(H, W, L), 0, 1) * 255)
        self._gbuf = {"uGPosition": self._texture(pos, False), "uGNormal": self._texture(rgba(g.normal), False),
                      "uGAlbedo": self._texture(rgba(g.albedo), False),
                      "uGEmission": self._texture(rgba(g.emission), False)}
        self._shadow_textures = [{"uShadowMask0": self._texture(sm[..., 8 * k:8 * k + 4], False),
                                  "uShadowMask1": self._texture(sm[..., 8 * k + 4:8 * k + 8], False)}
                                 for k in range(G)]
        self._albedo = np.asarray(g.albedo, np.float32).reshape(H, W, 3) if G > 1 else None
        if self._size != (W, H):
            if self._fbo is not None:
                self._fbo.release()
                self._target.release()
            self._target = self.ctx.texture((W, H), 4, dtype="f4")
            self._fbo = self.ctx.framebuffer(color_attachments=[self._target])
            self._size = (W, H)

    def _bind(self, mode: str, output: int, eye, group: int = 0) -> None:
        prog = self.program(mode)
        res = self.modes.get(mode) or ModeResources(mode)
        unit = 0
        bound = set()
        shadow = self._shadow_textures[group] if self._shadow_textures else {}
        for name, tex in (list(self._gbuf.items()) + list(shadow.items())
                          + list(self.mode_textures.get(mode, {}).items())):
            if name in prog:
                tex.use(location=unit)
                prog[name].value = unit
                bound.add(name)
                unit += 1
        # samplers the mode declares but this bake lacks (the K > 4 atlas, weights of plain mask GI) still need
        # a texture of their type on their unit: two sampler types on one unit make the draw fail
        for name in prog:
            u = prog[name]
            kind = _SAMPLER_TYPES.get(getattr(u, "gl_type", None))
            if kind and name not in bound:
                self._dummy(kind).use(location=unit)
                u.value = unit
                unit += 1
        values = {**self._group_uniforms[group], **res.uniforms, "uEye": tuple(float(x) for x in eye),
                  "uOutput": int(output),
                  "uGiFrame": self._frame_uniform}
        for name, v in values.items():
            if name not in prog:
                continue
            if isinstance(v, np.ndarray):
                prog[name].write(np.ascontiguousarray(v, np.float32 if v.dtype.kind == "f" else v.dtype).tobytes())
            else:
                prog[name].value = v

    def _dummy(self, kind: str):
        if kind not in self._dummies:
            if kind == "3d":
                self._dummies[kind] = self.ctx.texture3d((1, 1, 1), 4, bytes(16), dtype="f4")
            else:
                self._dummies[kind] = self.ctx.texture((1, 1), 4, bytes(16), dtype="f4")
        return self._dummies[kind]

    def _draw(self, mode: str, output: int, eye, group: int) -> None:
        self._bind(mode, output, eye, group)
        self._fbo.use()
        self.ctx.viewport = (0, 0, *self._size)
        self.ctx.disable(self._mgl.DEPTH_TEST | self._mgl.BLEND)
        self._vao(mode).render(self._mgl.TRIANGLES, vertices=3)

    def _read(self) -> np.ndarray:
        W, H = self._size
        a = np.frombuffer(self._target.read(), np.float32).reshape(H, W, 4)
        return np.ascontiguousarray(a[..., :3])

    def draw(self, mode: str, output: int = 0, eye=(0.0, 0.0, 0.0)) -> None:
        """Render the pass into the target (no read back, no finish): one draw per light group (a scene with more
        than :data:`MAX_LIGHTS` lights pays a pass per group, E_direct alone after the first, as :meth:`render`
        does; the target then holds the last group's)."""
        self._draw(mode, output, eye, 0)
        for k in range(1, len(self.light_groups)):
            self._draw(mode, 2, eye, k)

    def render(self, mode: str, output: int = 0, eye=(0.0, 0.0, 0.0)) -> np.ndarray:
        """(H, W, 3) float32: radiance (output 0), E_indirect (1) or E_direct (2), row 0 = top.

        With more than :data:`MAX_LIGHTS` lights, one pass per group of 8: E_direct is the sum of the groups'
        E_direct, E_indirect the first pass's (it does not depend on the lights: the PRT mode's coefficients hold
        all of them), and the radiance the first pass's (emission, its lights, the GI) plus ``albedo/π ·
        E_direct`` of every further group (the G-buffer's albedo, float32 sums on the CPU)."""
        self._draw(mode, output, eye, 0)
        out = self._read()
        if output == 1 or len(self.light_groups) == 1:
            return out
        extra = np.zeros_like(out)
        for k in range(1, len(self.light_groups)):
            self._draw(mode, 2, eye, k)
            extra += self._read()
        if output == 2:
            return out + extra
        return out + self._albedo * np.float32(1.0 / math.pi) * extra

    def time_pass(self, mode: str, eye=(0.0, 0.0, 0.0), repeats: int = 5) -> dict:
        """Wall time of the whole pass (draw + ctx.finish()), one warm-up, then ``repeats``: median, min, all."""
        self.draw(mode, 0, eye)
        self.ctx.finish()
        times = []
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            self.draw(mode, 0, eye)
            self.ctx.finish()
            times.append(time.perf_counter() - t0)
        return {"median_s": statistics.median(times), "min_s": min(times), "repeats": len(times)}

    def time_passes(self, modes, eye=(0.0, 0.0, 0.0), repeats: int = 5, warmup: bool = True) -> dict:
        """:meth:`time_pass` of several modes measured side by side: one warm-up each (``warmup``; skip it when
        the same modes were just drawn, e.g. for another camera), then ``repeats`` rounds that time every mode once
        in turn, so load from other processes on this shared machine falls on all modes alike and their ratios
        hold. Returns ``{mode: {median_s, min_s, repeats}}``."""
        modes = list(modes)
        for m in modes if warmup else ():
            self.draw(m, 0, eye)
            self.ctx.finish()
        times = {m: [] for m in modes}
        for _ in range(max(1, int(repeats))):
            for m in modes:
                t0 = time.perf_counter()
                self.draw(m, 0, eye)
                self.ctx.finish()
                times[m].append(time.perf_counter() - t0)
        return {m: {"median_s": statistics.median(t), "min_s": min(t), "repeats": len(t)} for m, t in times.items()}

    def release(self) -> None:
        for texs in self.mode_textures.values():
            for t in texs.values():
                t.release()
        for t in list(self._gbuf.values()) + [t for d in self._shadow_textures for t in d.values()]:
            t.release()
        for v in list(self._vaos.values()) + list(self._dummies.values()):
            v.release()
        for p in self.programs.values():
            p.release()
        if self._fbo is not None:
            self._fbo.release()
            self._target.release()
        self.mode_textures, self._gbuf, self._vaos, self.programs, self._shadow_textures = {}, {}, {}, {}, []
        if self._own_ctx:
            self.ctx.release()
