"""Cycles references for the fidelity benchmark (tests/bench/bench_fidelity.py): run by hand, needs Blender 3.4.

    .venv/bin/python tests/data/fidelity/make_references.py [--scenes two-rooms-vc,metal-room,living-room]
        [--samples 8192] [--seeds 0,1] [--points-only] [--timeout 900] [--direct-samples 1024]

For each procedural scene (``workers.procedural.make_scene``) and each real scene of :data:`EXTERNAL` (read where it
lies, in ``../shared/scenes`` — never copied into the project; ``KILN_SHARED_SCENES`` overrides the folder — with the
lights of its entry added):

1. writes ``<scene>.points.json`` here: free-space check points by region (:data:`REGIONS`, hand-placed) plus
   ``probes``, un-relocated probe positions of the grid ``place.counts = [8, 8, 8]`` over the scene bounds (the
   default grid before the automatic one) that are at least :data:`PROBE_CLEARANCE` from every surface (a subset,
   :data:`PROBES_PER_SCENE`; real scenes: so many in each of the entry's ``probe_boxes``), so the bench can compare the light stage's stored probe values too (it bakes that
   grid when the default one holds no probe there). No "normals": the oracle gives each point the 6 axis
   normals +X, -X, +Y, -Y, +Z, -Z. ``regions`` maps region -> point indices. Every point is checked to be
   outside geometry (ray parity) and at least :data:`MIN_CLEARANCE` from every triangle.
2. writes the GLB to a temp dir and runs the shared oracle (``../shared/oracle/cycles_irradiance_points.py``,
   through :file:`oracle_lambert_textures.py`, which only makes its Lambert model follow metallic textures and keep
   emissive surfaces emitting — the stock Lambert replacement drops their emission) once per seed: ``--samples N --bounces 64 --sky 0,0,0 --material lambert`` (and for ``metal-room`` also
   ``--material importer --glossy 64``), under ``nice -n 10``.
3. writes ``<scene>.<material>.cycles.json``: per receiver (point x axis normal) the seed means of ``E_direct``
   and ``E_indirect`` (RGB), ``E_probe`` (what a probe bake stores: the indirect light plus the direct light of
   emissive surfaces, which Cycles counts as direct; = ``E_indirect`` in scenes without emitters — for those
   with emitters a second run with the punctual lights removed gives that direct part, for the first
   ``--emit-seeds`` seeds: it converges far faster than the indirect light), the settings,
   seeds, wall time per run, and the spread between seeds (per region: relative difference of the region means
   of E_indirect; per receiver: RMS of the relative half-difference).

Sky 0 for the procedural scenes: they carry their own lights, and a probe then holds exactly E_probe.

Real scenes (:data:`EXTERNAL`, e.g. ``living-room``: ``godot-living-room/living_room.glb``, which has no lights of its
own) are baked by the bench with the default config plus the entry's ``config`` (``scene.lights`` and ``scene.sky``).
The oracle gets the same lights as ``KHR_lights_punctual`` nodes patched into the GLB's JSON chunk (the binary chunk is
kept byte for byte) and the same sky (``--sky``). With ``drop_coincident`` (living-room) Cycles also gets the scene
without the triangles that coplanar copies cover entirely (:func:`drop_coincident`: Cycles 3.4 bakes such doubled
surfaces black); new index accessors are appended after the original binary data, and Kiln's rays from every check
point must find the same hit distances in both (:func:`same_surfaces`, recorded in the reference's
``oracle_scene_fix``); Kiln's path tracer gives identical values on both files (measured). Their points are checked with the exact point-triangle distance and
with rays (:data:`CHECK_RAYS` directions, Kiln's ray caster on Kiln's ingest of the file: every hit at least the
clearance away) and parity. With a sky, Cycles counts the sky seen from the receiver as direct light, so
``E_probe = E_total(sky) - E_direct(sky 0)``: a second run with sky 0 (``--direct-samples`` spp, the first
``--direct-seeds`` seeds; the punctual lights' direct light converges far faster than the indirect light) gives the
punctual lights' direct part.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT))

from workers.procedural import ALL_SCENES, make_scene  # noqa: E402

SHARED_SCENES = Path(os.environ.get("KILN_SHARED_SCENES", ROOT.parent / "shared" / "scenes"))

ORACLE = Path(os.environ.get("KILN_ORACLE", ROOT.parent / "shared" / "oracle" / "cycles_irradiance_points.py"))
WRAPPER = HERE / "oracle_lambert_textures.py"
AXES = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
DEFAULT_COUNTS = (8, 8, 8)  # the probe grid of the "probes" region: place.counts over the scene bounds
MIN_CLEARANCE = 0.04        # metres from every surface, for any check point
PROBE_CLEARANCE = {"cornell": 0.08}  # default 0.15 m
PROBES_PER_SCENE = 8
MATERIALS = {"metal-room": ("lambert", "importer")}  # default: ("lambert",)
GLOSSY = 64                                          # glossy bounces of --material importer

# Shared-wall layout of two-rooms: room A x in [0, 4], the 5 cm wall x in [4, 4.05], room B x in [4.05, 8.05];
# door z in [1.55, 2.45], y < 2. The wall points sit behind the wall (0.95 m from the door's edge), below and
# above the door's height.
_WALL_YZ = [(1.0, 0.6), (2.2, 0.6), (1.0, 3.4), (2.2, 3.4)]
_TWO_ROOMS = {
    "dark-5cm": [(4.10, y, z) for y, z in _WALL_YZ],
    "dark-10cm": [(4.15, y, z) for y, z in _WALL_YZ],
    "dark-25cm": [(4.30, y, z) for y, z in _WALL_YZ],
    "dark-middle": [(6.05, 1.5, 2.0), (6.05, 1.0, 1.0), (6.5, 2.0, 3.0), (5.5, 0.8, 3.2)],
    "lit-10cm": [(3.90, y, z) for y, z in _WALL_YZ],
    "lit": [(2.5, 1.2, 1.0), (1.0, 1.0, 3.0), (3.0, 2.0, 3.2), (2.0, 0.6, 2.0)],
}
REGIONS: dict[str, dict[str, list[tuple[float, float, float]]]] = {
    "two-rooms": _TWO_ROOMS,
    "two-rooms-vc": _TWO_ROOMS,
    # metal-room: interior [0, 4] x [0, 2.5] x [0, 3], the metal wall at x = 4, the striped box
    # [0.7, 1.5] x [0, 0.8] x [0.8, 1.6], the light at (2.4, 2.0, 1.8)
    "metal-room": {
        "metal-10cm": [(3.90, y, z) for y, z in [(0.8, 0.8), (1.7, 0.8), (0.8, 2.2), (1.7, 2.2)]],
        "metal-25cm": [(3.75, y, z) for y, z in [(0.8, 0.8), (1.7, 0.8), (0.8, 2.2), (1.7, 2.2)]],
        "middle": [(2.0, 1.25, 1.5), (2.6, 1.0, 1.0), (1.6, 1.5, 2.2), (2.8, 0.9, 2.4)],
        "object": [(1.1, 1.0, 1.2), (1.7, 0.4, 1.2), (1.1, 0.4, 1.8), (0.5, 0.4, 1.2)],
        "floor": [(2.5, 0.15, 0.7), (3.0, 0.15, 2.3), (0.5, 0.15, 2.5)],
    },
    # sealed-box: floor slab y < 0, box [-0.5, 0.5] x [0, 1] x [-0.5, 0.5] with a sealed cavity (no light at all)
    "sealed-box": {
        "cavity": [(0.0, 0.5, 0.0), (0.3, 0.3, -0.3), (-0.3, 0.8, 0.3)],
        "box-10cm": [(0.6, 0.5, 0.0), (-0.6, 0.5, 0.0), (0.0, 0.5, 0.6), (0.0, 0.5, -0.6)],
        "above-box": [(0.0, 1.1, 0.0), (0.25, 1.2, 0.25)],
        "open": [(2.0, 0.5, -2.0), (-2.5, 1.0, 2.0), (3.0, 0.3, 0.0), (-1.5, 0.5, -3.0)],
    },
    # cornell: cavity [0.02, 0.98]^2 x [0.02, 1] open at z = 1; red wall x = 0.02, green x = 0.98
    "cornell": {
        "middle": [(0.5, 0.5, 0.5), (0.4, 0.35, 0.6), (0.6, 0.65, 0.4)],
        "red-5cm": [(0.07, 0.5, 0.6), (0.07, 0.8, 0.8)],
        "green-5cm": [(0.93, 0.5, 0.4), (0.93, 0.8, 0.3)],
        "low": [(0.5, 0.1, 0.5), (0.45, 0.2, 0.75)],
    },
}
# Real scenes: read from SHARED_SCENES / source, baked with the default config plus ``config`` (added lights, sky).
# living_room.glb (Godot demo, 5088 triangles, all materials double-sided, untextured, metallic 0, no lights):
# the room x in [-4, 4], floor y = 1, ceiling y = 3.5, z in [-2, 2]; walls 0.5-1 m thick (solid); the window wall
# z in [2, 2.5] has two floor-to-ceiling openings (x in [-3.45, -0.55] and [0.55, 3.45], no glass) onto a courtyard
# (z in [2.5, 11.5], x in [-4.5, 4.5], no roof: the only way to the sky); a round table (top y in [1.805, 1.875],
# radius 0.9 about x = -2, z = 0.2, on a pole). Two 60 cd bulbs 40 cm under the ceiling (one over the table, so
# the floor under it is the dark region) and a blue-ish sky through the courtyard.
_LR_WALLS = [((-1.0, 1.6), "z"), ((1.0, 2.8), "z"), ((3.0, 2.0), "z"), ((2.2, -0.8), "+x"), ((2.6, 0.8), "-x")]


def _lr_wall(d: float) -> list[tuple[float, float, float]]:
    """living-room points d from a wall: three in front of the back wall (z = -2), one by each side wall."""
    out = []
    for (a, b), wall in _LR_WALLS:
        out.append((a, b, -2.0 + d) if wall == "z" else ((4.0 - d) if wall == "+x" else (-4.0 + d), a, b))
    return out


EXTERNAL: dict[str, dict] = {
    "living-room": {
        "source": "godot-living-room/living_room.glb",
        "triangles": 5088,
        "config": {"scene": {
            "lights": [
                {"type": "point", "position": [-2.0, 3.1, 0.2], "color": [1.0, 1.0, 1.0], "intensity": 60.0},
                {"type": "point", "position": [2.0, 3.1, -0.6], "color": [1.0, 1.0, 1.0], "intensity": 60.0},
            ],
            "sky": [8.0, 9.0, 11.0],
        }},
        "min_clearance": 0.05,
        "probe_clearance": 0.15,
        "drop_coincident": True,   # for Cycles: see drop_coincident()
        # the "probes" region: free grid positions in these boxes only (the bounds also span the solid shell and
        # the void around the building): (box, how many), here the room and the courtyard
        "probe_boxes": [(((-4.0, 1.0, -2.0), (4.0, 3.5, 2.0)), 6), (((-4.5, 1.0, 2.5), (4.5, 4.0, 11.5)), 2)],
    },
}
REGIONS["living-room"] = {
    "wall-5cm": _lr_wall(0.05),
    "wall-10cm": _lr_wall(0.10),
    "wall-25cm": _lr_wall(0.25),
    "middle": [(0.0, 2.25, 0.0), (1.2, 2.0, 0.6), (-0.6, 2.7, -0.9), (2.6, 1.6, 0.9)],
    # in the room, 25 cm in front of the window plane (z = 2): two in front of the openings, one of the pier
    "window": [(-2.0, 2.2, 1.75), (2.0, 2.8, 1.75), (0.0, 2.2, 1.75)],
    # outside, under the sky
    "courtyard": [(0.0, 2.0, 4.0), (-2.5, 1.5, 3.5), (2.5, 2.5, 6.0), (3.5, 3.0, 3.0)],
    "table-top": [(-2.3, 1.975, 0.0), (-1.6, 1.975, 0.5), (-2.6, 1.975, 0.6)],
    # under the table top, shadowed from the bulb above it: the dark region
    "under-table": [(-2.5, 1.4, 0.2), (-1.6, 1.2, 0.6), (-2.0, 1.5, -0.3), (-2.3, 1.6, 0.7)],
    # 15 cm from three surfaces
    "corner": [(-3.85, 1.15, -1.85), (3.85, 1.15, -1.85), (-3.85, 1.15, 1.85), (-3.85, 3.35, -1.85)],
}
CHECK_RAYS = 512  # ray directions (spherical Fibonacci) of the free-space check of a real scene's points
UNITS_NOTE = "E in W/m^2 (glTF units: cd / m^2, lux); RGB mean per receiver; dirs = the 6 axis normals per point"


# ------------------------------------------------------------------ geometry checks
def _glb_json(data: bytes) -> tuple[dict, bytes]:
    js_len = int.from_bytes(data[12:16], "little")
    doc = json.loads(data[20:20 + js_len])
    off = 20 + js_len
    n = int.from_bytes(data[off:off + 4], "little")
    return doc, data[off + 8:off + 8 + n]


def triangles(data: bytes) -> np.ndarray:
    """(T, 3, 3) float64 world-space triangles of a procedural GLB (identity node transforms)."""
    doc, blob = _glb_json(data)
    out = []

    def acc(i, dtype, width):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        arr = np.frombuffer(blob, dtype, a["count"] * width, v["byteOffset"] + a.get("byteOffset", 0))
        return arr.reshape(a["count"], width)

    for mesh in doc["meshes"]:
        for p in mesh["primitives"]:
            pos = acc(p["attributes"]["POSITION"], np.float32, 3).astype(np.float64)
            idx = acc(p["indices"], np.uint32, 1).reshape(-1, 3)
            out.append(pos[idx])
    return np.concatenate(out)


def _crossings(tris: np.ndarray, o, d) -> int:
    o, d = np.asarray(o, float), np.asarray(d, float)
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - tris[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return int((ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)).sum())


def inside(tris: np.ndarray, p) -> bool:
    """Parity test along two oblique directions (they must agree)."""
    a = _crossings(tris, p, (0.3117, 0.8123, 0.4931)) % 2
    b = _crossings(tris, p, (-0.5237, 0.2719, -0.8073)) % 2
    if a != b:
        raise RuntimeError(f"parity disagrees at {p}")
    return bool(a)


def clearance(tris: np.ndarray, p) -> float:
    """A lower bound of the distance from p to the surface: the distance to each triangle's bounding box (exact for
    the axis-aligned grid-cell faces of the procedural scenes, whose triangles are halves of rectangles)."""
    lo, hi = tris.min(axis=1), tris.max(axis=1)
    d = np.maximum(np.maximum(lo - p, 0.0), p - hi)
    return float(np.sqrt((d * d).sum(axis=1)).min())


def surface_distance(tris: np.ndarray, p) -> float:
    """The exact distance from p to the nearest triangle (closest point on each triangle, Ericson 5.1.5)."""
    p = np.asarray(p, np.float64)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        q = a + ab * (vb / den)[:, None] + ac * (vc / den)[:, None]              # inside the face
        edge_ab = a + ab * (d1 / (d1 - d3))[:, None]
        edge_ac = a + ac * (d2 / (d2 - d6))[:, None]
        edge_bc = b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]
    for mask, val in [((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), edge_bc),
                      ((vb <= 0) & (d2 >= 0) & (d6 <= 0), edge_ac),
                      ((d6 >= 0) & (d5 <= d6), c), ((vc <= 0) & (d1 >= 0) & (d3 <= 0), edge_ab),
                      ((d3 >= 0) & (d4 <= d3), b), ((d1 <= 0) & (d2 <= 0), a)]:
        q = np.where(mask[:, None], val, q)                                      # later cases take precedence
    dist = np.sqrt(((q - p) ** 2).sum(1))
    return float(np.nanmin(dist))


def fibonacci_dirs(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    y = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - y * y)
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


class ExternalScene:
    """A real scene of :data:`EXTERNAL`, read through Kiln's ingest: its triangles (world space, node transforms
    applied) and Kiln's ray caster, for the free-space checks."""

    def __init__(self, name: str):
        from workers.gltf import ingest_file
        from workers.raycast import caster_for_scene

        self.name, self.spec = name, EXTERNAL[name]
        self.path = external_path(name)
        self.data = self.path.read_bytes()
        self.scene = ingest_file(self.path)
        self.tris = np.asarray(self.scene.triangles, np.float64)
        self.caster = caster_for_scene(self.scene)
        self.dirs = fibonacci_dirs(CHECK_RAYS)

    def ray_clearance(self, p) -> float:
        """The nearest hit of CHECK_RAYS rays from p (inf when all miss)."""
        o = np.repeat(np.asarray([p], np.float64), len(self.dirs), axis=0)
        return float(np.min(self.caster.intersect(o, self.dirs).t))

    def free(self, p, need: float) -> tuple[bool, str]:
        d = surface_distance(self.tris, p)
        r = self.ray_clearance(p)
        par = bool(self.caster.inside_parity(np.asarray([p], np.float64))[0])
        ok = d >= need - 1e-6 and r >= need - 1e-6 and not par
        return ok, f"distance {d:.4f} m, nearest of {CHECK_RAYS} rays {r:.4f} m, inside (parity) {par}"


def external_path(name: str) -> Path:
    return SHARED_SCENES / EXTERNAL[name]["source"]


def probe_grid(tris: np.ndarray):
    """counts, origin, spacing of the grid place.counts = [8, 8, 8] (place stage: counts over the scene bounds)."""
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    counts = np.array(DEFAULT_COUNTS)
    spacing = (hi - lo) / (counts - 1)
    return counts, lo, spacing


def probe_points(scene: str, tris: np.ndarray, ext: ExternalScene | None = None) -> list[list[float]]:
    counts, origin, spacing = probe_grid(tris)
    need = EXTERNAL[scene]["probe_clearance"] if ext else PROBE_CLEARANCE.get(scene, 0.15)
    boxes = EXTERNAL[scene]["probe_boxes"] if ext else [(None, PROBES_PER_SCENE)]
    out = []
    for box, n in boxes:
        free = []
        for k in range(counts[2]):
            for j in range(counts[1]):
                for i in range(counts[0]):
                    p = origin + spacing * np.array([i, j, k])
                    p = np.array([float(np.float32(x)) for x in p])  # as the place stage stores them (float32)
                    if box is not None and not (np.all(p >= box[0]) and np.all(p <= box[1])):
                        continue
                    if ext is not None:
                        if ext.free(p, need)[0]:
                            free.append(p)
                    elif clearance(tris, p) >= need and not inside(tris, p):
                        free.append(p)
        if free:
            pick = np.unique(np.linspace(0, len(free) - 1, min(n, len(free))).round().astype(int))
            out += [[float(x) for x in free[i]] for i in pick]
    return out


def points_doc(scene: str) -> dict:
    ext = ExternalScene(scene) if scene in EXTERNAL else None
    data = ext.data if ext else make_scene(scene)
    tris = ext.tris if ext else triangles(data)
    pts: list[list[float]] = []
    regions: dict[str, list[int]] = {}
    checks = []
    for region, plist in {**REGIONS[scene], "probes": probe_points(scene, tris, ext)}.items():
        regions[region] = []
        for p in plist:
            p = [float(x) for x in p]
            if ext:
                need = EXTERNAL[scene]["min_clearance"]
                ok, why = ext.free(p, need)
                if not ok:
                    raise ValueError(f"{scene} {region} point {p} is not in free space ({why}; need {need} m)")
                checks.append(round(min(surface_distance(tris, p), ext.ray_clearance(p)), 4))
            else:
                c = clearance(tris, np.asarray(p))
                if c < MIN_CLEARANCE or inside(tris, p):
                    raise ValueError(f"{scene} {region} point {p} is not in free space (clearance {c:.3f} m)")
            regions[region].append(len(pts))
            pts.append(p)
    counts, origin, spacing = probe_grid(tris)
    doc = {"scene": scene, "points": pts, "regions": regions,
           "probe_grid": {"counts": counts.tolist(), "origin": origin.tolist(), "spacing": spacing.tolist(),
                          "note": "the grid of place.counts = [8, 8, 8] over the scene bounds; "
                                  "'probes' are un-relocated positions of it"},
           "glb_sha256": hashlib.sha256(data).hexdigest()}
    if ext:
        doc["source"] = EXTERNAL[scene]["source"]
        doc["source_note"] = ("a real scene, read from ../shared/scenes/<source> (never copied into the project); "
                              "the bench bakes it with the default config plus 'config'")
        doc["config"] = EXTERNAL[scene]["config"]
        doc["clearance"] = checks
        doc["clearance_note"] = (f"per point: min(exact distance to the nearest triangle, nearest hit of {CHECK_RAYS} "
                                 f"rays), metres; every point >= {EXTERNAL[scene]['min_clearance']} m, outside by "
                                 "parity")
    return doc


def write_points(scene: str) -> Path:
    path = HERE / f"{scene}.points.json"
    path.write_text(json.dumps(points_doc(scene), indent=1) + "\n")
    return path


# ------------------------------------------------------------------ oracle runs
def _strip_punctual(data: bytes) -> bytes:
    """The GLB without its KHR_lights_punctual lights (emissive surfaces stay)."""
    import struct

    doc, blob = _glb_json(data)
    doc.pop("extensions", None)
    doc["extensionsUsed"] = [e for e in doc.get("extensionsUsed", []) if e != "KHR_lights_punctual"]
    if not doc["extensionsUsed"]:
        del doc["extensionsUsed"]
    keep = [i for i, n in enumerate(doc["nodes"]) if "KHR_lights_punctual" not in n.get("extensions", {})]
    remap = {old: new for new, old in enumerate(keep)}
    doc["nodes"] = [doc["nodes"][i] for i in keep]
    for sc in doc["scenes"]:
        sc["nodes"] = [remap[i] for i in sc["nodes"] if i in remap]
    js = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    return b"".join([struct.pack("<III", 0x46546C67, 2, 28 + len(js) + len(blob)),
                     struct.pack("<II", len(js), 0x4E4F534A), js, struct.pack("<II", len(blob), 0x004E4942), blob])


# ------------------------------------------------------------------ coincident faces (for Cycles)
COINCIDENT_LEVEL = 48      # barycentric grid level of the "covered" test (1225 sample points per triangle)
COINCIDENT_TOL = 1e-5      # metres: plane distance and in-triangle tolerance
_COMP = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _glb_parts(data: bytes) -> tuple[dict, bytes, bytes]:
    """(JSON, BIN chunk data, the chunks after BIN) of a GLB with a BIN chunk right after JSON."""
    js_len = int.from_bytes(data[12:16], "little")
    doc = json.loads(data[20:20 + js_len])
    off = 20 + js_len
    n = int.from_bytes(data[off:off + 4], "little")
    if data[off + 4:off + 8] != b"BIN\x00":
        raise ValueError("GLB without a BIN chunk after JSON")
    return doc, data[off + 8:off + 8 + n], data[off + 8 + n:]


def _accessor(doc: dict, blob: bytes, i: int) -> np.ndarray:
    a = doc["accessors"][i]
    v = doc["bufferViews"][a["bufferView"]]
    dt, w = np.dtype(_COMP[a["componentType"]]), _WIDTH[a["type"]]
    start = v.get("byteOffset", 0) + a.get("byteOffset", 0)
    stride = v.get("byteStride") or dt.itemsize * w
    rows = np.frombuffer(blob, np.uint8, (a["count"] - 1) * stride + dt.itemsize * w, start) if a["count"] else b""
    if not a["count"]:
        return np.zeros((0, w), dt)
    return np.lib.stride_tricks.as_strided(rows.view(np.uint8), (a["count"], dt.itemsize * w), (stride, 1)) \
        .copy().view(dt).reshape(a["count"], w)


def _node_matrices(doc: dict) -> dict[int, np.ndarray]:
    """World matrix (4x4) of every node reachable from the default scene."""
    def local(n):
        if "matrix" in n:
            return np.asarray(n["matrix"], np.float64).reshape(4, 4).T
        t = np.eye(4)
        t[:3, 3] = n.get("translation", [0, 0, 0])
        x, y, z, w = n.get("rotation", [0, 0, 0, 1])
        r = np.eye(4)
        r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
        sc = np.diag([*n.get("scale", [1, 1, 1]), 1.0])
        return t @ r @ sc

    out: dict[int, np.ndarray] = {}

    def walk(i, parent):
        out[i] = parent @ local(doc["nodes"][i])
        for c in doc["nodes"][i].get("children", []):
            walk(c, out[i])

    for i in doc["scenes"][doc.get("scene", 0)]["nodes"]:
        walk(i, np.eye(4))
    return out


def _in_tri(p: np.ndarray, tri: np.ndarray, tol: float) -> np.ndarray:
    """(M,) bool: 2D points p (M, 2) inside (or within ~tol of) the 2D triangle tri (3, 2)."""
    a, b, c = tri
    area2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    sgn = 1.0 if area2 > 0 else -1.0
    ok = np.ones(len(p), bool)
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        cross = e[0] * (p[:, 1] - u[1]) - e[1] * (p[:, 0] - u[0])
        ok &= sgn * cross >= -tol * np.hypot(e[0], e[1])
    return ok


def drop_coincident(data: bytes) -> tuple[bytes, dict]:
    """The GLB without the triangles that other coplanar triangles cover entirely (for Cycles).

    Some real scenes stack several triangulations of one surface (living_room.glb: 72 of its 1551 non-degenerate
    triangles lie under others, e.g. the window wall twice over, the lintels' undersides inside the ceiling quad).
    Blender 3.4's Cycles does not offset rays (it only skips the triangle a ray leaves), so a ray leaving such a
    surface hits the coincident copy at distance ~0: those patches bake black (measured: 0.02 W/m2 facing the left
    window strip, where Kiln reads 4.0 and 2 cm to the right the wall is lit normally). Kiln's caster reads them as
    the surface they are. This removes a triangle when every point of a barycentric grid of it (level
    :data:`COINCIDENT_LEVEL`, shrunk by 0.2% about its centroid) lies in the union of the other coplanar triangles
    still kept (smallest first; a covering triangle must face the same way unless both materials are double-sided),
    so the surfaces (their union) stay the same; a covered triangle of another material takes the covering one's
    (on living_room.glb the lintels' undersides become ceiling, which is what Kiln's rays return there 98% of the
    time). Degenerate triangles are kept. The kept indices go to new accessors appended after the original binary
    data (which is kept byte for byte). Returns the GLB and a report."""
    import struct

    doc, blob, rest = _glb_parts(data)
    mats = doc.get("materials", [])
    world = _node_matrices(doc)
    meshes: dict[int, int] = {}
    for ni in world:
        m = doc["nodes"][ni].get("mesh")
        if m is not None:
            if m in meshes:
                raise NotImplementedError(f"mesh {m} is instanced by several nodes")
            meshes[m] = ni
    tris, owner = [], []                              # world triangles; (mesh, primitive, local index)
    prim_idx = {}
    for m, ni in meshes.items():
        for pi, prim in enumerate(doc["meshes"][m]["primitives"]):
            if prim.get("mode", 4) != 4:
                continue
            pos = _accessor(doc, blob, prim["attributes"]["POSITION"]).astype(np.float64)
            idx = (_accessor(doc, blob, prim["indices"]).reshape(-1) if "indices" in prim
                   else np.arange(len(pos))).astype(np.int64).reshape(-1, 3)
            prim_idx[(m, pi)] = idx
            wp = pos @ world[ni][:3, :3].T + world[ni][:3, 3]
            tris.append(wp[idx])
            owner += [(m, pi, k, prim.get("material")) for k in range(len(idx))]
    T = np.concatenate(tris)
    g = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    area = np.linalg.norm(g, axis=1) / 2
    ok = area > 1e-10
    n = np.zeros_like(g)
    n[ok] = g[ok] / (2 * area[ok, None])
    first = np.where(np.abs(n[:, 0]) > 1e-6, n[:, 0], np.where(np.abs(n[:, 1]) > 1e-6, n[:, 1], n[:, 2]))
    sign = np.where(first < 0, -1.0, 1.0)
    nc = n * sign[:, None]
    d = (nc * T[:, 0]).sum(1)
    groups: dict[tuple, list[int]] = {}
    for i in np.flatnonzero(ok):
        groups.setdefault(tuple(np.round(np.r_[nc[i] * 1e3, d[i] / COINCIDENT_TOL / 10]).astype(np.int64)),
                          []).append(int(i))
    L = COINCIDENT_LEVEL
    bary = np.array([(i, j, L - i - j) for i in range(L + 1) for j in range(L + 1 - i)], np.float64) / L
    bary = bary * (1 - 2e-3) + 2e-3 / 3

    def double(i):
        mi = owner[i][3]
        return mi is not None and bool(mats[mi].get("doubleSided", False))

    dropped: list[int] = []
    pairs: dict[str, int] = {}
    for key, members in groups.items():
        if len(members) < 2:
            continue
        nv = nc[members[0]]
        t = np.cross(nv, [1.0, 0, 0] if abs(nv[0]) < 0.9 else [0, 1.0, 0])
        t /= np.linalg.norm(t)
        b = np.cross(nv, t)
        flat = {i: np.stack([T[i] @ t, T[i] @ b], 1) for i in members}
        if max(abs(float(nv @ v) - d[i]) for i in members for v in T[i]) > COINCIDENT_TOL:
            continue                                   # not one plane after all (a rounding neighbour)
        kept = set(members)
        for i in sorted(members, key=lambda i: (area[i], i)):
            cover = [j for j in kept if j != i and (sign[j] == sign[i] or (double(i) and double(j)))]
            if not cover:
                continue
            pts = bary @ flat[i]
            inside_any = np.zeros(len(pts), bool)
            for j in cover:
                inside_any |= _in_tri(pts, flat[j], COINCIDENT_TOL)
            if inside_any.all():
                kept.discard(i)
                dropped.append(i)
                by = sorted({owner[j][3] for j in cover if _in_tri(pts, flat[j], COINCIDENT_TOL).any()}, key=str)
                name = lambda mi: mats[mi].get("name", str(mi)) if mi is not None else "default"  # noqa: E731
                k = f"{name(owner[i][3])} under {'+'.join(name(x) for x in by)}"
                pairs[k] = pairs.get(k, 0) + 1
    report = {"triangles": int(len(T)), "degenerate_kept": int((~ok).sum()), "dropped": len(dropped),
              "dropped_area_m2": round(float(area[dropped].sum()), 4), "by_material": pairs}
    if not dropped:
        return data, report
    drop_by_prim: dict[tuple, list[int]] = {}
    for i in dropped:
        m, pi, k, _ = owner[i]
        drop_by_prim.setdefault((m, pi), []).append(k)
    new_blob = bytearray(blob)
    new_blob += b"\x00" * (-len(new_blob) % 4)
    for (m, pi), ks in sorted(drop_by_prim.items()):
        keep = np.delete(prim_idx[(m, pi)], ks, axis=0).astype(np.uint32).reshape(-1)
        off = len(new_blob)
        new_blob += keep.tobytes()
        doc["bufferViews"].append({"buffer": 0, "byteOffset": off, "byteLength": keep.nbytes, "target": 34963})
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5125,
                                 "count": int(keep.size), "type": "SCALAR"})
        doc["meshes"][m]["primitives"][pi]["indices"] = len(doc["accessors"]) - 1
    new_blob += b"\x00" * (-len(new_blob) % 4)
    doc["buffers"][0]["byteLength"] = len(new_blob)
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    out = b"".join([struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(new_blob) + len(rest)),
                    struct.pack("<II", len(js), 0x4E4F534A), js,
                    struct.pack("<II", len(new_blob), 0x004E4942), bytes(new_blob), rest])
    return out, report


def same_surfaces(a: Path, b: Path, origins: np.ndarray, n_dirs: int = 512) -> dict:
    """Kiln's rays from ``origins`` in ``n_dirs`` directions against the scenes of GLBs a and b (Kiln's ingest):
    how many hit distances or materials differ (b = a with coincident triangles dropped: none may)."""
    from workers.gltf import ingest_file
    from workers.raycast import caster_for_scene

    dirs = fibonacci_dirs(n_dirs)
    o = np.repeat(origins, len(dirs), axis=0)
    dd = np.tile(dirs, (len(origins), 1))
    res = []
    for path in (a, b):
        sc = ingest_file(path)
        h = caster_for_scene(sc).intersect(o, dd)
        names = np.array([m.get("name", "") for m in sc.materials] + [""])
        res.append((np.asarray(h.t, np.float64), names[np.where(h.tri >= 0, np.asarray(sc.material)[h.tri], -1)]))
    (ta, ma), (tb, mb) = res
    both_inf = np.isinf(ta) & np.isinf(tb)
    with np.errstate(invalid="ignore"):
        dt = np.where(both_inf, 0.0, np.abs(ta - tb))
    return {"rays": int(len(o)), "t_differs": int((dt > 1e-4).sum()), "max_dt": float(np.nanmax(dt)),
            "material_differs": int((ma != mb).sum()),
            "material_differs_pairs": {f"{x}->{y}": int(((ma == x) & (mb == y)).sum())
                                       for x, y in sorted({(x, y) for x, y in zip(ma[ma != mb], mb[ma != mb])})}}


def with_lights(data: bytes, lights: list[dict]) -> bytes:
    """The GLB with ``lights`` (config lights: point/spot/directional, KHR_lights_punctual units) added as
    KHR_lights_punctual lights on new root nodes of the default scene: only the JSON chunk changes; the binary
    chunk (and any other) is kept byte for byte."""
    import struct

    assert data[:4] == b"glTF" and int.from_bytes(data[4:8], "little") == 2
    js_len = int.from_bytes(data[12:16], "little")
    doc = json.loads(data[20:20 + js_len])
    rest = data[20 + js_len:]                            # the chunks after JSON, unchanged
    ext = doc.setdefault("extensions", {}).setdefault("KHR_lights_punctual", {"lights": []})
    used = doc.setdefault("extensionsUsed", [])
    if "KHR_lights_punctual" not in used:
        used.append("KHR_lights_punctual")
    scene = doc["scenes"][doc.get("scene", 0)]
    for k, light in enumerate(lights):
        lt = {"type": light["type"], "color": list(light.get("color", [1.0, 1.0, 1.0])),
              "intensity": float(light.get("intensity", 1.0)), "name": f"kiln_config_light_{k}"}
        if light.get("range") is not None:
            lt["range"] = float(light["range"])
        node = {"name": f"kiln_config_light_{k}", "extensions": {"KHR_lights_punctual": {"light": len(ext["lights"])}}}
        if light["type"] in ("point", "spot"):
            node["translation"] = [float(x) for x in light["position"]]
        if light["type"] in ("spot", "directional"):
            # glTF lights shine along the node's local -Z: rotate -Z onto the light's direction
            d = np.asarray(light["direction"], np.float64)
            d /= np.linalg.norm(d)
            axis = np.cross([0.0, 0.0, -1.0], d)
            s_, c_ = np.linalg.norm(axis), float(np.dot([0.0, 0.0, -1.0], d))
            if s_ < 1e-12:
                q = [0.0, 0.0, 0.0, 1.0] if c_ > 0 else [1.0, 0.0, 0.0, 0.0]
            else:
                ang = math.atan2(s_, c_)
                q = [*(axis / s_ * math.sin(ang / 2)).tolist(), math.cos(ang / 2)]
            node["rotation"] = q
        if light["type"] == "spot":
            lt["spot"] = {"innerConeAngle": float(light.get("inner_cone_angle", 0.0)),
                          "outerConeAngle": float(light.get("outer_cone_angle", math.pi / 4))}
        ext["lights"].append(lt)
        scene.setdefault("nodes", []).append(len(doc["nodes"]))
        doc["nodes"].append(node)
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    return b"".join([struct.pack("<III", 0x46546C67, 2, 20 + len(js) + len(rest)),
                     struct.pack("<II", len(js), 0x4E4F534A), js, rest])


def has_emitters(data: bytes) -> bool:
    doc, _ = _glb_json(data)
    return any(max(m.get("emissiveFactor", [0, 0, 0])) > 0 for m in doc.get("materials", []))


def run_oracle(glb: Path, points: Path, out: Path, *, samples: int, seed: int, material: str, timeout: float,
               log: Path, reuse: bool = False, sky=(0.0, 0.0, 0.0)) -> tuple[dict, float]:
    sky = [float(x) for x in sky]
    if reuse and out.exists() and out.with_suffix(".wall").exists():
        res = json.loads(out.read_text())
        npts = len(json.loads(points.read_text())["points"])
        if (res["samples"], res["material"], res["seed"], len(res["points"])) == (samples, material, seed, npts) \
                and res.get("glb_sha256") == hashlib.sha256(glb.read_bytes()).hexdigest() \
                and res.get("sky", [0.0, 0.0, 0.0]) == sky:
            return res, float(out.with_suffix(".wall").read_text())
    cmd = ["nice", "-n", "10", shutil.which("blender") or "blender", "-b", "--factory-startup", "--python",
           str(WRAPPER), "--", str(glb), str(points), str(out), "--samples", str(samples), "--bounces", "64",
           "--seed", str(seed), "--sky", ",".join(repr(x) for x in sky), "--material", material]
    if material == "importer":
        cmd += ["--glossy", str(GLOSSY)]
    t0 = time.perf_counter()
    with open(log, "w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, timeout=timeout,
                           env={**os.environ, "KILN_ORACLE": str(ORACLE)})
    wall = time.perf_counter() - t0
    if r.returncode != 0 or not out.exists():
        raise RuntimeError(f"oracle failed ({r.returncode}); see {log}:\n" + log.read_text()[-3000:])
    res = json.loads(out.read_text())
    res["glb_sha256"] = hashlib.sha256(glb.read_bytes()).hexdigest()
    res["sky"] = sky
    out.write_text(json.dumps(res))
    out.with_suffix(".wall").write_text(f"{wall:.2f}")
    return res, wall


def _r(x, digits=6):
    """Round nested floats to ``digits`` significant digits (small files)."""
    a = np.asarray(x, np.float64)
    with np.errstate(divide="ignore"):
        mag = np.where(a == 0, 0, np.floor(np.log10(np.abs(np.where(a == 0, 1, a)))))
    scale = 10.0 ** (digits - 1 - mag)
    return (np.round(a * scale) / scale).tolist()


def reference(scene: str, material: str, samples: int, seeds: list[int], timeout: float, work: Path,
              reuse: bool = False, emit_seeds: int | None = None, direct_samples: int = 1024,
              direct_seeds: int = 1, points_file: Path | None = None) -> dict:
    """The Cycles reference of ``scene`` at the points of ``points_file`` (default: ``<scene>.points.json`` here)."""
    points_file = points_file or HERE / f"{scene}.points.json"
    tag = "" if points_file.parent == HERE else f"{points_file.parent.name}."   # work-file names of another set
    external = scene in EXTERNAL
    fix = None
    if external:
        src = external_path(scene).read_bytes()
        section = EXTERNAL[scene]["config"].get("scene", {})
        base = src
        if EXTERNAL[scene].get("drop_coincident"):
            base, fix = drop_coincident(src)
            (work / f"{scene}.clean.glb").write_bytes(base)
            pts_ = np.asarray(json.loads(points_file.read_text())["points"], np.float64)
            fix["check"] = same_surfaces(external_path(scene), work / f"{scene}.clean.glb", pts_)
            print(f"  {scene}: dropped {fix['dropped']} coincident triangles for Cycles ({fix['by_material']}); "
                  f"Kiln's rays from the check points: {fix['check']}", flush=True)
            if fix["check"]["t_differs"]:
                raise RuntimeError(f"{scene}: dropping coincident triangles changed the surfaces: {fix['check']}")
        data = with_lights(base, section.get("lights", []))
        sky = [float(x) for x in section.get("sky", [0.0, 0.0, 0.0])]
    else:
        src = data = make_scene(scene)
        sky = [0.0, 0.0, 0.0]
    glb = work / f"{scene}.glb"
    glb.write_bytes(data)
    pdoc = json.loads(points_file.read_text())
    if pdoc["glb_sha256"] != hashlib.sha256(src).hexdigest() \
            or (external and pdoc.get("config") != EXTERNAL[scene]["config"]):
        raise RuntimeError(f"{scene}.points.json was made for another version of the scene: rerun --points-only")
    pts = work / f"{scene}.{tag}points.json"
    pts.write_text(json.dumps({"points": pdoc["points"]}))
    emit = has_emitters(data)
    use_sky = max(sky) > 0
    if emit and use_sky:
        raise NotImplementedError(f"{scene}: a sky and emissive surfaces together (E_probe needs the punctual "
                                  "lights' direct light alone: not implemented)")
    if emit:
        (work / f"{scene}.emit.glb").write_bytes(_strip_punctual(data))
    runs, walls, emit_runs, emit_walls, direct_runs, direct_walls = [], [], [], [], [], []
    for seed in seeds:
        out = work / f"{scene}.{tag}{material}.{seed}.json"
        res, wall = run_oracle(glb, pts, out, samples=samples, seed=seed, material=material, timeout=timeout,
                               log=work / f"{out.stem}.log", reuse=reuse, sky=sky)
        runs.append(res)
        walls.append(wall)
        print(f"  {scene} {material} seed {seed}: {wall:.0f} s wall ({res['bake_s']:.0f} s baking), "
              f"{res['n_receivers']} receivers{f', sky {sky}' if use_sky else ''}", flush=True)
        if use_sky and len(direct_runs) < direct_seeds:
            out = work / f"{scene}.{tag}{material}.{seed}.sky0.json"
            res, wall = run_oracle(glb, pts, out, samples=direct_samples, seed=seed, material=material,
                                   timeout=timeout, log=work / f"{out.stem}.log", reuse=reuse)
            direct_runs.append(res)
            direct_walls.append(wall)
            print(f"  {scene} {material} seed {seed} (sky 0, {direct_samples} spp: the lights' direct light): "
                  f"{wall:.0f} s", flush=True)
        if emit and (emit_seeds is None or len(emit_runs) < emit_seeds):
            out = work / f"{scene}.{tag}{material}.{seed}.emit.json"
            res, wall = run_oracle(work / f"{scene}.emit.glb", pts, out, samples=samples, seed=seed,
                                   material=material, timeout=timeout, log=work / f"{out.stem}.log", reuse=reuse)
            emit_runs.append(res)
            emit_walls.append(wall)
            print(f"  {scene} {material} seed {seed} (emitters only): {wall:.0f} s", flush=True)
    d = np.array([r["E_direct_rgb"] for r in runs])      # (S, P, 6, 3)
    i = np.array([r["E_indirect_rgb"] for r in runs])
    probe = i + (np.array([r["E_direct_rgb"] for r in emit_runs]).mean(0) if emit else 0.0)
    d0 = None
    if use_sky:
        # E_total(sky) - E_direct(sky 0): the indirect light plus the sky seen directly (Cycles: direct light)
        d0 = np.array([r["E_direct_rgb"] for r in direct_runs]).mean(0)
        probe = i + d - d0
    lum = probe.mean(-1)                                  # (S, P, 6)
    spread = {}
    S = len(seeds)
    if S >= 2:
        m = lum.mean(0)
        ok = m > 1e-9 * max(float(m.max()), 1e-30)
        sem = lum.std(0, ddof=1) / math.sqrt(S)
        spread["receiver_rel_sem_rms"] = float(np.sqrt(np.mean((sem[ok] / m[ok]) ** 2))) if ok.any() else 0.0
        spread["region_rel_spread"], spread["region_rel_sem"] = {}, {}
        for reg, idx in pdoc["regions"].items():
            r = lum[:, idx].mean(axis=(1, 2))            # (S,) region means per seed
            mu = float(r.mean())
            spread["region_rel_spread"][reg] = float(r.max() - r.min()) / mu if mu > 0 else 0.0
            spread["region_rel_sem"][reg] = float(r.std(ddof=1) / math.sqrt(S)) / mu if mu > 0 else 0.0
        spread["note"] = (f"over {S} seeds, of E_probe (RGB mean): per region (max - min) / mean of the seeds' region "
                          "means, and the standard error of their mean / mean; per receiver the RMS of its relative "
                          "standard error")
    extra = {}
    if external:
        extra = {"source": EXTERNAL[scene]["source"], "config": EXTERNAL[scene]["config"],
                 "oracle_glb_sha256": hashlib.sha256(data).hexdigest(),
                 "oracle_glb_note": "the source GLB with config.scene.lights added as KHR_lights_punctual nodes "
                                    "(JSON chunk patched; the binary chunk kept byte for byte"
                                    + (", new index accessors appended after it: coincident triangles dropped, "
                                       "see oracle_scene_fix)" if fix and fix["dropped"] else ")"),
                 "oracle_scene_fix": fix}
    if use_sky:
        extra["sky_direct_runs"] = {
            "seeds": seeds[:len(direct_runs)], "samples": direct_samples,
            "wall_seconds": [round(w, 1) for w in direct_walls],
            "note": "sky 0: their E_direct (mean over these seeds) is the punctual lights' direct light; "
                    "E_probe = E_indirect + E_direct(sky) - that, per seed"}
        extra["E_direct_lights_rgb"] = _r(d0)
    return {
        **extra,
        "scene": scene, "material": material,
        "oracle": {"script": "cycles_irradiance_points.py (../shared/oracle) via tests/data/fidelity/"
                             "oracle_lambert_textures.py (Lambert albedo follows metallic textures; emission kept)",
                   "blender": runs[0].get("blender", "3.4.1")},
        "settings": {"samples": samples, "bounces": runs[0]["bounces"], "glossy_bounces": GLOSSY
                     if material == "importer" else 0, "sky": sky, "layout": runs[0]["layout"],
                     "lighting_mode": runs[0]["lighting_mode"], "material": material},
        "seeds": seeds, "wall_seconds": [round(w, 1) for w in walls],
        "bake_seconds": [r["bake_s"] for r in runs],
        "emitter_runs": {"seeds": seeds[:len(emit_runs)], "wall_seconds": [round(w, 1) for w in emit_walls],
                         "note": "punctual lights removed: their E_direct (mean over these seeds) is the emitters' "
                                 "direct light, added to every seed's E_indirect"}
        if emit else None,
        "glb_sha256": pdoc["glb_sha256"], "units": UNITS_NOTE,
        "points": pdoc["points"], "dirs": AXES, "regions": pdoc["regions"],
        "E_direct_rgb": _r(d.mean(0)), "E_indirect_rgb": _r(i.mean(0)), "E_probe_rgb": _r(probe.mean(0)),
        "E_probe_note": "what a probe stores: E_indirect, plus the emissive surfaces' and the sky's direct light "
                        "(Cycles counts them as direct)" + ("; this scene has emitters" if emit else
                                                            "; sky: = E_total(sky) - E_direct(sky 0)" if use_sky
                                                            else "; no emitters, sky 0: = E_indirect"),
        "spread": spread,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="two-rooms-vc,metal-room", help=f"comma list of {', '.join(REGIONS)}")
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--materials", default=None, help="comma list (default: lambert, plus importer for metal-room)")
    ap.add_argument("--points-only", action="store_true", help="only (re)write the points files")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per Blender run")
    ap.add_argument("--keep", type=Path, default=None, help="keep the oracle outputs and logs here")
    ap.add_argument("--emit-seeds", type=int, default=None, help="emitter-only runs for the first N seeds only "
                    "(scenes with emitters; default: every seed)")
    ap.add_argument("--reuse", action="store_true", help="reuse per-seed oracle outputs found in --keep (same "
                    "scene bytes, points, samples, material, seed, sky)")
    ap.add_argument("--direct-samples", type=int, default=1024, help="scenes with a sky: spp of the sky-0 run that "
                    "gives the punctual lights' direct light")
    ap.add_argument("--direct-seeds", type=int, default=1, help="scenes with a sky: sky-0 runs for the first N seeds")
    args = ap.parse_args()
    scenes = [s for s in args.scenes.split(",") if s]
    for s in scenes:
        if (s not in ALL_SCENES and s not in EXTERNAL) or s not in REGIONS:
            raise SystemExit(f"no check points for scene {s!r}; have {', '.join(REGIONS)}")
    for s in [s for s in scenes if s in EXTERNAL and not external_path(s).is_file()]:
        print(f"skipping {s}: its source {external_path(s)} is not there (a real scene, read from "
              f"{SHARED_SCENES}, never copied into the project; KILN_SHARED_SCENES sets the folder)", flush=True)
        scenes.remove(s)
    for s in scenes:
        p = write_points(s)
        doc = json.loads(p.read_text())
        print(f"{p.name}: {len(doc['points'])} points, regions "
              + ", ".join(f"{k} {len(v)}" for k, v in doc["regions"].items()))
    if args.points_only:
        return
    seeds = [int(x) for x in args.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for s in scenes:
            mats = args.materials.split(",") if args.materials else MATERIALS.get(s, ("lambert",))
            for m in mats:
                t0 = time.perf_counter()
                ref = reference(s, m, args.samples, seeds, args.timeout, work, reuse=args.reuse,
                                emit_seeds=args.emit_seeds, direct_samples=args.direct_samples,
                                direct_seeds=args.direct_seeds)
                out = HERE / f"{s}.{m}.cycles.json"
                out.write_text(json.dumps(ref, separators=(",", ":")) + "\n")
                spr = {k: round(v, 4) for k, v in ref["spread"].get("region_rel_spread", {}).items()}
                print(f"{out.name}: {time.perf_counter() - t0:.0f} s; seed spread {spr}", flush=True)


if __name__ == "__main__":
    main()
