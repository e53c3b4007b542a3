"""A minimal glTF 2.0 (GLB) writer for tests: primitives with any attributes, materials, images, lights.

Tests build the exact files a case needs (vertex colours as float or normalized integers, metallic-roughness
textures, alpha cutouts) instead of patching real scenes.
"""
from __future__ import annotations

import io
import json
import struct

import numpy as np

_COMPONENT = {np.dtype(np.float32): 5126, np.dtype(np.uint8): 5121, np.dtype(np.uint16): 5123,
              np.dtype(np.uint32): 5125, np.dtype(np.int16): 5122, np.dtype(np.int8): 5120}
_TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}


def png_bytes(rgba: np.ndarray) -> bytes:
    """PNG file bytes of an (H, W, 3|4) uint8 image."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


class GltfBuilder:
    """Accumulates buffers, accessors, meshes and materials; :meth:`glb` returns the file bytes."""

    def __init__(self):
        self.blob = bytearray()
        self.doc: dict = {"asset": {"version": "2.0", "generator": "kiln tests"}, "scene": 0,
                          "scenes": [{"nodes": []}], "nodes": [], "meshes": [], "materials": [],
                          "accessors": [], "bufferViews": []}

    def _view(self, data: bytes, target: int | None = None) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        view = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.blob.extend(data)
        self.doc["bufferViews"].append(view)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array, normalized: bool = False, minmax: bool = False, target: int | None = 34962) -> int:
        a = np.ascontiguousarray(array)
        if a.dtype == np.float64:
            a = a.astype(np.float32)
        if a.ndim == 1:
            a = a[:, None]
        acc = {"bufferView": self._view(a.tobytes(), target), "componentType": _COMPONENT[a.dtype],
               "count": int(a.shape[0]), "type": _TYPE[a.shape[1]]}
        if normalized:
            acc["normalized"] = True
        if minmax:
            acc["min"] = a.min(axis=0).tolist()
            acc["max"] = a.max(axis=0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def image(self, rgba: np.ndarray) -> int:
        """A PNG texture (sampler default: linear, REPEAT); returns the texture index."""
        self.doc.setdefault("images", []).append({"bufferView": self._view(png_bytes(rgba)), "mimeType": "image/png"})
        self.doc.setdefault("textures", []).append({"source": len(self.doc["images"]) - 1})
        return len(self.doc["textures"]) - 1

    def material(self, **m) -> int:
        self.doc["materials"].append(m)
        return len(self.doc["materials"]) - 1

    def mesh(self, positions, indices=None, *, normals=None, material: int | None = None, colors=None,
             color_normalized: bool = False, uv=None, translation=None) -> int:
        """One mesh of one triangle primitive in its own node; returns the node index."""
        attrs = {"POSITION": self.accessor(np.asarray(positions, np.float32), minmax=True)}
        if normals is not None:
            attrs["NORMAL"] = self.accessor(np.asarray(normals, np.float32))
        if colors is not None:
            attrs["COLOR_0"] = self.accessor(np.asarray(colors), normalized=color_normalized)
        if uv is not None:
            attrs["TEXCOORD_0"] = self.accessor(np.asarray(uv, np.float32))
        prim: dict = {"attributes": attrs, "mode": 4}
        if indices is not None:
            prim["indices"] = self.accessor(np.asarray(indices, np.uint32).ravel(), target=34963)
        if material is not None:
            prim["material"] = material
        self.doc["meshes"].append({"primitives": [prim]})
        node: dict = {"mesh": len(self.doc["meshes"]) - 1}
        if translation is not None:
            node["translation"] = list(map(float, translation))
        self.doc["nodes"].append(node)
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)
        return len(self.doc["nodes"]) - 1

    def point_light(self, position, intensity: float, color=(1.0, 1.0, 1.0)) -> None:
        ext = self.doc.setdefault("extensions", {}).setdefault("KHR_lights_punctual", {"lights": []})
        ext["lights"].append({"type": "point", "intensity": float(intensity), "color": list(color)})
        used = self.doc.setdefault("extensionsUsed", [])
        if "KHR_lights_punctual" not in used:
            used.append("KHR_lights_punctual")
        self.doc["nodes"].append({"translation": list(map(float, position)),
                                  "extensions": {"KHR_lights_punctual": {"light": len(ext["lights"]) - 1}}})
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)

    def glb(self) -> bytes:
        doc = {k: v for k, v in self.doc.items() if v != []}
        while len(self.blob) % 4:
            self.blob.append(0)
        doc["buffers"] = [{"byteLength": len(self.blob)}]
        js = json.dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(self.blob), 0x004E4942) + self.blob
        return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def box_inward(lo, hi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed axis-aligned box whose faces point inward: positions (24, 3), normals (24, 3), indices (12, 3)."""
    lo, hi = np.asarray(lo, np.float32), np.asarray(hi, np.float32)
    pos, nrm, idx = [], [], []
    for axis in range(3):
        for side, n_sign in ((0, 1.0), (1, -1.0)):             # the lo face looks +axis, the hi face -axis
            u, v = (axis + 1) % 3, (axis + 2) % 3
            c = np.zeros((4, 3), np.float32)
            c[:, axis] = lo[axis] if side == 0 else hi[axis]
            c[:, u] = [lo[u], hi[u], hi[u], lo[u]]
            c[:, v] = [lo[v], lo[v], hi[v], hi[v]]
            n = np.zeros(3, np.float32)
            n[axis] = n_sign
            base = len(pos) * 4
            quad = [[0, 1, 2], [0, 2, 3]]
            # counter-clockwise seen from the side the normal points to
            if np.dot(np.cross(c[1] - c[0], c[2] - c[0]), n) < 0:
                quad = [[0, 2, 1], [0, 3, 2]]
            pos.append(c)
            nrm.append(np.repeat(n[None], 4, axis=0))
            idx += [[base + a for a in t] for t in quad]
    return np.concatenate(pos), np.concatenate(nrm), np.asarray(idx, np.uint32)


def quad(corner, edge_u, edge_v, normal) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A quad ``corner + s·edge_u + t·edge_v`` facing ``normal``: positions (4, 3), normals, uv (4, 2), indices."""
    c = np.asarray(corner, np.float32)
    eu, ev = np.asarray(edge_u, np.float32), np.asarray(edge_v, np.float32)
    pos = np.stack([c, c + eu, c + eu + ev, c + ev])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    idx = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    if np.dot(np.cross(eu, ev), normal) < 0:
        idx = idx[:, [0, 2, 1]]
    return pos, np.repeat(np.asarray(normal, np.float32)[None], 4, axis=0), uv, idx
