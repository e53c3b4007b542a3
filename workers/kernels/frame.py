"""The bake frame: the world turned about +Y so that the probe grid's axes follow the scene's walls (numpy only).

Why: the probe grid is axis-aligned, and every fidelity number of the light stage was measured on rooms whose walls
are parallel to its cells. Turned 30° about +Y, the same interiors read 1.07-1.26 of Cycles in their dark rooms
(``tests/bench/bench_fidelity.py --rotate 30``; docs/architecture.md "The same interiors rotated"): the walls cut the
cells at every angle, the probes stand at every distance in front of them, and the light stage's bounces feed the
gather's excess back into the stored values (with light stage 10's map-reading gather; light stage 11's gather reads
the probes' SH and takes most of it: 1.02-1.09 on thick-wall and plane-wall turned without a frame). A building is rarely aligned with the world axes of the file it comes
in; RTXGI's volumes carry a rotation for this reason. Kiln fits the rotation instead of asking for it.

**The frame.** ``yaw`` θ (degrees) turns the grid about the world's +Y: the grid's x, y, z axes are the columns of
``R_y(θ) = [[cos θ, 0, sin θ], [0, 1, 0], [−sin θ, 0, cos θ]]``. The probe stages (place … prt, and evaluate's GI
lookups) work on the scene mapped by ``M = R_y(θ)ᵀ`` (world → bake frame; positions about the world origin and
directions alike): ``p_bake = M · p_world``. Every probe artifact is in the bake frame; a reader maps a world point,
normal and view direction with M before a GI lookup, and a bake-frame position back with Mᵀ (proto/bundle.md §5).
θ = 0 is the identity: an aligned scene bakes exactly as before.

**The fit** (:func:`fit_yaw`). Walls are the triangles whose normal is within ``WALL_TILT`` of horizontal. Each
votes, by area, for the angle ``φ = atan2(n_x, n_z)`` modulo 90° (a room's four walls give one angle). The peak of
the area histogram (0.25° bins, smoothed over ±1°), refined by the area-weighted median of φ over the walls within
``PEAK_WINDOW`` of it (a few walls a degree off do not pull it), is θ in (−45°, 45°]. It is kept when the walls within the window hold at least
``MIN_SUPPORT`` of the wall area and the walls at least ``MIN_WALL_AREA`` of all the area; otherwise (terrain,
organic shapes, no walls) θ = 0. A fitted |θ| below ``SNAP_DEG`` is 0 (an aligned file stays bit-identical).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["fit_yaw", "frame_matrix", "choose_frame", "to_frame", "from_frame", "frame_of", "rotate_scene",
           "rotate_lights", "WALL_TILT", "MIN_SUPPORT", "MIN_WALL_AREA", "PEAK_WINDOW", "SNAP_DEG"]

WALL_TILT = 10.0
"""Degrees from vertical (a normal within this of horizontal) for a triangle to count as a wall."""

MIN_SUPPORT = 0.35
"""Fraction of the wall area within :data:`PEAK_WINDOW` of the peak for the fit to be kept."""

MIN_WALL_AREA = 0.05
"""Fraction of the scene's triangle area that must be walls for the fit to be kept."""

PEAK_WINDOW = 3.0
"""Degrees (of φ mod 90°) around the histogram peak whose walls refine it."""

SNAP_DEG = 0.01
"""A fitted yaw smaller than this (degrees) is 0: the world frame."""


def frame_matrix(yaw_deg: float) -> np.ndarray:
    """(3, 3) float64 ``M = R_y(θ)ᵀ``, world → bake frame (row-major: ``p_bake = M @ p_world``)."""
    if float(yaw_deg) == 0.0:
        return np.eye(3)
    t = math.radians(float(yaw_deg))
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]], np.float64)


def fit_yaw(triangles: np.ndarray) -> dict:
    """The dominant wall direction of a scene: ``{"yaw_deg", "support", "wall_fraction", "fitted"}``.

    triangles : (T, 3, 3) float, world-space vertex positions, metres. ``yaw_deg`` in (−45, 45] (0 when not
    ``fitted``); ``support``: the fraction of the wall area within :data:`PEAK_WINDOW` of it; ``wall_fraction``:
    the walls' share of the total area. See the module doc.
    """
    tri = np.asarray(triangles, np.float64).reshape(-1, 3, 3)
    out = {"yaw_deg": 0.0, "support": 0.0, "wall_fraction": 0.0, "fitted": False}
    if tri.shape[0] == 0:
        return out
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cr, axis=1)
    total = float(area2.sum())
    if total <= 0.0:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        n = cr / area2[:, None]
    horiz = np.hypot(n[:, 0], n[:, 2])
    wall = (area2 > 0) & (horiz >= math.cos(math.radians(WALL_TILT)))
    w = area2[wall]
    out["wall_fraction"] = float(w.sum() / total)
    if not wall.any() or out["wall_fraction"] < MIN_WALL_AREA:
        return out
    phi = np.degrees(np.arctan2(n[wall, 0], n[wall, 2])) % 90.0          # [0, 90)
    bins = 360                                                            # 0.25° bins over the 90° period
    hist = np.bincount(np.minimum((phi / 90.0 * bins).astype(np.int64), bins - 1), weights=w, minlength=bins)
    k = 4                                                                 # ±1°: circular smoothing
    smooth = sum(np.roll(hist, s) for s in range(-k, k + 1))
    peak = (np.argmax(smooth) + 0.5) * 90.0 / bins
    d = (phi - peak + 45.0) % 90.0 - 45.0                                 # signed distance to the peak, mod 90°
    near = np.abs(d) <= PEAK_WINDOW
    out["support"] = float(w[near].sum() / w.sum())
    if out["support"] < MIN_SUPPORT:
        return out
    dn, wn = d[near], w[near]                                             # weighted median of the offsets: robust
    order = np.argsort(dn)                                                # to a few walls a degree or two off
    cw = np.cumsum(wn[order])
    yaw = peak + float(dn[order][np.searchsorted(cw, 0.5 * cw[-1])])
    yaw = (yaw + 45.0) % 90.0 - 45.0
    if yaw <= -45.0:
        yaw += 90.0
    if abs(yaw) < SNAP_DEG:
        yaw = 0.0
    out.update(yaw_deg=float(yaw), fitted=bool(yaw != 0.0))
    return out


def choose_frame(triangles: np.ndarray, place) -> dict:
    """The bake frame of a scene for a ``place`` section (:class:`proto.models.PlaceSection`).

    ``place.yaw`` set: that yaw (``source: "config"``). Else a ``place.box`` (world axis-aligned) keeps the world
    frame (``source: "box"``). Else :func:`fit_yaw` (``source: "walls"``; ``"none"`` when it keeps θ = 0).
    Returns ``{"yaw_deg", "matrix" (3 × 3 row-major, world → bake), "source", "reason", and the fit's numbers}``
    (the place stage's ``frame`` stat and the manifest's ``grid.frame``).
    """
    yaw = getattr(place, "yaw", None)
    if yaw is not None:
        info = {"yaw_deg": float(yaw), "source": "config",
                "reason": f"place.yaw = {float(yaw):g} deg (the config's)"}
    elif getattr(place, "box", None) is not None:
        info = {"yaw_deg": 0.0, "source": "box", "reason": "place.box is given in world axes: the world frame"}
    else:
        fit = fit_yaw(triangles)
        info = {**fit, "source": "walls" if fit["fitted"] else "none"}
        if fit["fitted"]:
            info["reason"] = (f"the grid turned {fit['yaw_deg']:.2f} deg about +Y to the walls "
                              f"({100 * fit['support']:.0f}% of the wall area within {PEAK_WINDOW:g} deg of it)")
        elif fit["wall_fraction"] < MIN_WALL_AREA:
            info["reason"] = "world axes: too few walls to align to"
        elif fit["support"] < MIN_SUPPORT:
            info["reason"] = (f"world axes: no dominant wall direction ({100 * fit['support']:.0f}% of the wall "
                              "area near the peak)")
        else:
            info["reason"] = "world axes: the walls are aligned with them"
    info["matrix"] = frame_matrix(info["yaw_deg"]).tolist()
    return info


def frame_of(grid: dict | None) -> np.ndarray | None:
    """The (3, 3) world → bake matrix of a grid dict (manifest ``grid``, place stats), or None for the identity."""
    fr = (grid or {}).get("frame")
    if not fr or not float(fr.get("yaw_deg", 0.0)):
        return None
    return np.asarray(fr["matrix"], np.float64).reshape(3, 3)


def to_frame(v, M: np.ndarray | None) -> np.ndarray:
    """Points or directions (..., 3), world → bake frame (``M @ v``, float64); ``M`` None: ``v`` as it is."""
    if M is None:
        return np.asarray(v)
    return np.asarray(v, np.float64) @ np.asarray(M, np.float64).T


def from_frame(v, M: np.ndarray | None) -> np.ndarray:
    """Points or directions (..., 3), bake frame → world (``Mᵀ @ v``, float64); ``M`` None: ``v`` as it is."""
    if M is None:
        return np.asarray(v)
    return np.asarray(v, np.float64) @ np.asarray(M, np.float64)


def rotate_lights(lights: list[dict], M: np.ndarray | None) -> list[dict]:
    """Light dicts (:mod:`workers.scene`) with ``position`` and ``direction`` mapped by M (copies)."""
    out = []
    for lt in lights:
        lt = dict(lt)
        for key in ("position", "direction"):
            if lt.get(key) is not None and M is not None:
                lt[key] = [float(x) for x in to_frame(lt[key], M)]
        out.append(lt)
    return out


def rotate_scene(scene, M: np.ndarray | None):
    """The :class:`workers.scene.NormalizedScene` ``scene`` with its vertices, normals, lights and cameras mapped by M.

    A shallow copy: UVs, colours, materials and textures are shared (rotation-free). ``M`` None: ``scene`` itself.
    """
    if M is None:
        return scene
    import copy

    out = copy.copy(scene)
    Mf = np.asarray(M, np.float64)
    out.triangles = (np.asarray(scene.triangles, np.float64) @ Mf.T).astype(np.float32)
    out.normals = (np.asarray(scene.normals, np.float64) @ Mf.T).astype(np.float32)
    out.lights = rotate_lights(scene.lights, M)
    out.cameras = [{**c, **{k: [float(x) for x in to_frame(c[k], M)] for k in ("position", "target") if k in c}}
                   for c in getattr(scene, "cameras", [])]
    return out
