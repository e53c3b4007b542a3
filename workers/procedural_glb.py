"""The mesher and glTF writer of the procedural scenes (:mod:`workers.procedural`): solids as unions of
axis-aligned boxes minus cavities, cut into watertight grid-cell faces (:func:`grid_solid`; the module doc of
:mod:`workers.procedural`, "Solid geometry"), and a spec-valid binary glTF 2.0 writer (:func:`encode_glb`: one
buffer, 4-byte aligned bufferViews with targets, POSITION min/max, flat NORMALs, uint32 indices, materials,
textures, KHR_lights_punctual). numpy, json and struct only.
"""
from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Box3", "Material", "Light", "SceneSpec", "grid_solid", "quads_to_primitive", "quat_from_neg_z", "encode_glb",
           "solid_mesh", "inside", "EPS"]

GLB_MAGIC = 0x46546C67  # b"glTF"
CHUNK_JSON = 0x4E4F534A  # b"JSON"
CHUNK_BIN = 0x004E4942  # b"BIN\0"
ARRAY_BUFFER = 34962
ELEMENT_ARRAY_BUFFER = 34963
FLOAT = 5126
UNSIGNED_INT = 5125
UNSIGNED_BYTE = 5121
NEAREST = 9728
REPEAT = 10497
TRIANGLES = 4
EPS = 1e-9  # metres; tolerance when matching grid coordinates


# ---------------------------------------------------------------------------- geometry
Box3 = tuple[tuple[float, float, float], tuple[float, float, float]]


def inside(p, box: Box3, tol: float = EPS) -> bool:
    lo, hi = box
    return all(lo[a] - tol <= p[a] <= hi[a] + tol for a in range(3))


def grid_solid(ops: list[tuple[bool, Box3]], material_of) -> dict[str, list[np.ndarray]]:
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
            if inside(centre, box, tol=0.0):
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


def quads_to_primitive(quads: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quads -> (positions (4Q, 3) f32, flat normals (4Q, 3) f32, indices (6Q,) u32)."""
    q = np.asarray(quads, dtype=np.float64)  # (Q, 4, 3)
    n = np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    positions = q.reshape(-1, 3).astype(np.float32)
    normals = np.repeat(n, 4, axis=0).astype(np.float32)
    base = (np.arange(len(q), dtype=np.uint32) * 4)[:, None]
    indices = (base + np.array([0, 1, 2, 0, 2, 3], dtype=np.uint32)).reshape(-1)
    return positions, normals, indices


def quat_from_neg_z(direction) -> list[float]:
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
class Material:
    name: str
    base_color: tuple[float, float, float]
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    emissive_strength: float = 1.0
    metallic: float = 0.0
    roughness: float = 1.0
    base_color_png: bytes | None = None          # baseColorTexture (sRGB PNG), read with TEXCOORD_0
    metallic_roughness_png: bytes | None = None  # metallicRoughnessTexture (linear PNG: G rough, B metal)
    double_sided: bool = False                   # glTF doubleSided (written only when true)


@dataclass
class Light:
    name: str
    type: str  # "point" | "directional"
    intensity: float  # point: candela; directional: lux
    position: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None  # where the light travels
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass
class SceneSpec:
    name: str
    materials: list[Material]
    # (mesh name, {material: (pos, nrm, idx[, {"COLOR_0" | "TEXCOORD_0": array}])})
    meshes: list[tuple[str, dict[str, tuple]]]
    lights: list[Light] = field(default_factory=list)
    bake_box: Box3 | None = None  # the probe-grid box in extras.kiln_bake_box (procedural.make_scene: BAKE_BOXES[name])


def encode_glb(spec: SceneSpec) -> bytes:
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
        if component == UNSIGNED_BYTE:
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
                "POSITION": add(pos, ARRAY_BUFFER, "VEC3", FLOAT, True),
                "NORMAL": add(nrm, ARRAY_BUFFER, "VEC3", FLOAT, False),
            }
            for attr, arr in sorted((extra[0] if extra else {}).items()):
                comp = UNSIGNED_BYTE if arr.dtype == np.uint8 else FLOAT
                attributes[attr] = add(arr, ARRAY_BUFFER, f"VEC{arr.shape[1]}", comp, False)
            primitives.append({
                "attributes": attributes,
                "indices": add(idx, ELEMENT_ARRAY_BUFFER, "SCALAR", UNSIGNED_INT, False),
                "material": mat_index[mat_name],
                "mode": TRIANGLES,
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
        if m.double_sided:
            mat["doubleSided"] = True
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
            node["rotation"] = quat_from_neg_z(light.direction)
        nodes.append(node)

    while len(blob) % 4:
        blob.append(0)
    box = spec.bake_box
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
        doc["samplers"] = [{"magFilter": NEAREST, "minFilter": NEAREST, "wrapS": REPEAT, "wrapT": REPEAT}]
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
        struct.pack("<III", GLB_MAGIC, 2, total),
        struct.pack("<II", len(js), CHUNK_JSON), js,
        struct.pack("<II", len(blob), CHUNK_BIN), bytes(blob),
    ])


def solid_mesh(name: str, ops, material_of) -> tuple[str, dict[str, tuple]]:
    faces = grid_solid(ops, material_of)
    return name, {mat: quads_to_primitive(faces[mat]) for mat in sorted(faces)}
