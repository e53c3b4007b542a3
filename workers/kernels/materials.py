"""glTF materials at ray hits: the diffuse GI albedo, emission and alpha of a surface point.

One place for what every ray-hit consumer (light, visibility, relocation, PRT, the evaluate path tracer
and the cutout ray caster) reads of a material, so all of them read the scene the same way.

At a hit on triangle t with barycentrics (1 - u - v, u, v) and texture coordinates ``uv`` (the material's
UV set, :mod:`workers.scene`):

- base colour ``c = baseColorFactor × texture(uv) × COLOR_0`` (RGBA; texture RGB sRGB-decoded, alpha
  linear; COLOR_0 interpolated at the hit) — [glTF] 3.9.2 and 3.7.2.1;
- metallic ``m = metallicFactor × B(mrTexture)``, roughness ``r = roughnessFactor × G(mrTexture)``
  (the metallic-roughness texture is linear) — [glTF] 3.9.2;
- diffuse albedo ``c_diff = c.rgb × (1 - m)`` — [glTF] Appendix B (``c_diff = lerp(baseColor, black, m)``);
- the GI albedo adds a diffuse equivalent of the specular reflection, as engines' GI passes do (Unity's
  meta pass, ``UnityLightmappingAlbedo``: ``albedo = diffuse + specular × roughness / 2`` with Unity's
  roughness = perceptual² = ``r²`` and ``specular = F0 = lerp(0.04, c.rgb, m)``). ``specular_gi`` picks how
  much of it (the bake config's ``scene.specular_gi``):

  * ``"metals"`` (default): the metallic lobe only, ``c.rgb × m × r² / 2``: a dielectric is exactly
    glTF's diffuse term (what an outside path tracer's Lambert reference bakes), a rough metal scatters
    light as in Unity (a rough white metal: 0.5), a mirror-smooth one adds nothing (a diffuse bake
    cannot carry a mirror's directional reflection);
  * ``"all"``: Unity's formula as written, ``F0 × r² / 2`` (dielectrics gain up to 0.02);
  * ``"none"``: glTF's diffuse term alone.

- emission ``emissiveFactor × strength × texture(uv)`` (sRGB-decoded) — [glTF] 3.9.3,
  KHR_materials_emissive_strength;
- alpha ``c.a``; with alphaMode MASK the surface exists where ``alpha >= alphaCutoff`` ([glTF] 3.9.6:
  "rendered fully opaque if alpha >= cutoff, else fully transparent"); BLEND is baked as a cutout at
  0.5 (ingest warns; a probe bake has no order-dependent blending to offer).

Optionally the albedo is clamped per channel to ``scene.max_albedo`` (off by default: a closed room of
albedo 1 makes the bounce series diverge, which the bake reports as a warning instead).

Materials stored before metallic and alpha existed read as metallic 0 and opaque (their albedo then was
the base colour).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.kernels.shading import sample_texture_rgba

__all__ = ["MaterialTable", "material_table", "gi_albedo", "surface_materials", "cutout_materials",
           "opaque_at_hits", "double_sided_triangles", "albedo_report", "albedo_warnings", "SPECULAR_GI_MODES", "ALBEDO_WARN"]

SPECULAR_GI_MODES = ("metals", "all", "none")

ALBEDO_WARN = 0.95
"""A diffuse GI albedo at or above this (any channel) is physically implausible and is warned about."""

DIELECTRIC_F0 = 0.04
"""Normal-incidence reflectance of glTF's dielectric ([glTF] Appendix B: ``f0 = 0.04``)."""


@dataclass(frozen=True)
class MaterialTable:
    """Per-material arrays (M materials): the numbers :func:`surface_materials` needs."""

    base: np.ndarray            # (M, 4) float64 base colour factor, linear RGBA
    emissive: np.ndarray        # (M, 3) float64 emissive factor × strength
    metallic: np.ndarray        # (M,) float64
    roughness: np.ndarray       # (M,) float64 perceptual (glTF's)
    base_tex: np.ndarray        # (M,) int64 texture index or -1
    emissive_tex: np.ndarray    # (M,) int64
    mr_tex: np.ndarray          # (M,) int64
    cutoff: np.ndarray          # (M,) float64 alpha cutoff; -inf for opaque materials
    double_sided: np.ndarray    # (M,) bool


def _tex(m: dict, key: str) -> int:
    v = m.get(key)
    return -1 if v is None else int(v)


def material_table(materials: list[dict]) -> MaterialTable:
    """The per-material arrays of a scene's material dicts (:mod:`workers.scene`)."""
    def cutoff(m):
        mode = m.get("alpha_mode", "OPAQUE")
        if mode == "MASK":
            return float(m.get("alpha_cutoff", 0.5))
        if mode == "BLEND":
            return 0.5
        return -np.inf

    return MaterialTable(
        base=np.array([list(m["base_color"]) + [1.0] * (4 - len(m["base_color"])) for m in materials],
                      np.float64).reshape(-1, 4),
        emissive=np.array([m.get("emissive", [0, 0, 0]) for m in materials], np.float64).reshape(-1, 3),
        metallic=np.array([float(m.get("metallic", 0.0)) for m in materials], np.float64),
        roughness=np.array([float(m.get("roughness", 1.0)) for m in materials], np.float64),
        base_tex=np.array([_tex(m, "base_color_texture") for m in materials], np.int64),
        emissive_tex=np.array([_tex(m, "emissive_texture") for m in materials], np.int64),
        mr_tex=np.array([_tex(m, "metallic_roughness_texture") for m in materials], np.int64),
        cutoff=np.array([cutoff(m) for m in materials], np.float64),
        double_sided=np.array([bool(m.get("double_sided", False)) for m in materials], bool),
    )


def gi_albedo(base_rgb, metallic, roughness, specular_gi: str = "metals") -> np.ndarray:
    """Diffuse GI albedo (N, 3) from base colour (N, 3), metallic (N,) and perceptual roughness (N,).

    ``base × (1 - m)`` ([glTF] Appendix B) plus the specular diffuse equivalent chosen by ``specular_gi``
    (module doc; Unity's meta pass ``specular × roughness² / 2``).
    """
    base_rgb = np.asarray(base_rgb, np.float64)
    m = np.asarray(metallic, np.float64)[:, None]
    a = np.asarray(roughness, np.float64)[:, None] ** 2          # Unity's roughness: perceptual²
    diffuse = base_rgb * (1.0 - m)
    if specular_gi == "none":
        return diffuse
    if specular_gi == "metals":
        return diffuse + base_rgb * m * a * 0.5
    if specular_gi == "all":
        f0 = DIELECTRIC_F0 * (1.0 - m) + base_rgb * m              # lerp(0.04, base, m)
        return diffuse + f0 * a * 0.5
    raise ValueError(f"specular_gi must be one of {SPECULAR_GI_MODES}, got {specular_gi!r}")


def _corner_mix(arr: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Barycentric mix of per-corner values ``arr[t]`` (H, 3, C) at (1 - u - v, u, v): (H, C) float64."""
    c = arr[t].astype(np.float64)
    b0 = (1.0 - u - v)[:, None]
    return b0 * c[:, 0] + u[:, None] * c[:, 1] + v[:, None] * c[:, 2]


def _interp_uv(scene, t, u, v) -> np.ndarray:
    return _corner_mix(np.asarray(scene.uv0), t, u, v)


def surface_materials(scene, t, u, v, uv=None, table: MaterialTable | None = None,
                      specular_gi: str = "metals", max_albedo: float | None = None) -> dict:
    """Material values at H hits (all hits, no misses): ``t`` (H,) triangle, ``u, v`` (H,) barycentrics.

    ``uv`` (H, 2): the interpolated ``uv0`` if already known. Returns float64 arrays ``albedo`` (H, 3)
    (the diffuse GI albedo of the module doc, clamped to ``max_albedo`` when given), ``emission`` (H, 3),
    ``alpha`` (H,), ``cutoff`` (H,) (-inf where opaque), ``double_sided`` (H,) bool, ``material`` (H,).
    """
    t = np.asarray(t, np.int64)
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    tab = material_table(scene.materials) if table is None else table
    if uv is None:
        uv = _interp_uv(scene, t, u, v)
    mat = np.asarray(scene.material)[t].astype(np.int64)
    base = tab.base[mat].copy()
    emission = tab.emissive[mat].copy()
    metallic = tab.metallic[mat].copy()
    rough = tab.roughness[mat].copy()
    for tid_all, srgb, apply in ((tab.base_tex, True, "base"), (tab.emissive_tex, True, "emission"),
                                 (tab.mr_tex, False, "mr")):
        tid = tid_all[mat]
        for k in np.unique(tid[tid >= 0]):           # one texture at a time, all its hits at once
            sel = np.flatnonzero(tid == k)
            texel = sample_texture_rgba(scene.textures[int(k)], uv[sel], srgb=srgb)
            if apply == "base":
                base[sel] *= texel
            elif apply == "emission":
                emission[sel] *= texel[:, :3]
            else:                                     # [glTF] 3.9.2: G = roughness, B = metallic
                rough[sel] *= texel[:, 1]
                metallic[sel] *= texel[:, 2]
    colors = getattr(scene, "colors", None)
    if colors is not None:
        base *= _corner_mix(np.asarray(colors), t, u, v)
    albedo = gi_albedo(base[:, :3], metallic, rough, specular_gi)
    if max_albedo is not None:
        albedo = np.minimum(albedo, float(max_albedo))
    return {"albedo": albedo, "emission": emission, "alpha": base[:, 3], "cutoff": tab.cutoff[mat],
            "double_sided": tab.double_sided[mat], "material": mat}


def albedo_report(scene, specular_gi: str = "metals") -> list[dict]:
    """The brightest diffuse GI albedo each used material can reach, before any clamp.

    Per material: ``base factor × (brightest texel per channel) × (largest COLOR_0 per channel on its
    triangles)``, through :func:`gi_albedo` at its metallic and roughness factors (× the texture's
    brightest where a metallic-roughness texture scales them: an upper bound). Returns
    ``[{"material", "name", "max_albedo" (max over channels), "triangles"}]`` for materials with triangles.
    """
    tab = material_table(scene.materials)
    mat = np.asarray(scene.material).astype(np.int64)
    counts = np.bincount(mat, minlength=len(scene.materials))
    colors = getattr(scene, "colors", None)
    out = []
    for i, m in enumerate(scene.materials):
        if counts[i] == 0:
            continue
        c = tab.base[i, :3].copy()
        if tab.base_tex[i] >= 0:
            tex = np.asarray(scene.textures[int(tab.base_tex[i])])
            rgb = tex[..., :3] if tex.ndim == 3 and tex.shape[2] >= 3 else tex.reshape(tex.shape[0], tex.shape[1], -1)[..., :1]
            c *= sample_lut_max(rgb)
        if colors is not None:
            c *= np.asarray(colors)[mat == i][..., :3].reshape(-1, 3).max(axis=0)
        metal, rough = tab.metallic[i], tab.roughness[i]
        if tab.mr_tex[i] >= 0:                        # any metallic in [0, factor]: take the brighter end
            alb = np.maximum(gi_albedo(c[None], [0.0], [rough], specular_gi),
                             gi_albedo(c[None], [metal], [rough], specular_gi))[0]
        else:
            alb = gi_albedo(c[None], [metal], [rough], specular_gi)[0]
        out.append({"material": i, "name": m.get("name", f"material_{i}"), "max_albedo": float(alb.max()),
                    "triangles": int(counts[i])})
    return out


def sample_lut_max(rgb: np.ndarray) -> np.ndarray:
    """(3,) the brightest linear value per channel of an sRGB-encoded uint8 image (H, W, 1|3)."""
    from workers.kernels.shading import SRGB_TO_LINEAR_LUT

    mx = np.asarray(rgb).reshape(-1, rgb.shape[-1]).max(axis=0)
    return np.resize(SRGB_TO_LINEAR_LUT[mx], 3)


def albedo_warnings(scene, max_albedo: float | None, specular_gi: str = "metals") -> list[dict]:
    """``albedo_high`` (any material reaching :data:`ALBEDO_WARN`, no clamp set) or ``albedo_clamped``
    (materials above ``max_albedo``, which the bake clamped) as ``{code, message}`` dicts."""
    rep = albedo_report(scene, specular_gi)
    if max_albedo is not None:
        over = [r for r in rep if r["max_albedo"] > max_albedo]
        if not over:
            return []
        names = ", ".join(f"{r['name']} ({r['max_albedo']:.2f})" for r in over[:5]) + (" ..." if len(over) > 5 else "")
        return [{"code": "albedo_clamped", "message": (
            f"{len(over)} material(s) had a diffuse albedo above scene.max_albedo = {max_albedo:g} and were clamped "
            f"to it: {names}")}]
    high = [r for r in rep if r["max_albedo"] >= ALBEDO_WARN]
    if not high:
        return []
    names = ", ".join(f"{r['name']} ({r['max_albedo']:.2f})" for r in high[:5]) + (" ..." if len(high) > 5 else "")
    return [{"code": "albedo_high", "message": (
        f"{len(high)} material(s) reflect {ALBEDO_WARN:.0%} or more of the light (no real surface does; kept as the "
        f"file says): {names}. Bounced light in a closed room of such surfaces converges slowly or not at all; "
        "set scene.max_albedo (e.g. 0.9) to clamp")}]


def double_sided_triangles(scene) -> np.ndarray:
    """(T,) bool: the triangle's material is double-sided (its back faces count as front faces)."""
    flags = np.array([bool(m.get("double_sided", False)) for m in scene.materials] or [False], bool)
    return flags[np.asarray(scene.material)]


def cutout_materials(scene) -> np.ndarray:
    """(M,) bool: which materials are cutouts (alphaMode MASK, or BLEND baked as a cutout)."""
    return np.isfinite(material_table(scene.materials).cutoff)


def opaque_at_hits(scene, t, u, v, table: MaterialTable | None = None) -> np.ndarray:
    """(H,) bool: whether each hit is on the surface (True) or falls in a cutout's hole (False).

    [glTF] 3.9.6: with alphaMode MASK a fragment exists iff ``alpha >= alphaCutoff``; alpha is the base
    colour's (factor × texture × COLOR_0) at the hit.
    """
    tab = material_table(scene.materials) if table is None else table
    t = np.asarray(t, np.int64)
    out = np.ones(t.shape[0], bool)
    mat = np.asarray(scene.material)[t].astype(np.int64)
    cut = np.flatnonzero(np.isfinite(tab.cutoff[mat]))
    if cut.size == 0:
        return out
    tc, uc, vc = t[cut], np.asarray(u, np.float64)[cut], np.asarray(v, np.float64)[cut]
    m = mat[cut]
    alpha = tab.base[m, 3].copy()
    tid = tab.base_tex[m]
    if (tid >= 0).any():
        uv = _interp_uv(scene, tc, uc, vc)
        for k in np.unique(tid[tid >= 0]):
            sel = np.flatnonzero(tid == k)
            alpha[sel] *= sample_texture_rgba(scene.textures[int(k)], uv[sel])[:, 3]
    colors = getattr(scene, "colors", None)
    if colors is not None:
        alpha *= _corner_mix(np.asarray(colors)[:, :, 3:4], tc, uc, vc)[:, 0]
    out[cut] = alpha >= tab.cutoff[m]
    return out
