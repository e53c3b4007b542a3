"""Where the evaluate stage measures: stratified surface points, points the review cameras see, check points.

Every function is deterministic for its seed and independent of the probe grid, so every bake of a scene (same
lighting, same reference settings) measures at the same points.

Surface points by area (:func:`area_points`)
--------------------------------------------
Uniform by area over the front faces (glTF's counter-clockwise side) of every triangle with positive area,
stratified: candidate i of M takes the area-CDF position ``(i + ξ_i) / M`` (triangles in file order, so
neighbouring strata are mostly neighbouring surfaces) and a uniform point in its triangle
(``b = 1 - √ξ₁``, ...). A candidate is kept when it lies in free space: of ``FREE_RAYS`` cosine-distributed rays
from it (offset ``eps`` along the geometric normal) at most ``max_backface`` see the back of a single-sided
surface (a face inside a solid, or behind a wall, sees back faces; DDGI-P §6.1's test). Candidates are drawn
1.5× (plus 16) the number wanted and the first kept ones in stratum order are returned, so the set is still
spread over the whole area.

Surface points the cameras see (:func:`camera_points`)
-----------------------------------------------------
Per camera an equal share of the points, at jittered pixel positions of a stratified grid over the image (the
grid's aspect the image's): the closest hit of each pixel ray, kept where it shows a front face or a
double-sided surface, the normals flipped toward the camera. Where the grid (1.5x the share) finds fewer such
pixels than the share (sky fills much of an open scene's image: a 10 m floor under a sky kept 421 of 2,048), it is
cast again, denser by the fraction found (at most :data:`DENSER_PASSES` times, :data:`MAX_OVERSAMPLING` rays a point),
and the share taken spread over the image from the densest grid.

The reference stage's choice (:func:`surface_point_set`): camera points for ``sampling = "cameras"``, unless the
cameras see fewer than 10% of the points wanted: then (and for ``"area"``) area points.

Check points (:func:`check_point_set`)
-------------------------------------
The config's ``evaluate.points``: each point with its unit normal, or the 6 axis normals +X, -X, +Y, -Y, +Z, -Z
(the order of ``../shared/oracle``'s receivers). Receivers in free space, lit on the side the normal faces.

All return float64 arrays; the view direction of a point (what the mask and DDGI modes bias toward) is the
direction to the camera for camera points and the normal otherwise (a viewer in front of the surface).
"""
from __future__ import annotations

import math

import numpy as np

from workers.kernels.materials import double_sided_triangles

__all__ = ["area_points", "camera_points", "check_point_set", "surface_point_set", "AXIS_NORMALS", "FREE_RAYS"]

AXIS_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
FREE_RAYS = 16
"""Rays of the free-space test of each candidate surface point."""
DENSER_PASSES = 2
"""Camera points: further passes, each a denser pixel grid, when a camera's first grid finds fewer surface pixels
than its share (an open scene: sky fills much of the image)."""
MAX_OVERSAMPLING = 16
"""Camera points: at most this many pixel rays per point wanted, per camera."""


def _unit(a: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


def _cosine_dirs(normals: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Cosine-distributed unit directions about unit ``normals`` (N, 3) from uniforms (N,)."""
    n = normals
    helper = np.where(np.abs(n[:, :1]) > 0.9, np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    t1 = _unit(np.cross(helper, n))
    t2 = np.cross(n, t1)
    r = np.sqrt(u1)
    phi = 2 * math.pi * u2
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    return (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + z[:, None] * n


def _surfaces(scene, tri, bu, bv) -> dict:
    from workers.kernels.shading import surface_at_hits

    s = surface_at_hits(scene, tri, bu, bv)
    return {k: np.asarray(v, np.float64) if k != "double_sided" else np.asarray(v, bool) for k, v in s.items()}


def _double_sided(scene) -> np.ndarray:
    return double_sided_triangles(scene) if scene.n_triangles else np.zeros(0, bool)


def area_points(scene, n: int, *, seed: int = 0, caster=None, eps: float | None = None,
                max_backface: float = 0.5) -> dict:
    """About ``n`` stratified points uniform by area on front faces, in free space (module doc).

    Returns ``{"position", "normal" (shading, on the front side), "geo_normal", "view" (= normal), "albedo",
    "emission"}`` (K, 3) float64 with K <= n, ``"tri"`` (K,) int64, and ``"stats"``: candidates, dropped
    (inside solids), total area (m²).
    """
    from workers.kernels.pathtrace import scene_eps
    from workers.raycast import caster_for_scene

    n = int(n)
    empty = {k: np.zeros((0, 3)) for k in ("position", "normal", "geo_normal", "view", "albedo", "emission")}
    empty["tri"] = np.zeros(0, np.int64)
    tris = np.asarray(scene.triangles, np.float64).reshape(-1, 3, 3)
    if n <= 0 or len(tris) == 0:
        return {**empty, "stats": {"candidates": 0, "dropped": 0, "area": 0.0}}
    cr = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    area = 0.5 * np.linalg.norm(cr, axis=1)
    area = np.where(np.isfinite(area), area, 0.0)
    total = float(area.sum())
    if total <= 0:
        return {**empty, "stats": {"candidates": 0, "dropped": 0, "area": 0.0}}
    cdf = np.cumsum(area) / total
    cdf[-1] = 1.0
    rng = np.random.default_rng([int(seed), 0x5EF0])
    M = int(math.ceil(1.5 * n)) + 16
    strata = (np.arange(M) + rng.random(M)) / M
    tri = np.minimum(np.searchsorted(cdf, strata, side="right"), len(tris) - 1).astype(np.int64)
    su = np.sqrt(rng.random(M))
    r2 = rng.random(M)
    bu = su * (1.0 - r2)          # Hits convention: x = (1 - u - v) v0 + u v1 + v v2
    bv = su * r2
    s = _surfaces(scene, tri, bu, bv)
    geo = s["geo_normal"]
    nrm = s["normal"]
    nrm = np.where((np.einsum("ij,ij->i", nrm, geo) < 0)[:, None], -nrm, nrm)
    ok = np.linalg.norm(geo, axis=1) > 0.5
    eps = scene_eps(scene) if eps is None else float(eps)
    caster = caster_for_scene(scene) if caster is None else caster
    # free space: few back faces of single-sided surfaces among FREE_RAYS cosine rays
    R = FREE_RAYS
    g = np.repeat(geo, R, axis=0)
    d = _cosine_dirs(np.where(np.linalg.norm(g, axis=1, keepdims=True) > 0.5, g, np.array([[0.0, 1.0, 0.0]])),
                     rng.random(M * R), rng.random(M * R))
    o = np.repeat(s["position"], R, axis=0) + eps * g
    h = caster.intersect(o, d)
    ds = _double_sided(scene)
    back = (h.hit & h.backface & ~ds[np.where(h.hit, h.tri, 0)]).reshape(M, R).mean(axis=1)
    free = ok & (back <= max_backface)
    keep = np.flatnonzero(free)[:n]
    out = {"position": s["position"][keep], "normal": nrm[keep], "geo_normal": geo[keep], "view": nrm[keep],
           "albedo": s["albedo"][keep], "emission": s["emission"][keep], "tri": tri[keep]}
    out["stats"] = {"candidates": M, "dropped": int(ok.sum() - free.sum()), "degenerate": int((~ok).sum()),
                    "area": total}
    return out


def camera_points(scene, cameras, n: int, *, seed: int = 0, caster=None) -> dict:
    """About ``n`` points on the surfaces the ``cameras`` (:class:`workers.render.cameras.Camera`) see, an equal
    share per camera (module doc). Same keys as :func:`area_points` plus ``"camera"`` (K,) int64; ``view`` is the
    unit direction to the camera."""
    from workers.raycast import caster_for_scene

    cams = list(cameras)
    n = int(n)
    keys = ("position", "normal", "geo_normal", "view", "albedo", "emission")
    if n <= 0 or not cams:
        return {**{k: np.zeros((0, 3)) for k in keys}, "tri": np.zeros(0, np.int64), "camera": np.zeros(0, np.int64),
                "stats": {"rays": 0, "kept": 0}}
    caster = caster_for_scene(scene) if caster is None else caster
    rng = np.random.default_rng([int(seed), 0xCA3E])
    ds = _double_sided(scene)
    parts, rays = [], 0
    share = -(-n // len(cams))
    for ci, cam in enumerate(cams):
        want = share * 3 // 2 + 16   # some pixels see nothing or back faces
        for _ in range(DENSER_PASSES + 1):
            gh = max(1, int(round(math.sqrt(want / cam.aspect))))
            gw = max(1, int(math.ceil(want / gh)))
            jj, ii = np.meshgrid(np.arange(gw), np.arange(gh))
            cols = (jj.ravel() + rng.random(jj.size)) / gw * cam.width
            rows = (ii.ravel() + rng.random(ii.size)) / gh * cam.height
            d = cam.pixel_directions(rows, cols)
            o = np.broadcast_to(np.asarray(cam.position, np.float64), d.shape)
            h = caster.intersect(o, d)
            rays += len(d)
            good = h.hit & (~h.backface | ds[np.where(h.hit, h.tri, 0)])
            idx = np.flatnonzero(good)
            if idx.size >= share or idx.size == 0 or want >= MAX_OVERSAMPLING * share:
                break
            # much of the image is sky or back faces: a denser grid, to fill the share with what the camera sees
            want = int(min(MAX_OVERSAMPLING * share, math.ceil(1.25 * share * len(d) / idx.size) + 16))
        # spread the share over the image: every k-th good pixel in raster order
        if idx.size > share:
            idx = idx[np.linspace(0, idx.size - 1, share).round().astype(np.int64)]
        tri = h.tri[idx].astype(np.int64)
        s = _surfaces(scene, tri, h.u[idx], h.v[idx])
        view = _unit(np.asarray(cam.position, np.float64) - s["position"])
        flip = (np.einsum("ij,ij->i", s["geo_normal"], view) < 0)[:, None]
        geo = np.where(flip, -s["geo_normal"], s["geo_normal"])
        nrm = s["normal"]
        nrm = np.where((np.einsum("ij,ij->i", nrm, geo) < 0)[:, None], -nrm, nrm)
        parts.append({"position": s["position"], "normal": nrm, "geo_normal": geo, "view": view,
                      "albedo": s["albedo"], "emission": s["emission"], "tri": tri,
                      "camera": np.full(len(idx), ci, np.int64)})
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out = {k: v[:n] for k, v in out.items()}
    out["stats"] = {"rays": rays, "kept": int(len(out["tri"]))}
    return out


def surface_point_set(scene, cameras, n: int, sampling: str, *, seed: int = 0, caster=None,
                      eps: float | None = None) -> tuple[dict, str, list[dict]]:
    """The reference's surface points (module doc): ``(points, sampling used, warnings)``; the points as
    :func:`camera_points` / :func:`area_points` return them; the warning ``few_surface_points`` when fewer than
    half of the ``n`` wanted could be placed."""
    sp = None
    if sampling == "cameras" and cameras:
        sp = camera_points(scene, cameras, n, seed=seed, caster=caster)
        if len(sp["position"]) < 0.1 * n:
            sp = None                 # the cameras see (almost) nothing: uniform by area instead
    if sp is None:
        sampling = "area"
        sp = area_points(scene, n, seed=seed, caster=caster, eps=eps)
    warnings = []
    if n and len(sp["position"]) < 0.5 * n:
        warnings.append({"code": "few_surface_points",
                         "message": f"only {len(sp['position'])} of {n} surface points could be "
                                    f"placed ({sampling} sampling): the metrics are noisier"})
    return sp, sampling, warnings


def check_point_set(points, normals=None) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) points and (P, D, 3) unit normals: D = 1 with ``normals`` (one per point), else the 6 axis
    normals of :data:`AXIS_NORMALS` per point."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if normals is None:
        return p, np.broadcast_to(AXIS_NORMALS, (len(p), 6, 3)).copy()
    nrm = _unit(np.asarray(normals, np.float64).reshape(-1, 3))
    if nrm.shape != p.shape:
        raise ValueError(f"check points: {len(p)} points but {len(nrm)} normals")
    return p, nrm[:, None, :]
