"""Surface attributes at ray hits and direct light from punctual lights (numpy; no I/O).

The light stage (DESIGN.md "Bake stages" 2, DDGI-I §3.4) shades every probe ray's hit as

    L_out = emission + albedo / π · (E_direct + E_indirect)

with ``E_direct`` from :func:`direct_irradiance` (this module) and ``E_indirect`` from the previous
bounce's probes (:func:`workers.kernels.ddgi.sample_irradiance`). This module supplies the hit's
surface attributes (:func:`surface_at_hits`) and ``E_direct``.

Conventions
-----------
- World space, metres, glTF frame (+Y up, right-handed), counter-clockwise front faces.
- Barycentrics as :class:`workers.raycast.Hits`: ``x = (1 - u - v)·v0 + u·v1 + v·v2``.
- Colours are linear RGB. Textures are stored sRGB-encoded uint8 (glTF base colour and emissive
  textures are sRGB, glTF 2.0 §3.9.2/§3.9.3); each texel is decoded to linear *before* bilinear
  filtering, as a GPU sampler of an ``*_SRGB`` format does.
- Texture coordinates: glTF UV (0, 0) is the first texel of the image's first row (top-left),
  u runs along columns, v along rows. Texel (row r, col c) of an H x W image is centred at
  ``u = (c + 0.5)/W, v = (r + 0.5)/H``. Wrap mode REPEAT on both axes (the glTF default sampler);
  the material's sampler settings and the alpha channel are not used.
- Light units (KHR_lights_punctual): point and spot ``intensity`` in candela (lm/sr), directional
  in lux (lm/m²); ``color`` is a linear RGB multiplier. Irradiance is returned in lux·colour, i.e.
  W/m²-like units consistent with the light intensities; a Lambertian surface then reflects
  radiance ``albedo/π · E``.

Bent shading normals (interpolated normals that lean away from the geometric one): Kiln shades path vertices and
probe-ray hits as Blender Cycles 3.4 does (intern/cycles/kernel/svm/closure.h, closure/bsdf_util.h,
closure/bsdf.h): the closure normal ``N' = ensure_valid_reflection(Ng, I, N)`` (:func:`ensure_valid_reflection`),
lights below the geometric plane give 0, and where N' differs from N the diffuse evaluation is multiplied by
the bump shadowing term (:func:`bump_shadowing_term`); :func:`horizon_factor` is the part of uniform incident light
such a surface keeps (used for the light stage's probe-interpolated E_indirect). :func:`direct_irradiance` applies
the frame when given ``geo_normals`` / ``smooth_normals`` / ``bent``; without them it is unchanged.

Consumers: stages/light (ray shading), stages/evaluate (reference path tracer), stages/prt
(direct light at measurement points). Inverse: none.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from workers.kernels.chunks import map_chunks

__all__ = ["srgb_to_linear", "SRGB_TO_LINEAR_LUT", "surface_at_hits", "sample_texture", "direct_irradiance",
           "ensure_valid_reflection", "bump_shadowing_term", "horizon_factor"]

# Points per chunk of direct_irradiance: bounds the float64 temporaries (~60 doubles per point)
# and the shadow-ray batch, whatever the number of points.
DIRECT_CHUNK = 1 << 17


def srgb_to_linear(c) -> np.ndarray:
    """sRGB electro-optical transfer (IEC 61966-2-1): encoded [0, 1] -> linear [0, 1], float64.

    ``c / 12.92`` for ``c <= 0.04045``, else ``((c + 0.055) / 1.055) ** 2.4``.
    """
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# uint8 code -> linear value, float64 (256,): texels are decoded by table lookup.
SRGB_TO_LINEAR_LUT = srgb_to_linear(np.arange(256) / 255.0)


def _unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length; zero rows stay zero."""
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, REPEAT-wrapped lookup of an sRGB-encoded texture, decoded to linear RGB.

    Parameters
    ----------
    texture : (H, W, C>=3) uint8
        sRGB-encoded texels (the scene's ``textures[i]``); only RGB is read.
    uv : (N, 2) float
        glTF texture coordinates (see module doc: v = 0 is the image's first row).

    Returns
    -------
    rgb : (N, 3) float64, linear. Each of the 4 texels is decoded sRGB -> linear, then they are
    weighted bilinearly (texel centres at ``(index + 0.5) / size``), so at a texel centre the
    result is exactly that texel's decoded colour.
    """
    return sample_texture_rgba(texture, uv, srgb=True)[:, :3]


_LINEAR_LUT = np.arange(256) / 255.0


def sample_texture_rgba(texture: np.ndarray, uv: np.ndarray, srgb: bool = True) -> np.ndarray:
    """Bilinear, REPEAT-wrapped RGBA lookup: (N, 4) float64 in [0, 1].

    RGB is decoded sRGB -> linear per texel when ``srgb`` (base colour, emissive: [glTF] 3.9.2), read as
    stored otherwise (metallic-roughness, a linear texture). Alpha is always linear ([glTF] 3.9.6).
    A texture without an alpha channel reads alpha 1; a grey (H, W) or (H, W, 1) one repeats its channel.
    """
    tex = np.asarray(texture)
    if tex.ndim == 2:
        tex = tex[:, :, None]
    h, w = tex.shape[:2]
    rgb = tex[:, :, :3] if tex.shape[2] >= 3 else np.repeat(tex[:, :, :1], 3, axis=2)
    alpha = tex[:, :, 3] if tex.shape[2] >= 4 else (tex[:, :, 1] if tex.shape[2] == 2 else None)
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[:, 0] * w - 0.5  # continuous column index, texel centres at integers
    y = uv[:, 1] * h - 0.5  # continuous row index
    x0f, y0f = np.floor(x), np.floor(y)
    fx, fy = (x - x0f)[:, None], (y - y0f)[:, None]
    x0 = np.mod(x0f, w).astype(np.intp)  # REPEAT wrap
    y0 = np.mod(y0f, h).astype(np.intp)
    x1 = (x0 + 1) % w
    y1 = (y0 + 1) % h
    lut = SRGB_TO_LINEAR_LUT if srgb else _LINEAR_LUT

    def texel(r, c):
        out = np.empty((r.shape[0], 4))
        out[:, :3] = lut[rgb[r, c]]
        out[:, 3] = 1.0 if alpha is None else _LINEAR_LUT[alpha[r, c]]
        return out

    top = texel(y0, x0) * (1.0 - fx) + texel(y0, x1) * fx
    bottom = texel(y1, x0) * (1.0 - fx) + texel(y1, x1) * fx
    return top * (1.0 - fy) + bottom * fy


@numba.njit(cache=True, nogil=True)
def _interpolate_hits(tris, normals, uv0, t, u, v):  # pragma: no cover - compiled
    """Per hit h on triangle t[h] with barycentrics (1 − u − v, u, v): world position, unit geometric
    normal ``(v1 − v0) × (v2 − v0)`` (0 when degenerate), unit interpolated vertex normal (the geometric
    one where that is 0), interpolated uv0. float64 arithmetic on the float32 scene arrays."""
    H = t.shape[0]
    pos = np.empty((H, 3))
    geo = np.empty((H, 3))
    nrm = np.empty((H, 3))
    uv = np.empty((H, 2))
    for h in range(H):
        k = t[h]
        b0 = 1.0 - u[h] - v[h]
        b1 = u[h]
        b2 = v[h]
        for a in range(3):
            pos[h, a] = b0 * np.float64(tris[k, 0, a]) + b1 * np.float64(tris[k, 1, a]) + b2 * np.float64(tris[k, 2, a])
        e1x = np.float64(tris[k, 1, 0]) - np.float64(tris[k, 0, 0])
        e1y = np.float64(tris[k, 1, 1]) - np.float64(tris[k, 0, 1])
        e1z = np.float64(tris[k, 1, 2]) - np.float64(tris[k, 0, 2])
        e2x = np.float64(tris[k, 2, 0]) - np.float64(tris[k, 0, 0])
        e2y = np.float64(tris[k, 2, 1]) - np.float64(tris[k, 0, 1])
        e2z = np.float64(tris[k, 2, 2]) - np.float64(tris[k, 0, 2])
        gx = e1y * e2z - e1z * e2y
        gy = e1z * e2x - e1x * e2z
        gz = e1x * e2y - e1y * e2x
        gl = math.sqrt(gx * gx + gy * gy + gz * gz)
        if gl > 0:
            gx, gy, gz = gx / gl, gy / gl, gz / gl
        else:
            gx, gy, gz = 0.0, 0.0, 0.0
        geo[h, 0], geo[h, 1], geo[h, 2] = gx, gy, gz
        nx = b0 * np.float64(normals[k, 0, 0]) + b1 * np.float64(normals[k, 1, 0]) + b2 * np.float64(normals[k, 2, 0])
        ny = b0 * np.float64(normals[k, 0, 1]) + b1 * np.float64(normals[k, 1, 1]) + b2 * np.float64(normals[k, 2, 1])
        nz = b0 * np.float64(normals[k, 0, 2]) + b1 * np.float64(normals[k, 1, 2]) + b2 * np.float64(normals[k, 2, 2])
        nl = math.sqrt(nx * nx + ny * ny + nz * nz)
        if nl > 0:
            nrm[h, 0], nrm[h, 1], nrm[h, 2] = nx / nl, ny / nl, nz / nl
        else:
            nrm[h, 0], nrm[h, 1], nrm[h, 2] = gx, gy, gz
        for a in range(2):
            uv[h, a] = b0 * np.float64(uv0[k, 0, a]) + b1 * np.float64(uv0[k, 1, a]) + b2 * np.float64(uv0[k, 2, a])
    return pos, geo, nrm, uv


def surface_at_hits(scene, tri, u, v) -> dict:
    """Surface attributes at ray hits (the G-buffer of DDGI-I §3.3 "surfels").

    Parameters
    ----------
    scene : workers.scene.NormalizedScene
    tri : (N,) int
        Hit triangle index, -1 for a miss (``Hits.tri``).
    u, v : (N,) float
        Barycentrics (``Hits.u``, ``Hits.v``): ``x = (1 - u - v)·v0 + u·v1 + v·v2``.

    Returns
    -------
    dict of arrays (misses are all zeros / False):

    - ``position`` (N, 3) float32: world-space hit point, metres.
    - ``normal`` (N, 3) float32: interpolated vertex normal, unit (the geometric normal where the
      interpolation is degenerate). Not flipped toward the ray: callers flip for backface hits.
    - ``geo_normal`` (N, 3) float32: unit ``(v1 - v0) × (v2 - v0)`` (CCW front face); zero for a
      degenerate triangle.
    - ``albedo`` (N, 3) float32: the diffuse GI albedo of :mod:`workers.kernels.materials` (base colour
      factor × texture × COLOR_0, × (1 − metallic), plus the specular diffuse equivalent; textures
      bilinear, REPEAT, sRGB -> linear per texel, at the interpolated ``uv0``).
    - ``emission`` (N, 3) float32: linear emitted radiance = ``emissive`` (already × strength) ×
      emissive texture (same sampling).
    - ``double_sided`` (N,) bool: the material's ``double_sided``.

    Textures are sampled one texture at a time over all hits that use it (vectorized).
    """
    tri = np.asarray(tri).astype(np.int64, copy=False).ravel()
    u = np.asarray(u, dtype=np.float64).ravel()
    v = np.asarray(v, dtype=np.float64).ravel()
    n = tri.shape[0]
    if u.shape != (n,) or v.shape != (n,):
        raise ValueError(f"surface_at_hits: tri, u, v must have the same length, got {tri.shape}, {u.shape}, {v.shape}")
    n_tri = scene.n_triangles
    if n and tri.max(initial=-1) >= n_tri:
        raise ValueError(f"surface_at_hits: triangle index {int(tri.max())} out of range for {n_tri} triangles")

    out = {
        "position": np.zeros((n, 3), np.float32),
        "normal": np.zeros((n, 3), np.float32),
        "geo_normal": np.zeros((n, 3), np.float32),
        "albedo": np.zeros((n, 3), np.float32),
        "emission": np.zeros((n, 3), np.float32),
        "double_sided": np.zeros(n, bool),
    }
    hit = np.flatnonzero(tri >= 0)
    if hit.size == 0:
        return out
    t = tri[hit]
    pos, geo, nrm, uv = _interpolate_hits(np.asarray(scene.triangles), np.asarray(scene.normals),
                                          np.asarray(scene.uv0), t, u[hit], v[hit])
    out["position"][hit] = pos
    out["geo_normal"][hit] = geo
    out["normal"][hit] = nrm

    from workers.kernels.materials import surface_materials   # (materials imports this module's sampler)

    m = surface_materials(scene, t, u[hit], v[hit], uv=uv, specular_gi=getattr(scene, "specular_gi", "metals"),
                          max_albedo=getattr(scene, "max_albedo", None))
    out["albedo"][hit] = m["albedo"]
    out["emission"][hit] = m["emission"]
    out["double_sided"][hit] = m["double_sided"]
    return out


# ---------------------------------------------------------------------------------------- direct light
def _spot_cosines(light) -> tuple[float, float]:
    inner = light.get("inner_cone_angle")
    outer = light.get("outer_cone_angle")
    inner = 0.0 if inner is None else float(inner)
    outer = math.pi / 4 if outer is None else float(outer)
    return math.cos(inner), math.cos(outer)


def _light_arrays(light):
    color = np.asarray(light.get("color", [1.0, 1.0, 1.0]), np.float64) * float(light.get("intensity", 1.0))
    rng = light.get("range")
    rng = float(rng) if rng is not None and np.isfinite(rng) and rng > 0 else None
    return color, rng


def direct_irradiance(points, normals, lights, caster, eps: float, *, geo_normals=None, smooth_normals=None,
                      bent=None) -> np.ndarray:
    """Irradiance from punctual lights with shadow rays (KHR_lights_punctual; DDGI-I §3.4.2).

    For each light and point x with unit normal n (world space):

    - point / spot at position p: ``l = (p - x)/d``, ``d = |p - x|``::

          E = color · I · max(0, n·l) / d² · W(d) · A(l)

      ``W(d) = clamp(1 - (d/range)⁴, 0, 1)²`` when the light has a range (else 1), and for a spot
      ``A = t²``, ``t = clamp((cos θ - cos θ_outer) / max(1e-3, cos θ_inner - cos θ_outer), 0, 1)``,
      ``cos θ = direction · (-l)`` (the KHR_lights_punctual reference implementation; the 1e-3 floor
      only matters for cones whose inner and outer angles nearly coincide). Point lights: A = 1.
    - directional with travel direction ω: ``E = color · I · max(0, n·(-ω))``.

    Shadows: a ray from ``o = x + eps·n`` toward the light, occluded in ``[0, tfar]`` with
    ``tfar = |p - o| - 2·eps`` (point, spot; direction ``(p - o)/|p - o|``) or ``inf`` (directional,
    direction ``-ω``). Only points with a non-zero unshadowed contribution cast rays.

    Bent shading normals (Cycles 3.4, closure/bsdf.h ``bsdf_eval``; used by the path tracer's vertices and the
    light stage's probe-ray hits): with ``geo_normals`` a light below the geometric plane (``Ng·l <= 0``) gives 0
    (a closed surface occludes it; Cycles' shadow rays skip their own triangle, so only an open sheet would differ),
    and rows with ``bent`` (``normals`` is N' of :func:`ensure_valid_reflection`, differing from the smooth
    normal) are multiplied by :func:`bump_shadowing_term` (smooth normal, N', l), as Cycles' diffuse closure
    evaluation is. Without them (the default) nothing changes.

    Parameters
    ----------
    points : (N, 3) float
        Shading points, world space, metres.
    normals : (N, 3) float
        Unit normals, facing the side being lit (flip them for back-face hits on double-sided
        surfaces before calling). Zero rows get zero irradiance.
    geo_normals : (N, 3) float, optional
        Unit geometric normals on the lit side: lights below them give 0.
    smooth_normals : (N, 3) float, optional; bent : (N,) bool, optional
        The interpolated normal before :func:`ensure_valid_reflection` and where it was bent: the bump
        shadowing term on those rows (both or neither).
    lights : list of dict
        The scene's lights (see :mod:`workers.scene`).
    caster : RayCaster or None
        ``occluded(origins, dirs, tfar)`` provider; ``None`` disables shadows.
    eps : float
        Shadow-ray offset along the normal, metres (scale it with the scene).

    Returns
    -------
    E : (N, 3) float32, linear RGB irradiance (lux × colour). Work proceeds in chunks of
    :data:`DIRECT_CHUNK` points, so memory stays bounded for millions of points.
    """
    pts = np.asarray(points)            # each chunk converted to float64 on its own (bounded temporaries)
    nrm = np.asarray(normals)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape:
        raise ValueError(f"direct_irradiance: points and normals must both be (N, 3), got {pts.shape}, {nrm.shape}")
    eps = float(eps)
    if not (eps >= 0 and np.isfinite(eps)):
        raise ValueError(f"direct_irradiance: eps must be finite and >= 0, got {eps}")
    n = pts.shape[0]
    out = np.zeros((n, 3), np.float32)

    def chunk(s: int, e: int) -> None:      # two chunks at a time (workers.kernels.chunks): shading while casting
        acc = np.zeros((e - s, 3), np.float64)
        frame = None
        if geo_normals is not None or bent is not None:     # the chunk's rows only, then float64
            frame = (None if geo_normals is None else np.asarray(geo_normals[s:e], np.float64),
                     None if bent is None else np.asarray(smooth_normals[s:e], np.float64),
                     None if bent is None else np.asarray(bent[s:e], bool))
        x, nx = np.asarray(pts[s:e], np.float64), np.asarray(nrm[s:e], np.float64)
        for light in lights:
            _add_light(acc, x, nx, light, caster, eps, frame)
        out[s:e] = acc

    map_chunks(chunk, n, DIRECT_CHUNK)
    return out


def _bent_scale(scale, lit, l, n, frame):
    """``scale`` (of the rows ``lit``) × [Ng·l > 0] × the bump shadowing term on bent rows (``frame`` = (Ng, smooth
    normal, bent) of the chunk, entries None when absent); l (3,) or (len(lit), 3)."""
    if frame is None:
        return scale
    ng, sm, bent = frame
    ll = np.broadcast_to(l, (lit.size, 3))
    if ng is not None:          # (a degenerate triangle's zero Ng tests nothing)
        g = ng[lit]
        scale = np.where((np.einsum("ij,ij->i", g, ll) > 0) | ~np.any(g != 0, axis=1), scale, 0.0)
    if bent is not None:
        b = np.flatnonzero(bent[lit])
        if b.size:
            scale = scale.copy()
            scale[b] *= bump_shadowing_term(sm[lit[b]], n[lit[b]], ll[b])
    return scale


def _add_light(acc, x, n, light, caster, eps, frame=None) -> None:
    """acc += E of one light at points x (chunk), with shadows; ``frame``: bent normals (:func:`_bent_scale`)."""
    kind = light["type"]
    color, rng = _light_arrays(light)
    if not np.any(color > 0):
        return
    if kind == "directional":
        l = -np.asarray(light["direction"], np.float64)
        l = l / np.linalg.norm(l)
        scale = n @ l  # n·(-ω)
        lit = np.flatnonzero(scale > 0)
        if lit.size == 0:
            return
        scale = _bent_scale(scale[lit], lit, l, n, frame)
        if caster is not None:
            o = x[lit] + eps * n[lit]
            d = np.broadcast_to(l, o.shape)
            blocked = np.asarray(caster.occluded(o, d, tfar=np.inf), bool)
            scale = np.where(blocked, 0.0, scale)
        acc[lit] += scale[:, None] * color
        return
    if kind not in ("point", "spot"):
        raise ValueError(f"direct_irradiance: unknown light type {kind!r}")

    p = np.asarray(light["position"], np.float64)
    if kind == "point" and rng is None:                 # the common case in one compiled pass (the same floats)
        _add_point_light(acc, x, n, p, color, caster, eps, frame)
    else:
        _add_local_light(acc, x, n, light, p, color, rng, caster, eps, frame)


def _add_local_light(acc, x, n, light, p, color, rng, caster, eps, frame) -> None:
    """:func:`_add_light` for a point or spot light at p (float64 (3,)) in numpy: any range, the spot's cone; the
    reference form of :func:`_add_point_light` (which gives its floats for a point light without range)."""
    kind = light["type"]
    to_light = p - x
    d2 = np.einsum("ij,ij->i", to_light, to_light)
    d = np.sqrt(d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        l = to_light / d[:, None]
        cos_n = np.einsum("ij,ij->i", n, l)
        scale = cos_n / d2  # I·max(0, n·l)/d² (inverse square, candela -> lux)
    ok = (d > 0) & (cos_n > 0)
    if rng is not None:
        win = np.clip(1.0 - (d / rng) ** 4, 0.0, 1.0) ** 2  # range window W(d)
        scale = scale * win
        ok &= win > 0
    if kind == "spot":
        cos_in, cos_out = _spot_cosines(light)
        sd = np.asarray(light["direction"], np.float64)
        sd = sd / np.linalg.norm(sd)
        with np.errstate(invalid="ignore"):
            cos_t = -(l @ sd)  # cos θ between the spot axis and light -> point
        t = np.clip((cos_t - cos_out) / max(1e-3, cos_in - cos_out), 0.0, 1.0)  # KHR angular attenuation
        scale = scale * t * t
        ok &= t > 0
    lit = np.flatnonzero(ok)
    if lit.size == 0:
        return
    scale = _bent_scale(scale[lit], lit, l[lit], n, frame)
    if caster is not None:
        o = x[lit] + eps * n[lit]
        ray = p - o
        dist = np.linalg.norm(ray, axis=1)
        tfar = dist - 2.0 * eps
        trace = np.flatnonzero(tfar > 0)  # a light closer than 2·eps to the origin is never shadowed
        if trace.size:
            blocked = np.asarray(
                caster.occluded(o[trace], ray[trace] / dist[trace, None], tfar=tfar[trace]), bool
            )
            scale[trace[blocked]] = 0.0
    acc[lit] += scale[:, None] * color


def _add_point_light(acc, x, n, p, color, caster, eps, frame) -> None:
    """:func:`_add_light` for a point light without range: the rows it lights, their cosine / distance² term with
    :func:`_bent_scale`'s frame and their shadow rays made by one compiled pass (:func:`_point_rows`) instead of
    some fifteen numpy passes over (N, 3) float64 arrays, with the same float64 operations, so the same floats."""
    m = x.shape[0]
    ng, sm, bent = frame if frame is not None else (None, None, None)
    has_ng, has_bent = ng is not None, bent is not None
    zero3, zerob = np.zeros((1, 3)), np.zeros(1, np.bool_)
    rows = np.empty(m, np.int64)
    scale = np.empty(m)
    trace = np.empty(m, np.bool_)
    o, d = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
    tfar = np.empty(m, np.float32)
    k = _point_rows(x, n, ng if has_ng else zero3, sm if has_bent else zero3, bent if has_bent else zerob,
                    has_ng, has_bent, p, float(eps), rows, scale, trace, o, d, tfar)
    if k == 0:
        return
    rows, scale = rows[:k], scale[:k]
    if caster is not None:
        t = np.flatnonzero(trace[:k])       # a light closer than 2·eps to the origin is never shadowed
        if t.size:
            blocked = np.asarray(caster.occluded(o[t], d[t], tfar=tfar[t]), bool)
            scale[t[blocked]] = 0.0
    acc[rows] += scale[:, None] * color


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _point_rows(x, n, ng, sm, bent, has_ng, has_bent, p, eps, rows, scale, trace, o, d, tfar):  # pragma: no cover
    """The rows a point light at p lights (``d > 0`` and ``n·l > 0``), in order: their index, ``cos/d²`` times
    :func:`_bent_scale`'s terms (Ng·l > 0 or a zero Ng; the bump term on bent rows), and the shadow ray from
    ``x + eps·n`` to p (float32 origin, unit direction and ``tfar = |p − o| − 2·eps`` as the caster rounds them;
    ``trace``: tfar > 0). Returns their count. The float64 operations of the numpy form, including numpy's einsum
    order for a 3-term dot product, ``(a0·b0 + a2·b2) + a1·b1``, and norm's ``(a0² + a1²) + a2²``."""
    k = 0
    for i in range(x.shape[0]):
        tx, ty, tz = p[0] - x[i, 0], p[1] - x[i, 1], p[2] - x[i, 2]
        d2 = (tx * tx + tz * tz) + ty * ty
        dd = math.sqrt(d2)
        lx, ly, lz = tx / dd, ty / dd, tz / dd
        c = (n[i, 0] * lx + n[i, 2] * lz) + n[i, 1] * ly
        if not (dd > 0.0 and c > 0.0):
            continue
        s = c / d2
        if has_ng:
            gx, gy, gz = ng[i, 0], ng[i, 1], ng[i, 2]
            if not (((gx * lx + gz * lz) + gy * ly) > 0.0 or (gx == 0.0 and gy == 0.0 and gz == 0.0)):
                s = 0.0
        if has_bent and bent[i]:
            s *= _bump_shadowing(sm[i, 0], sm[i, 1], sm[i, 2], n[i, 0], n[i, 1], n[i, 2], lx, ly, lz)
        ox, oy, oz = x[i, 0] + eps * n[i, 0], x[i, 1] + eps * n[i, 1], x[i, 2] + eps * n[i, 2]
        rx, ry, rz = p[0] - ox, p[1] - oy, p[2] - oz
        dist = math.sqrt((rx * rx + ry * ry) + rz * rz)
        tf = dist - 2.0 * eps
        rows[k] = i
        scale[k] = s
        trace[k] = tf > 0.0
        o[k, 0], o[k, 1], o[k, 2] = ox, oy, oz
        d[k, 0], d[k, 1], d[k, 2] = rx / dist, ry / dist, rz / dist
        tfar[k] = tf
        k += 1
    return k


# ------------------------------------------------------------------- bent shading normals (Cycles 3.4)
@numba.njit(cache=True, nogil=True)
def _valid_reflection(gx, gy, gz, ix, iy, iz, nx, ny, nz):  # pragma: no cover - compiled
    """Cycles 3.4's ``ensure_valid_reflection(Ng, I, N)`` (intern/cycles/kernel/closure/bsdf_util.h), float64.

    ``(x, y, z, bent)``: N unchanged (``bent`` False) when the mirror reflection ``R = 2(N·I)N − I`` of the viewer
    direction I is at least ``t = min(0.9·Ng·I, 0.01)`` above the geometric plane; else N rotated toward Ng, in the
    plane of N and Ng, just enough that the reflection is at ``t`` (``bent`` True). With ``X = unit(N − (N·Ng)Ng)``,
    ``Ix = I·X``, ``Iz = I·Ng``, ``a = Ix² + Iz²``, ``b = √(Ix²(a − t²))``, ``c = Iz·t + a`` the candidates are
    ``N'z² = (c ± b)/(2a)``, ``N'x = √(1 − N'z²)``; a candidate with ``N'z²`` outside (1e-5, 1 + 1e-5] is dropped,
    of two the one whose reflection ``2(N'·I)N'z − Iz`` is >= 1e-5 (both: the shallower); none: Ng. Ng, I, N unit;
    Ng and N on the side of I (Ng·I > 0), as Cycles' shader setup leaves them."""
    ni = nx * ix + ny * iy + nz * iz
    rx, ry, rz = 2.0 * ni * nx - ix, 2.0 * ni * ny - iy, 2.0 * ni * nz - iz
    gi = gx * ix + gy * iy + gz * iz
    thr = min(0.9 * gi, 0.01)
    if gx * rx + gy * ry + gz * rz >= thr:
        return nx, ny, nz, False
    ng = nx * gx + ny * gy + nz * gz
    xx, xy, xz = nx - ng * gx, ny - ng * gy, nz - ng * gz
    xl = math.sqrt(xx * xx + xy * xy + xz * xz)
    if not xl > 0.0:           # N = ±Ng: Cycles' normalize would give NaN; its fallback
        return gx, gy, gz, True
    xx, xy, xz = xx / xl, xy / xl, xz / xl
    i_x = ix * xx + iy * xy + iz * xz
    i_z = gi
    ix2, iz2 = i_x * i_x, i_z * i_z
    a = ix2 + iz2
    b = math.sqrt(max(ix2 * (a - thr * thr), 0.0))
    c = i_z * thr + a
    fac = 0.5 / a
    n1z2, n2z2 = fac * (b + c), fac * (-b + c)
    valid1 = (n1z2 > 1e-5) and (n1z2 <= 1.0 + 1e-5)
    valid2 = (n2z2 > 1e-5) and (n2z2 <= 1.0 + 1e-5)
    if valid1 and valid2:
        n1x, n1z = math.sqrt(max(1.0 - n1z2, 0.0)), math.sqrt(max(n1z2, 0.0))
        n2x, n2z = math.sqrt(max(1.0 - n2z2, 0.0)), math.sqrt(max(n2z2, 0.0))
        r1 = 2.0 * (n1x * i_x + n1z * i_z) * n1z - i_z
        r2 = 2.0 * (n2x * i_x + n2z * i_z) * n2z - i_z
        v1, v2 = r1 >= 1e-5, r2 >= 1e-5
        if v1 and v2:
            first = r1 < r2
        else:
            first = r1 > r2
        px, pz = (n1x, n1z) if first else (n2x, n2z)
    elif valid1 or valid2:
        z2 = n1z2 if valid1 else n2z2
        px, pz = math.sqrt(max(1.0 - z2, 0.0)), math.sqrt(max(z2, 0.0))
    else:
        return gx, gy, gz, True
    return px * xx + pz * gx, px * xy + pz * gy, px * xz + pz * gz, True


@numba.njit(cache=True, nogil=True)
def _bump_shadowing(sx, sy, sz, nx, ny, nz, wx, wy, wz):  # pragma: no cover - compiled
    """Cycles 3.4's ``bump_shadowing_term(sd->N, sc->N, ω)`` (intern/cycles/kernel/closure/bsdf.h; Chiang, Li and
    Burley 2019, "Taming the Shadow Terminator"): s the smooth (interpolated) normal, n the closure's normal N', ω the
    light / sampled direction. ``g = (s'·ω) / ((n·ω)(s'·n))`` with s' = s, negated when n·ω < 0; 1 for g >= 1, 0 for
    g < 0 (ω below the smooth normal), else ``−g³ + g² + g``. 0/0 reads 0 (Cycles' safe_divide)."""
    cni = nx * wx + ny * wy + nz * wz
    if cni < 0.0:
        sx, sy, sz = -sx, -sy, -sz
    den = cni * (sx * nx + sy * ny + sz * nz)
    g = (sx * wx + sy * wy + sz * wz) / den if den != 0.0 else 0.0
    if g >= 1.0:
        return 1.0
    if g < 0.0:
        return 0.0
    g2 = g * g
    return -g2 * g + g2 + g


@numba.njit(cache=True, nogil=True)
def _valid_reflection_kernel(g, i, n, out, bent):  # pragma: no cover - compiled
    for k in range(g.shape[0]):
        x, y, z, b = _valid_reflection(g[k, 0], g[k, 1], g[k, 2], i[k, 0], i[k, 1], i[k, 2], n[k, 0], n[k, 1], n[k, 2])
        out[k, 0], out[k, 1], out[k, 2] = x, y, z
        bent[k] = b


def ensure_valid_reflection(geo_normals, views, normals) -> tuple[np.ndarray, np.ndarray]:
    """Cycles 3.4's shading-normal correction (:func:`_valid_reflection`) of N rows: ``(N' (N, 3) float64,
    bent (N,) bool)``; ``N' == normals`` exactly where not bent.

    geo_normals : (N, 3) unit geometric normals Ng, on the viewer's side (Ng·I > 0); views : (N, 3) unit directions
    toward the viewer I (minus the arriving ray's direction); normals : (N, 3) unit shading normals N (on Ng's side:
    flipped with Ng, as Cycles flips both for a back face). Cycles applies it to every BSDF closure's normal
    (svm_node_closure_bsdf: ``N = ensure_valid_reflection(sd->Ng, sd->I, N)``)."""
    g = np.ascontiguousarray(geo_normals, np.float64)
    i = np.ascontiguousarray(views, np.float64)
    n = np.ascontiguousarray(normals, np.float64)
    out = np.empty_like(n)
    bent = np.zeros(n.shape[0], np.bool_)
    _valid_reflection_kernel(g, i, n, out, bent)
    return out, bent


@numba.njit(cache=True, nogil=True)
def _bump_shadowing_kernel(s, n, w, out):  # pragma: no cover - compiled
    for k in range(s.shape[0]):
        out[k] = _bump_shadowing(s[k, 0], s[k, 1], s[k, 2], n[k, 0], n[k, 1], n[k, 2], w[k, 0], w[k, 1], w[k, 2])


def bump_shadowing_term(smooth_normals, normals, dirs) -> np.ndarray:
    """(N,) float64: :func:`_bump_shadowing` per row (smooth normal s, closure normal N', direction ω; all (N, 3)).
    Cycles 3.4 multiplies a diffuse closure's evaluation and sample by it where its N' differs from the smooth
    normal, i.e. where :func:`ensure_valid_reflection` bent it (closure/bsdf.h ``bsdf_eval``, ``bsdf_sample``)."""
    s = np.ascontiguousarray(smooth_normals, np.float64)
    n = np.ascontiguousarray(normals, np.float64)
    w = np.ascontiguousarray(np.broadcast_to(np.asarray(dirs, np.float64), n.shape))
    out = np.empty(n.shape[0])
    _bump_shadowing_kernel(s, n, w, out)
    return out


HORIZON_FLAT = 1.0 - 1e-6
"""N'·Ng above this reads as flat: horizon factor exactly 1 (its true value differs by < 5e-7), so flat-shaded
scenes bake bit-identically."""

HORIZON_QUADRATURE = (24, 48)
"""(radial, angular) midpoint cells of the cosine-lobe quadrature of a bent hit's horizon factor."""


@numba.njit(cache=True, nogil=True)
def _horizon_kernel(n, g, s, bent, nr, nphi, out):  # pragma: no cover - compiled
    for k in range(n.shape[0]):
        nx, ny, nz = n[k, 0], n[k, 1], n[k, 2]
        c = nx * g[k, 0] + ny * g[k, 1] + nz * g[k, 2]
        if g[k, 0] == 0.0 and g[k, 1] == 0.0 and g[k, 2] == 0.0:     # degenerate triangle: no plane
            out[k] = 1.0
            continue
        if not bent[k]:
            out[k] = 1.0 if c > HORIZON_FLAT else 0.5 * (1.0 + c)
            continue
        # the cosine lobe about N' (Malley: uniform disc (r, φ) lifted), midpoint cells of equal probability
        sg = 1.0 if nz >= 0.0 else -1.0
        aa = -1.0 / (sg + nz)
        bb = nx * ny * aa
        t1x, t1y, t1z = 1.0 + sg * nx * nx * aa, sg * bb, -sg * nx
        t2x, t2y, t2z = bb, sg + ny * ny * aa, -ny
        acc = 0.0
        for a in range(nr):
            u1 = (a + 0.5) / nr
            r = math.sqrt(u1)
            zc = math.sqrt(1.0 - u1)
            for b in range(nphi):
                phi = 2.0 * math.pi * (b + 0.5) / nphi
                x, y = r * math.cos(phi), r * math.sin(phi)
                wx = x * t1x + y * t2x + zc * nx
                wy = x * t1y + y * t2y + zc * ny
                wz = x * t1z + y * t2z + zc * nz
                if wx * g[k, 0] + wy * g[k, 1] + wz * g[k, 2] <= 0.0:
                    continue
                acc += _bump_shadowing(s[k, 0], s[k, 1], s[k, 2], nx, ny, nz, wx, wy, wz)
        out[k] = acc / (nr * nphi)


def horizon_factor(normals, geo_normals, smooth_normals=None, bent=None) -> np.ndarray:
    """(N,) float64: the fraction of uniform incident radiance a Lambertian surface with closure normal N' keeps when
    directions below its geometric plane (normal Ng) are lost: ``h = (1/π) ∫ max(0, N'·ω) [Ng·ω > 0] dω``.

    Derivation (not bent; H = the hemisphere Ng·ω > 0): write ``max(0, x) = (x + |x|)/2``, so
    ``π h = ½ ∫_H N'·ω dω + ½ ∫_H |N'·ω| dω``. The first integral is ``N'·∫_H ω dω = π N'·Ng`` (the hemisphere's
    vector irradiance is π Ng). In the second, ω → −ω maps H onto the other hemisphere and keeps |N'·ω|, so it is
    half of the whole sphere's ``∫ |N'·ω| dω = 2π``: π. Hence ``h = (1 + N'·Ng)/2`` (1 when N' = Ng, 1/2 when N'
    lies in the plane) — the sky view factor of a tilted surface.

    ``bent`` rows (Cycles applied :func:`ensure_valid_reflection`, so it also multiplies by
    :func:`bump_shadowing_term` with the smooth normal s): ``h = (1/π) ∫ max(0, N'·ω) [Ng·ω > 0] S(s, N', ω) dω``,
    which has no closed form here: a midpoint quadrature over the cosine lobe (:data:`HORIZON_QUADRATURE`
    equal-probability cells, ~0.2% accurate). ``N'·Ng >`` :data:`HORIZON_FLAT` reads 1 (flat).

    normals, geo_normals, smooth_normals : (N, 3) unit (N', Ng on the lit side, s); bent : (N,) bool or None (none).
    """
    normals, geo_normals = np.asarray(normals), np.asarray(geo_normals)
    smooth = normals if smooth_normals is None else np.asarray(smooth_normals)
    out = np.empty(normals.shape[0])

    def chunk(a: int, e: int) -> None:     # each chunk's rows in float64, two chunks at a time (the same floats)
        n = np.ascontiguousarray(normals[a:e], np.float64)
        g = np.ascontiguousarray(geo_normals[a:e], np.float64)
        s = n if smooth_normals is None else np.ascontiguousarray(smooth[a:e], np.float64)
        b = np.zeros(e - a, np.bool_) if bent is None else np.ascontiguousarray(bent[a:e], np.bool_)
        _horizon_kernel(n, g, s, b, HORIZON_QUADRATURE[0], HORIZON_QUADRATURE[1], out[a:e])

    map_chunks(chunk, normals.shape[0], DIRECT_CHUNK)
    return out
