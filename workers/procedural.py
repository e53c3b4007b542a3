"""Procedural known-answer scenes, written as binary glTF 2.0 (.glb).

The test scenes of RTXGI's harness (``cornell``, ``furnace``, ``two-rooms``) plus a
``sealed-box``, built here with numpy + json + struct only, so tests and benchmarks need
no asset files. Each file is spec-valid glTF 2.0: one buffer in the GLB BIN chunk, one
bufferView per accessor (4-byte aligned, with ``target``), POSITION accessors with
``min``/``max``, flat per-face NORMALs, uint32 indices, materials with
``pbrMetallicRoughness`` (metallic 0, roughness 1), ``emissiveFactor`` and
``KHR_materials_emissive_strength`` for emitters brighter than 1, and lights from
``KHR_lights_punctual`` attached to nodes. Units are metres, +Y up, right-handed,
counter-clockwise front faces; every node transform is the identity except light
nodes' translation/rotation, so vertex data is already world space.

Solid geometry
    Every solid (a wall, a box) is a *closed, outward-facing* triangle surface, so a
    point is inside geometry exactly when a ray from it crosses the surface an odd
    number of times (the parity test of probe classification). Each scene's solids are
    built as one union of axis-aligned boxes minus cavities (:func:`_grid_solid`):
    the boundary of the union is cut along every box coordinate into grid-cell faces,
    so the surface is watertight with no T-junctions, no coincident faces between
    touching parts (a box standing on a floor is fused with it) and no self-overlap.
    The price is that large faces are split into several quads where other boxes'
    coordinates cross them.

Scenes (T = triangle count; all lights white)

``cornell`` (T = 1036)
    Outer extent exactly [0, 1]^3. A U-shaped shell with 2 cm walls: cavity
    [0.02, 0.98] x [0.02, 0.98] x [0.02, 1] open towards +z (look at it from z > 1
    along -z). Cavity faces: left (x = 0.02) red, right (x = 0.98) green; floor, ceiling,
    back wall, the outside of the shell and both boxes white (the classic Cornell
    albedos below). Emitter: a 0.25 x 0.01 x 0.25 panel fused to the ceiling,
    [0.375, 0.625] x [0.97, 0.98] x [0.375, 0.625]; its downward face (2 triangles, at
    y = 0.97) emits (1, 1, 1) x strength 10 (W sr^-1 m^-2, i.e. radiance 10), its sides
    are white. A KHR point light "ceiling" of 1 cd sits 1 cm below the emitter's centre,
    (0.5, 0.96, 0.5), so its shadow rays do not start inside the panel. Boxes fused to the
    floor: tall [0.10, 0.36] x [0.02, 0.62] x [0.10, 0.36] (back left), short
    [0.64, 0.92] x [0.02, 0.30] x [0.64, 0.92] (front right).

``furnace`` (T = 1)
    Open space: no lights (so no KHR_lights_punctual: an empty light list is invalid glTF),
    one triangle with 1 mm legs at y = -1000 m facing down
    (vertices (0, -1000, 0), (0.001, -1000, 0), (0, -1000, 0.001)); glTF needs at least
    one triangle and ingest rejects scenes without one. The scene's own bounds are that
    1 mm triangle, so bake it with the probe box ``BAKE_BOXES["furnace"]``
    ([-2, 2]^3, 1 km away, seeing the triangle under ~5e-13 sr): every probe then sees
    only the config's uniform sky and its irradiance is pi * L.

``two-rooms`` (T = 352)
    Two closed rooms along x, interiors 4 x 3 x 4 m: A = [0, 4] x [0, 3] x [0, 4],
    B = [4.05, 8.05] x [0, 3] x [0, 4], sharing a 5 cm wall x in [4, 4.05] with a door
    opening z in [1.55, 2.45], y in [0, 2] (0.9 m x 2 m). All outer walls, floor and
    ceiling are 5 cm thick: outer extent [-0.05, 8.1] x [-0.05, 3.05] x [-0.05, 4.05].
    All surfaces grey 0.75. One KHR point light "room-a", 20 cd at (1.5, 2.5, 2.0), in
    room A only.

``sealed-box`` (T = 224)
    A floor slab [-5, 5] x [-0.1, 0] x [-5, 5] (grey 0.5) with a closed box fused onto
    it: outer [-0.5, 0.5] x [0, 1] x [-0.5, 0.5], 5 cm walls on all six sides, sealed
    cavity [-0.45, 0.45] x [0.05, 0.95] x [-0.45, 0.45] (box white 0.8 inside and out).
    A KHR directional light "sun", 3 lux, travelling along normalize(-0.4, -1, -0.3)
    (the light node's -Z, via its rotation), and a KHR point light "lamp", 15 cd at
    (2.5, 2.0, 2.5). Nothing in the cavity can see either light or the sky.

The numbers (triangle counts, coordinates) are asserted by ``tests/workers/test_procedural.py``.

Material scenes (:data:`MATERIAL_SCENES`, kept out of :data:`SCENES`, whose scenes are all rough
dielectrics with constant colours): the same conventions, but materials the outside check
(``tests/data/fidelity``, ``tests/bench/bench_fidelity.py``) needs to catch an ingest that reads a
material wrongly. Each carries its own probe-grid box (its bounds) in ``kiln_bake_box``.

``two-rooms-vc``
    The ``two-rooms`` geometry (same grid solid, same light), but every material's
    ``baseColorFactor`` is white [1, 1, 1, 1] (metallic 0, roughness 1) and the albedo is carried
    by ``COLOR_0`` (glTF multiplies the two: a reader ignoring COLOR_0 sees albedo 1). Room A's
    faces, the door's jambs and lintel and the outside ("vc-float") hold float RGB (VEC3)
    colours, room B's faces ("vc-ubyte") normalized unsigned-byte RGBA (VEC4, alpha 255). One
    colour per wall group (:data:`TWO_ROOMS_VC_COLORS`).

``metal-room``
    A closed room, interior [0, 4] x [0, 2.5] x [0, 3], 5 cm walls (outer extent
    [-0.05, 4.05] x [-0.05, 2.55] x [-0.05, 3.05]); a 12 cd point light "lamp" at (2.4, 2.0, 1.8).
    Materials (:data:`METAL_ROOM_MATERIALS`): floor "checker": ``baseColorTexture`` (an embedded
    16 x 16 sRGB PNG checker, 4 x 4-texel squares of two colours, NEAREST, REPEAT; TEXCOORD_0 =
    (z, x) / 2 m, one repeat every 2 m) times the factor (0.9, 0.85, 0.8); wall x = 4 (inside)
    "metal": metallic 1, roughness 0.5, base (0.95, 0.64, 0.54); a box [0.7, 1.5] x [0, 0.8] x
    [0.8, 1.6] fused to the floor, "striped-metal": base (0.8, 0.8, 0.8), factors 1 and a linear
    8 x 8 ``metallicRoughnessTexture`` (B = metallic 255 / 0 in 4-texel stripes along u, G =
    roughness 128, R 0; TEXCOORD_0 = the face's two in-plane coordinates / 0.4 m: two repeats per
    side, so metallic averages 0.5 on every face); every other face a rough dielectric.
"""
from __future__ import annotations

import json
import os
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from proto.atomic import atomic_write_bytes

__all__ = ["SCENES", "BAKE_BOXES", "MATERIAL_SCENES", "ALL_SCENES", "make_scene", "write_scene"]

SCENES: dict[str, str] = {
    "cornell": "1 m Cornell box open towards +z: red left / green right walls, "
               "ceiling emitter panel plus a 1 cd point light, two white boxes",
    "furnace": "open space, no lights, one 1 mm triangle 1 km below; bake with BAKE_BOXES['furnace'] "
               "and a uniform sky",
    "two-rooms": "two closed 4 x 3 x 4 m rooms sharing a 5 cm wall with a 0.9 x 2 m door, "
                 "a 20 cd point light in room A only",
    "sealed-box": "10 x 10 m floor under a sun and a point light, with a closed 1 m box "
                  "(5 cm walls) whose cavity sees no light",
}

# Probe-grid boxes ((min xyz), (max xyz), metres) meant for each scene: the scene bounds,
# except the furnace, whose bounds are its tiny far-away triangle.
BAKE_BOXES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "cornell": ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
    "furnace": ((-2.0, -2.0, -2.0), (2.0, 2.0, 2.0)),
    "two-rooms": ((-0.05, -0.05, -0.05), (8.1, 3.05, 4.05)),
    "sealed-box": ((-5.0, -0.1, -5.0), (5.0, 1.0, 5.0)),
}

# Scenes that exercise material reading (vertex colours, textures, metals); see the module doc.
MATERIAL_SCENES: dict[str, str] = {
    "two-rooms-vc": "two-rooms with white materials and the albedo in COLOR_0 vertex colours "
                    "(float RGB in room A, normalized ubyte RGBA in room B)",
    "metal-room": "closed 4 x 2.5 x 3 m room, 12 cd point light: checker-textured floor, a metallic wall, "
                  "a box with a striped metallicRoughnessTexture, dielectric walls",
}
ALL_SCENES: dict[str, str] = {**SCENES, **MATERIAL_SCENES}

# Classic Cornell box albedos (linear RGB).
_CORNELL_WHITE = (0.725, 0.71, 0.68)
_CORNELL_RED = (0.63, 0.065, 0.05)
_CORNELL_GREEN = (0.14, 0.45, 0.091)

_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A  # b"JSON"
_CHUNK_BIN = 0x004E4942  # b"BIN\0"
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_FLOAT = 5126
_UNSIGNED_INT = 5125
_UNSIGNED_BYTE = 5121
_NEAREST = 9728
_REPEAT = 10497
_TRIANGLES = 4
_EPS = 1e-9  # metres; tolerance when matching grid coordinates


# ---------------------------------------------------------------------------- geometry
Box3 = tuple[tuple[float, float, float], tuple[float, float, float]]


def _inside(p, box: Box3, tol: float = _EPS) -> bool:
    lo, hi = box
    return all(lo[a] - tol <= p[a] <= hi[a] + tol for a in range(3))


def _grid_solid(ops: list[tuple[bool, Box3]], material_of) -> dict[str, list[np.ndarray]]:
    """Boundary of a union/difference of axis-aligned boxes as flat quads, by material.

    ops : [(solid, ((x0, y0, z0), (x1, y1, z1))), ...], applied in order: a grid cell is
        solid when the last box containing it says so (everything outside is empty).
    material_of(center, axis, sign) -> material name, for a face with centre ``center``
        and outward normal ``sign`` along ``axis``.

    Returns {material: [quad (4, 3) float64 counter-clockwise seen from outside, ...]}.
    Every face is one grid-cell face between a solid and an empty cell, so edges match
    exactly between neighbouring quads: a closed, manifold surface without T-junctions.
    """
    coords = [sorted({float(box[k][a]) for _, box in ops for k in (0, 1)}) for a in range(3)]
    shape = tuple(len(c) - 1 for c in coords)
    solid = np.zeros(shape, dtype=bool)
    for idx in np.ndindex(*shape):
        centre = [0.5 * (coords[a][idx[a]] + coords[a][idx[a] + 1]) for a in range(3)]
        for is_solid, box in ops:
            if _inside(centre, box, tol=0.0):
                solid[idx] = is_solid

    faces: dict[str, list[np.ndarray]] = {}
    padded = np.pad(solid, 1, constant_values=False)
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3  # (axis, u, v) cyclic: u x v = +axis
        for idx in np.ndindex(*padded.shape):
            if idx[axis] == padded.shape[axis] - 1:
                continue
            nxt = list(idx)
            nxt[axis] += 1
            a, b = padded[idx], padded[tuple(nxt)]
            if a == b:
                continue
            sign = 1 if a else -1  # normal points from the solid cell to the empty one
            cell = [i - 1 for i in idx]  # un-padded index of the lower cell
            c = coords[axis][cell[axis] + 1]
            u0, u1 = coords[u][cell[u]], coords[u][cell[u] + 1]
            v0, v1 = coords[v][cell[v]], coords[v][cell[v] + 1]
            corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
            if sign < 0:
                corners = corners[::-1]
            quad = np.zeros((4, 3))
            for k, (cu, cv) in enumerate(corners):
                quad[k, axis], quad[k, u], quad[k, v] = c, cu, cv
            name = material_of(quad.mean(axis=0), axis, sign)
            faces.setdefault(name, []).append(quad)
    return faces


def _quads_to_primitive(quads: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quads -> (positions (4Q, 3) f32, flat normals (4Q, 3) f32, indices (6Q,) u32)."""
    q = np.asarray(quads, dtype=np.float64)  # (Q, 4, 3)
    n = np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    positions = q.reshape(-1, 3).astype(np.float32)
    normals = np.repeat(n, 4, axis=0).astype(np.float32)
    base = (np.arange(len(q), dtype=np.uint32) * 4)[:, None]
    indices = (base + np.array([0, 1, 2, 0, 2, 3], dtype=np.uint32)).reshape(-1)
    return positions, normals, indices


def _quat_from_neg_z(direction) -> list[float]:
    """Unit quaternion [x, y, z, w] rotating the node's -Z axis onto ``direction``."""
    a = np.array([0.0, 0.0, -1.0])
    b = np.asarray(direction, dtype=np.float64)
    b = b / np.linalg.norm(b)
    d = float(a @ b)
    if d < -1.0 + 1e-12:  # opposite: half turn about +Y
        return [0.0, 1.0, 0.0, 0.0]
    q = np.append(np.cross(a, b), 1.0 + d)
    q /= np.linalg.norm(q)
    return [float(x) for x in q]


# ---------------------------------------------------------------------------- glTF writer
@dataclass
class _Material:
    name: str
    base_color: tuple[float, float, float]
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    emissive_strength: float = 1.0
    metallic: float = 0.0
    roughness: float = 1.0
    base_color_png: bytes | None = None          # baseColorTexture (sRGB PNG), read with TEXCOORD_0
    metallic_roughness_png: bytes | None = None  # metallicRoughnessTexture (linear PNG: G rough, B metal)


@dataclass
class _Light:
    name: str
    type: str  # "point" | "directional"
    intensity: float  # point: candela; directional: lux
    position: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None  # where the light travels
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass
class _SceneSpec:
    name: str
    materials: list[_Material]
    # (mesh name, {material: (pos, nrm, idx[, {"COLOR_0" | "TEXCOORD_0": array}])})
    meshes: list[tuple[str, dict[str, tuple]]]
    lights: list[_Light] = field(default_factory=list)
    bake_box: Box3 | None = None  # None: BAKE_BOXES[name]


def _encode_glb(spec: _SceneSpec) -> bytes:
    mat_index = {m.name: i for i, m in enumerate(spec.materials)}
    blob = bytearray()
    buffer_views: list[dict] = []
    accessors: list[dict] = []

    def add(array: np.ndarray, target: int, type_: str, component: int, minmax: bool) -> int:
        while len(blob) % 4:
            blob.append(0)
        data = np.ascontiguousarray(array).tobytes()
        buffer_views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data),
                             "target": target})
        blob.extend(data)
        acc = {"bufferView": len(buffer_views) - 1, "byteOffset": 0, "componentType": component,
               "count": int(array.shape[0]), "type": type_}
        if component == _UNSIGNED_BYTE:
            acc["normalized"] = True  # vertex colours as UNORM8
        if minmax:
            acc["min"] = [float(x) for x in array.min(axis=0)]
            acc["max"] = [float(x) for x in array.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    meshes, nodes = [], []
    for mesh_name, prims in spec.meshes:
        primitives = []
        for mat_name, (pos, nrm, idx, *extra) in prims.items():
            attributes = {
                "POSITION": add(pos, _ARRAY_BUFFER, "VEC3", _FLOAT, True),
                "NORMAL": add(nrm, _ARRAY_BUFFER, "VEC3", _FLOAT, False),
            }
            for attr, arr in sorted((extra[0] if extra else {}).items()):
                comp = _UNSIGNED_BYTE if arr.dtype == np.uint8 else _FLOAT
                attributes[attr] = add(arr, _ARRAY_BUFFER, f"VEC{arr.shape[1]}", comp, False)
            primitives.append({
                "attributes": attributes,
                "indices": add(idx, _ELEMENT_ARRAY_BUFFER, "SCALAR", _UNSIGNED_INT, False),
                "material": mat_index[mat_name],
                "mode": _TRIANGLES,
            })
        meshes.append({"name": mesh_name, "primitives": primitives})
        nodes.append({"name": mesh_name, "mesh": len(meshes) - 1})
    while len(blob) % 4:
        blob.append(0)

    images: list[dict] = []
    image_of: dict[bytes, int] = {}

    def texture(png: bytes) -> dict:
        """A textureInfo for PNG bytes: one image (in the BIN chunk, a bufferView without target) per distinct PNG,
        texture i = image i, all with sampler 0."""
        if png not in image_of:
            while len(blob) % 4:
                blob.append(0)
            buffer_views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
            blob.extend(png)
            images.append({"bufferView": len(buffer_views) - 1, "mimeType": "image/png"})
            image_of[png] = len(images) - 1
        return {"index": image_of[png], "texCoord": 0}

    materials = []
    uses_strength = False
    for m in spec.materials:
        mat = {
            "name": m.name,
            "pbrMetallicRoughness": {"baseColorFactor": [*map(float, m.base_color), 1.0],
                                     "metallicFactor": float(m.metallic), "roughnessFactor": float(m.roughness)},
            "emissiveFactor": [float(x) for x in m.emissive],
        }
        if m.base_color_png is not None:
            mat["pbrMetallicRoughness"]["baseColorTexture"] = texture(m.base_color_png)
        if m.metallic_roughness_png is not None:
            mat["pbrMetallicRoughness"]["metallicRoughnessTexture"] = texture(m.metallic_roughness_png)
        if m.emissive_strength != 1.0:
            mat["extensions"] = {"KHR_materials_emissive_strength":
                                 {"emissiveStrength": float(m.emissive_strength)}}
            uses_strength = True
        materials.append(mat)

    lights = []
    for i, light in enumerate(spec.lights):
        lights.append({"name": light.name, "type": light.type,
                       "color": [float(c) for c in light.color], "intensity": float(light.intensity)})
        node: dict = {"name": light.name, "extensions": {"KHR_lights_punctual": {"light": i}}}
        if light.position is not None:
            node["translation"] = [float(x) for x in light.position]
        if light.direction is not None:
            node["rotation"] = _quat_from_neg_z(light.direction)
        nodes.append(node)

    while len(blob) % 4:
        blob.append(0)
    box = spec.bake_box if spec.bake_box is not None else BAKE_BOXES[spec.name]
    doc: dict = {
        "asset": {"version": "2.0", "generator": "kiln workers.procedural"},
        "scene": 0,
        "scenes": [{"name": spec.name, "nodes": list(range(len(nodes))),
                    "extras": {"kiln_bake_box": {"min": list(box[0]), "max": list(box[1])}}}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": accessors,
        "bufferViews": buffer_views,
        "buffers": [{"byteLength": len(blob)}],
    }
    if images:
        doc["images"] = images
        doc["textures"] = [{"source": i, "sampler": 0} for i in range(len(images))]
        doc["samplers"] = [{"magFilter": _NEAREST, "minFilter": _NEAREST, "wrapS": _REPEAT, "wrapT": _REPEAT}]
    # An empty lights array is invalid glTF (EMPTY_ENTITY): light-less scenes omit the extension.
    used = (["KHR_lights_punctual"] if lights else []) + (
        ["KHR_materials_emissive_strength"] if uses_strength else [])
    if used:
        doc["extensionsUsed"] = used
    if lights:
        doc["extensions"] = {"KHR_lights_punctual": {"lights": lights}}
    js = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(blob)
    return b"".join([
        struct.pack("<III", _GLB_MAGIC, 2, total),
        struct.pack("<II", len(js), _CHUNK_JSON), js,
        struct.pack("<II", len(blob), _CHUNK_BIN), bytes(blob),
    ])


def _solid_mesh(name: str, ops, material_of) -> tuple[str, dict[str, tuple]]:
    faces = _grid_solid(ops, material_of)
    return name, {mat: _quads_to_primitive(faces[mat]) for mat in sorted(faces)}


# ---------------------------------------------------------------------------- scenes
def _cornell() -> _SceneSpec:
    t = 0.02
    emitter: Box3 = ((0.375, 0.97, 0.375), (0.625, 1.0 - t, 0.625))
    ops = [
        (True, ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))),
        (False, ((t, t, t), (1.0 - t, 1.0 - t, 1.0))),  # cavity, open at z = 1
        (True, emitter),
        (True, ((0.10, t, 0.10), (0.36, 0.62, 0.36))),  # tall box
        (True, ((0.64, t, 0.64), (0.92, 0.30, 0.92))),  # short box
    ]

    def material_of(c, axis, sign):
        if axis == 0 and sign > 0 and abs(c[0] - t) < _EPS:
            return "red"
        if axis == 0 and sign < 0 and abs(c[0] - (1.0 - t)) < _EPS:
            return "green"
        if axis == 1 and sign < 0 and abs(c[1] - emitter[0][1]) < _EPS:
            return "emitter"
        return "white"

    return _SceneSpec(
        name="cornell",
        materials=[_Material("white", _CORNELL_WHITE), _Material("red", _CORNELL_RED),
                   _Material("green", _CORNELL_GREEN),
                   _Material("emitter", _CORNELL_WHITE, (1.0, 1.0, 1.0), 10.0)],
        meshes=[_solid_mesh("cornell-box", ops, material_of)],
        lights=[_Light("ceiling", "point", 1.0, position=(0.5, 0.96, 0.5))],
    )


def _furnace() -> _SceneSpec:
    # Clockwise seen from above: the normal is -Y, facing away from the bake box.
    pos = np.array([[0.0, -1000.0, 0.0], [0.001, -1000.0, 0.0], [0.0, -1000.0, 0.001]], np.float32)
    nrm = np.tile(np.array([0.0, -1.0, 0.0], np.float32), (3, 1))
    idx = np.array([0, 1, 2], np.uint32)
    return _SceneSpec(
        name="furnace",
        materials=[_Material("grey", (0.5, 0.5, 0.5))],
        meshes=[("speck", {"grey": (pos, nrm, idx)})],
    )


def _two_rooms_ops(t: float = 0.05) -> list[tuple[bool, Box3]]:
    return [
        (True, ((-t, -t, -t), (8.0 + 2 * t, 3.0 + t, 4.0 + t))),
        (False, ((0.0, 0.0, 0.0), (4.0, 3.0, 4.0))),  # room A
        (False, ((4.0 + t, 0.0, 0.0), (8.0 + t, 3.0, 4.0))),  # room B
        (False, ((4.0, 0.0, 1.55), (4.0 + t, 2.0, 2.45))),  # door through the shared wall
    ]


def _two_rooms() -> _SceneSpec:
    return _SceneSpec(
        name="two-rooms",
        materials=[_Material("wall", (0.75, 0.75, 0.75))],
        meshes=[_solid_mesh("rooms", _two_rooms_ops(), lambda c, axis, sign: "wall")],
        lights=[_Light("room-a", "point", 20.0, position=(1.5, 2.5, 2.0))],
    )


def _sealed_box() -> _SceneSpec:
    t = 0.05
    box: Box3 = ((-0.5, 0.0, -0.5), (0.5, 1.0, 0.5))
    ops = [
        (True, ((-5.0, -0.1, -5.0), (5.0, 0.0, 5.0))),  # floor slab
        (True, box),
        (False, ((-0.5 + t, t, -0.5 + t), (0.5 - t, 1.0 - t, 0.5 - t))),  # sealed cavity
    ]

    def material_of(c, axis, sign):
        on_box = c[1] > _EPS and abs(c[0]) < 0.5 + _EPS and abs(c[2]) < 0.5 + _EPS
        return "box" if on_box else "floor"

    return _SceneSpec(
        name="sealed-box",
        materials=[_Material("floor", (0.5, 0.5, 0.5)), _Material("box", (0.8, 0.8, 0.8))],
        meshes=[_solid_mesh("floor-and-box", ops, material_of)],
        lights=[_Light("sun", "directional", 3.0, direction=(-0.4, -1.0, -0.3)),
                _Light("lamp", "point", 15.0, position=(2.5, 2.0, 2.5))],
    )


# ---------------------------------------------------------------------------- material scenes
def _png(pixels: np.ndarray) -> bytes:
    """(H, W, 3 | 4) uint8 -> PNG bytes (8-bit RGB / RGBA, no filter, zlib level 9; deterministic)."""
    px = np.ascontiguousarray(pixels, np.uint8)
    h, w, c = px.shape
    raw = b"".join(b"\x00" + px[r].tobytes() for r in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return b"".join([b"\x89PNG\r\n\x1a\n",
                     chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, {3: 2, 4: 6}[c], 0, 0, 0)),
                     chunk(b"IDAT", zlib.compress(raw, 9)), chunk(b"IEND", b"")])


def _quad_axis(quad: np.ndarray) -> int:
    """The axis a grid-cell face is perpendicular to (its constant coordinate)."""
    return int(np.argmin(np.ptp(quad, axis=0)))


def _attr_mesh(name: str, ops, group_of, material_of_group, attrs_of) -> tuple[str, dict[str, tuple]]:
    """:func:`_solid_mesh` with per-vertex attributes: faces are grouped by ``group_of`` (as ``material_of``
    of :func:`_grid_solid`), groups are merged into primitives by ``material_of_group(group)``, and
    ``attrs_of(group, quad (4, 3), axis) -> {attribute: (4, k) array}`` gives each quad's extra attributes."""
    faces = _grid_solid(ops, group_of)
    by_mat: dict[str, list[tuple[str, np.ndarray]]] = {}
    for group in sorted(faces):
        by_mat.setdefault(material_of_group(group), []).extend((group, q) for q in faces[group])
    prims = {}
    for mat in sorted(by_mat):
        quads = [q for _, q in by_mat[mat]]
        pos, nrm, idx = _quads_to_primitive(quads)
        per_quad = [attrs_of(g, q, _quad_axis(q)) for g, q in by_mat[mat]]
        extra = {k: np.concatenate([a[k] for a in per_quad]) for k in per_quad[0]} if per_quad[0] else {}
        prims[mat] = (pos, nrm, idx, extra) if extra else (pos, nrm, idx)
    return name, prims


# two-rooms-vc: wall group -> linear RGB albedo (COLOR_0). Room A, the door and the outside as float RGB;
# room B as normalized ubyte RGBA, with values that are whole bytes (multiples of 0.2 = 51/255).
TWO_ROOMS_VC_COLORS: dict[str, tuple[float, float, float]] = {
    "a-floor": (0.7, 0.7, 0.7), "a-ceiling": (0.8, 0.8, 0.8), "a-end": (0.6, 0.3, 0.3),
    "a-shared": (0.3, 0.35, 0.6), "a-sides": (0.55, 0.6, 0.35), "door": (0.75, 0.5, 0.25),
    "outside": (0.5, 0.5, 0.5),
    "b-floor": (0.6, 0.6, 0.6), "b-ceiling": (0.8, 0.8, 0.8), "b-end": (0.2, 0.4, 0.6),
    "b-shared": (0.6, 0.4, 0.2), "b-sides": (0.4, 0.6, 0.4),
}


def _two_rooms_vc() -> _SceneSpec:
    t = 0.05
    outer = ((-t, -t, -t), (8.0 + 2 * t, 3.0 + t, 4.0 + t))

    def group_of(c, axis, sign):
        if abs(c[axis] - outer[0][axis]) < _EPS or abs(c[axis] - outer[1][axis]) < _EPS:
            return "outside"
        if axis != 0 and 4.0 - _EPS < c[0] < 4.0 + t + _EPS:
            return "door"  # jambs, lintel and threshold of the doorway
        x = c[0] + (1e-3 * sign if axis == 0 else 0.0)  # a point just in front of the face
        room = "a" if x < 4.0 else "b"
        if axis == 1:
            return f"{room}-floor" if sign > 0 else f"{room}-ceiling"
        if axis == 2:
            return f"{room}-sides"
        return f"{room}-end" if abs(c[0]) < _EPS or abs(c[0] - (8.0 + t)) < _EPS else f"{room}-shared"

    def attrs_of(group, quad, axis):
        col = np.asarray(TWO_ROOMS_VC_COLORS[group], np.float64)
        if group.startswith("b-"):
            rgba = np.append(np.round(col * 255.0), 255.0).astype(np.uint8)
            return {"COLOR_0": np.tile(rgba, (4, 1))}
        return {"COLOR_0": np.tile(col.astype(np.float32), (4, 1))}

    return _SceneSpec(
        name="two-rooms-vc",
        materials=[_Material("vc-float", (1.0, 1.0, 1.0)), _Material("vc-ubyte", (1.0, 1.0, 1.0))],
        meshes=[_attr_mesh("rooms", _two_rooms_ops(t), group_of,
                           lambda g: "vc-ubyte" if g.startswith("b-") else "vc-float", attrs_of)],
        lights=[_Light("room-a", "point", 20.0, position=(1.5, 2.5, 2.0))],
        bake_box=outer,
    )


def _checker_png() -> bytes:
    """16 x 16 sRGB checker, 4 x 4-texel squares: (230, 200, 170) and (70, 90, 110)."""
    i = np.arange(16) // 4
    light = ((i[:, None] + i[None, :]) % 2 == 0)[..., None]
    return _png(np.where(light, np.array([230, 200, 170], np.uint8), np.array([70, 90, 110], np.uint8)))


def _stripes_png() -> bytes:
    """8 x 8 linear metallic-roughness map: B (metallic) 255 in columns 0-3, 0 in 4-7; G (roughness) 128; R 0."""
    px = np.zeros((8, 8, 3), np.uint8)
    px[..., 1] = 128
    px[:, :4, 2] = 255
    return _png(px)


# metal-room: material name -> (base colour, metallic, roughness, texture); see the module doc.
METAL_ROOM_MATERIALS: dict[str, dict] = {
    "checker": {"base_color": (0.9, 0.85, 0.8), "texture": "baseColorTexture"},
    "metal": {"base_color": (0.95, 0.64, 0.54), "metallic": 1.0, "roughness": 0.5},
    "striped-metal": {"base_color": (0.8, 0.8, 0.8), "metallic": 1.0, "roughness": 1.0,
                      "texture": "metallicRoughnessTexture"},
    "ceiling": {"base_color": (0.8, 0.8, 0.8)},
    "wall-blue": {"base_color": (0.3, 0.45, 0.7)},
    "wall-beige": {"base_color": (0.7, 0.65, 0.5)},
    "outside": {"base_color": (0.5, 0.5, 0.5)},
}


def _metal_room() -> _SceneSpec:
    t = 0.05
    outer: Box3 = ((-t, -t, -t), (4.0 + t, 2.5 + t, 3.0 + t))
    obj: Box3 = ((0.7, 0.0, 0.8), (1.5, 0.8, 1.6))
    ops = [(True, outer), (False, ((0.0, 0.0, 0.0), (4.0, 2.5, 3.0))), (True, obj)]

    def group_of(c, axis, sign):
        if abs(c[axis] - outer[0][axis]) < _EPS or abs(c[axis] - outer[1][axis]) < _EPS:
            return "outside"
        if _inside(c, obj, 1e-6) and c[1] > _EPS:
            return "striped-metal"
        if axis == 1:
            return "checker" if sign > 0 else "ceiling"
        if axis == 0:
            return "metal" if sign < 0 else "wall-blue"
        return "wall-beige"

    def attrs_of(group, quad, axis):
        if group == "checker":  # (u, v) = (z, x) / 2 m
            return {"TEXCOORD_0": (quad[:, [2, 0]] / 2.0).astype(np.float32)}
        if group == "striped-metal":  # the face's (u, v) axes of _grid_solid, / 0.4 m
            return {"TEXCOORD_0": (quad[:, [(axis + 1) % 3, (axis + 2) % 3]] / 0.4).astype(np.float32)}
        return {}

    pngs = {"baseColorTexture": {"base_color_png": _checker_png()},
            "metallicRoughnessTexture": {"metallic_roughness_png": _stripes_png()}}
    mats = []
    for name, m in METAL_ROOM_MATERIALS.items():
        kw = {k: v for k, v in m.items() if k in ("metallic", "roughness")}
        mats.append(_Material(name, m["base_color"], **kw, **pngs.get(m.get("texture"), {})))
    return _SceneSpec(
        name="metal-room",
        materials=mats,
        meshes=[_attr_mesh("room", ops, group_of, lambda g: g, attrs_of)],
        lights=[_Light("lamp", "point", 12.0, position=(2.4, 2.0, 1.8))],
        bake_box=outer,
    )


_BUILDERS = {"cornell": _cornell, "furnace": _furnace, "two-rooms": _two_rooms,
             "sealed-box": _sealed_box, "two-rooms-vc": _two_rooms_vc, "metal-room": _metal_room}


def make_scene(name: str) -> bytes:
    """The GLB bytes of procedural scene ``name`` (a key of :data:`SCENES` or :data:`MATERIAL_SCENES`);
    deterministic."""
    try:
        builder = _BUILDERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown procedural scene {name!r}; valid names: "
                         f"{', '.join(sorted(ALL_SCENES))}") from None
    return _encode_glb(builder())


def write_scene(name: str, path: str | os.PathLike) -> None:
    """Write :func:`make_scene` (name) to ``path`` atomically (temp file in the same folder + rename)."""
    atomic_write_bytes(path, make_scene(name))
