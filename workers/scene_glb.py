"""The normalized scene written back as glTF 2.0 binary (GLB): the ``scene`` artifact of every bake.

A bundle carries the geometry it was baked from so that any viewer (another browser session, a shared
link, an engine importer) can show it without the original upload, which the server does not keep.

What is written (``scene_to_glb``), all in world space (one identity node per UV1 chart, glTF's frame):

- triangles as indexed primitives, one per contiguous run of triangles sharing a material (so the
  triangle order of :class:`workers.scene.NormalizedScene` is kept), with ``POSITION``, ``NORMAL``,
  ``TEXCOORD_0`` (``uv0``: the UV set the textures sample, transforms already applied), ``TEXCOORD_1``
  where the scene has it and ``COLOR_0`` (linear RGBA float) when the scene has vertex colours;
  vertices are shared only between corners whose every attribute is equal;
- materials: base colour factor and texture, metallic/roughness factors and texture, emissive factor and
  texture (``KHR_materials_emissive_strength`` when the emission exceeds 1), ``doubleSided``,
  ``alphaMode`` and ``alphaCutoff``;
- textures as PNG (the RGBA bytes as stored; base colour and emissive are sRGB-encoded as glTF says);
- the lights (the ingest stage's resolved lights: the scene's plus the config's) as ``KHR_lights_punctual``
  on their own nodes (position = translation, direction = the node's -Z axis).

``workers.gltf.ingest_file`` reads the file back to the same triangles, normals, UVs, colours and
materials (tests/workers/test_scene_glb.py).
"""
from __future__ import annotations

import io
import json
import math
import struct

import numpy as np

from workers.scene import NormalizedScene

GLB_MAGIC = b"glTF"
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125


def _png(img: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img, np.uint8), "RGBA").save(buf, format="PNG")
    return buf.getvalue()


def _runs(keys: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of equal consecutive values."""
    if len(keys) == 0:
        return []
    cut = np.flatnonzero(keys[1:] != keys[:-1]) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [len(keys)]])
    return list(zip(starts.tolist(), ends.tolist()))


def _dedupe(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique rows of a (N, k) float32 array and the index of each row in them (bitwise equality, so
    nothing is rounded). Triangles whose corners would share a vertex keep distinct ones (an importer
    drops triangles with a repeated index)."""
    rows = np.ascontiguousarray(rows, np.float32)
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1, 3).astype(np.uint32)
    unique = rows[first]
    bad = (inverse[:, 0] == inverse[:, 1]) | (inverse[:, 1] == inverse[:, 2]) | (inverse[:, 0] == inverse[:, 2])
    if bad.any():  # a degenerate triangle (two equal corners): give it three vertices of its own
        tris = np.flatnonzero(bad)
        extra = rows.reshape(-1, 3, rows.shape[1])[tris].reshape(-1, rows.shape[1])
        inverse[tris] = (len(unique) + np.arange(3 * len(tris), dtype=np.uint32)).reshape(-1, 3)
        unique = np.concatenate([unique, extra])
    return unique, inverse


def _quat_from_neg_z(d) -> list[float]:
    """Unit quaternion [x, y, z, w] rotating the local -Z axis onto the unit vector ``d``."""
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d)
    a = np.array([0.0, 0.0, -1.0])
    c = np.cross(a, d)
    w = 1.0 + float(a @ d)
    if w < 1e-9:  # d = +Z: half a turn about X
        return [1.0, 0.0, 0.0, 0.0]
    q = np.array([c[0], c[1], c[2], w])
    return (q / np.linalg.norm(q)).tolist()


class _Bin:
    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []

    def add(self, data: bytes, target: int | None = None) -> int:
        pad = (-self.size) % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        view = {"buffer": 0, "byteOffset": self.size, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.parts.append(data)
        self.size += len(data)
        self.views.append(view)
        return len(self.views) - 1


def scene_to_glb(scene: NormalizedScene, lights: list[dict] | None = None, name: str = "kiln scene") -> bytes:
    """``scene`` (and ``lights``, dicts as in :mod:`workers.scene`; default: the scene's own) as GLB bytes.

    Deterministic: the same scene and lights always give the same bytes.
    """
    lights = list(scene.lights if lights is None else lights)
    T = scene.n_triangles
    binb = _Bin()
    accessors: list[dict] = []
    used: set[str] = set()

    def accessor(arr: np.ndarray, type_: str, target: int, minmax: bool = False) -> int:
        comp = _UNSIGNED_INT if arr.dtype == np.uint32 else _FLOAT
        view = binb.add(np.ascontiguousarray(arr).tobytes(), target)
        acc = {"bufferView": view, "componentType": comp, "count": int(arr.shape[0]), "type": type_}
        if minmax:
            acc["min"] = arr.min(axis=0).astype(float).tolist()
            acc["max"] = arr.max(axis=0).astype(float).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    # images / textures (one sampler: linear, mipmapped, repeat)
    images, textures = [], []
    for tex in scene.textures:
        view = binb.add(_png(tex))
        images.append({"bufferView": view, "mimeType": "image/png"})
        textures.append({"source": len(images) - 1, "sampler": 0})

    materials = []
    for i, m in enumerate(scene.materials):
        pbr: dict = {
            "baseColorFactor": [float(c) for c in m.get("base_color", [1, 1, 1, 1])],
            "metallicFactor": float(m.get("metallic", 0.0)),
            "roughnessFactor": float(m.get("roughness", 1.0)),
        }
        if m.get("base_color_texture") is not None:
            pbr["baseColorTexture"] = {"index": int(m["base_color_texture"])}
        if m.get("metallic_roughness_texture") is not None:
            pbr["metallicRoughnessTexture"] = {"index": int(m["metallic_roughness_texture"])}
        out = {"name": str(m.get("name") or f"material_{i}"), "pbrMetallicRoughness": pbr,
               "doubleSided": bool(m.get("double_sided", False))}
        emissive = [float(c) for c in m.get("emissive", [0, 0, 0])]
        strength = max(emissive) if emissive else 0.0
        if strength > 1.0:
            out["emissiveFactor"] = [c / strength for c in emissive]
            out["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
            used.add("KHR_materials_emissive_strength")
        elif strength > 0.0:
            out["emissiveFactor"] = emissive
        if m.get("emissive_texture") is not None:
            out["emissiveTexture"] = {"index": int(m["emissive_texture"])}
            out.setdefault("emissiveFactor", emissive)
        alpha = m.get("alpha_mode", "OPAQUE")
        if alpha != "OPAQUE":
            out["alphaMode"] = alpha
        cutoff = float(m.get("alpha_cutoff", 0.5))
        if alpha == "MASK" or cutoff != 0.5:
            out["alphaCutoff"] = cutoff
        materials.append(out)

    tc1 = scene.texcoord1()
    uv1, chart = tc1 if tc1 is not None else (None, np.zeros(T, np.int32))
    colors = scene.colors
    meshes, nodes = [], []
    for c0, c1 in _runs(np.asarray(chart)):
        prims = []
        for m0, m1 in _runs(np.asarray(scene.material[c0:c1])):
            a, b = c0 + m0, c0 + m1
            cols = [scene.triangles[a:b].reshape(-1, 3), scene.normals[a:b].reshape(-1, 3),
                    scene.uv0[a:b].reshape(-1, 2)]
            has_uv1 = uv1 is not None and int(chart[a]) >= 0
            if has_uv1:
                cols.append(uv1[a:b].reshape(-1, 2))
            if colors is not None:
                cols.append(colors[a:b].reshape(-1, 4))
            verts, index = _dedupe(np.concatenate([np.asarray(x, np.float32) for x in cols], axis=1))
            attrs = {"POSITION": accessor(verts[:, 0:3], "VEC3", _ARRAY_BUFFER, minmax=True),
                     "NORMAL": accessor(verts[:, 3:6], "VEC3", _ARRAY_BUFFER),
                     "TEXCOORD_0": accessor(verts[:, 6:8], "VEC2", _ARRAY_BUFFER)}
            k = 8
            if has_uv1:
                attrs["TEXCOORD_1"] = accessor(verts[:, k:k + 2], "VEC2", _ARRAY_BUFFER)
                k += 2
            if colors is not None:
                attrs["COLOR_0"] = accessor(verts[:, k:k + 4], "VEC4", _ARRAY_BUFFER)
            prims.append({"attributes": attrs, "indices": accessor(index.reshape(-1), "SCALAR", _ELEMENT_ARRAY_BUFFER),
                          "material": int(scene.material[a]), "mode": 4})
        meshes.append({"primitives": prims})
        nodes.append({"mesh": len(meshes) - 1, "name": f"chart_{int(chart[c0])}" if uv1 is not None else "scene"})

    light_defs = []
    for i, l in enumerate(lights):
        d = {"type": l["type"], "color": [float(c) for c in l.get("color", [1, 1, 1])],
             "intensity": float(l.get("intensity", 1.0))}
        if l.get("name"):
            d["name"] = str(l["name"])
        if l.get("range") is not None and l["type"] != "directional":
            d["range"] = float(l["range"])
        if l["type"] == "spot":
            inner, outer = l.get("inner_cone_angle"), l.get("outer_cone_angle")
            d["spot"] = {"innerConeAngle": float(inner if inner is not None else 0.0),
                         "outerConeAngle": float(outer if outer is not None else math.pi / 4)}
        light_defs.append(d)
        node: dict = {"name": f"light_{i}", "extensions": {"KHR_lights_punctual": {"light": i}}}
        if l.get("position") is not None and l["type"] != "directional":
            node["translation"] = [float(x) for x in l["position"]]
        if l.get("direction") is not None and l["type"] != "point":
            node["rotation"] = _quat_from_neg_z(l["direction"])
        nodes.append(node)
    if light_defs:
        used.add("KHR_lights_punctual")

    gltf: dict = {
        "asset": {"version": "2.0", "generator": "Kiln workers.scene_glb"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": accessors,
        "bufferViews": binb.views,
        "buffers": [{"byteLength": binb.size}],
    }
    if textures:
        gltf["images"] = images
        gltf["textures"] = textures
        gltf["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]
    if light_defs:
        gltf["extensions"] = {"KHR_lights_punctual": {"lights": light_defs}}
    if used:
        gltf["extensionsUsed"] = sorted(used)

    js = json.dumps(gltf, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()
    js += b" " * ((-len(js)) % 4)
    bin_data = b"".join(binb.parts)
    bin_data += b"\0" * ((-len(bin_data)) % 4)
    total = 12 + 8 + len(js) + 8 + len(bin_data)
    return (GLB_MAGIC + struct.pack("<II", 2, total) + struct.pack("<I", len(js)) + b"JSON" + js
            + struct.pack("<I", len(bin_data)) + b"BIN\0" + bin_data)
