"""Builders of small glTF uploads for the tests of :mod:`workers.gltf` (and the tests that upload scenes).

``Gltf`` assembles a document and its binary buffer from numpy arrays; ``write_glb`` / ``write_gltf`` /
``write_zip`` write it as each upload kind; ``expect_error`` asserts an ``IngestError``'s code and status.
"""

from __future__ import annotations

import base64
import copy
import io
import json
import struct
import urllib.parse
import zipfile
import zlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from workers.gltf import ERROR_CODES, IngestError, IngestLimits, ingest_file
from workers.gltf.materials import KTX2_MAGIC
from workers.scene import NormalizedScene


SHARED = Path(__file__).resolve().parents[3].parent / "shared"
CORPUS = SHARED / "gltf-corpus"
SCENES = SHARED / "scenes"
needs_corpus = pytest.mark.skipif(
    not (CORPUS / "MANIFEST.json").is_file(), reason=f"glTF corpus not found at {CORPUS} (../shared is absent)"
)
needs_scenes = pytest.mark.skipif(
    not SCENES.is_dir(), reason=f"real scenes not found at {SCENES} (../shared is absent)"
)


class Gltf:
    """Builds a small glTF document and its binary buffer from numpy arrays."""

    def __init__(self):
        self.bin = bytearray()
        self.images: list[bytes] = []
        self.doc: dict = {
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": []}],
            "nodes": [],
            "meshes": [],
            "accessors": [],
            "bufferViews": [],
            "buffers": [],
        }

    def view(self, data: bytes, **kw) -> int:
        while len(self.bin) % 4:
            self.bin.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data), **kw})
        self.bin += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, arr, component: int | None = None, **kw) -> int:
        arr = np.asarray(arr)
        if component is None:
            component = {
                np.dtype(np.float32): 5126,
                np.dtype(np.uint8): 5121,
                np.dtype(np.uint16): 5123,
                np.dtype(np.uint32): 5125,
            }[arr.dtype]
        n = 1 if arr.ndim == 1 else arr.shape[1]
        kind = kw.pop("type", {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}[n])
        acc = {
            "bufferView": self.view(arr.tobytes()),
            "componentType": component,
            "count": int(arr.shape[0]),
            "type": kind,
            **kw,
        }
        if kind == "VEC3" and arr.dtype == np.float32 and np.isfinite(arr).all():
            acc["min"], acc["max"] = arr.min(0).tolist(), arr.max(0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, positions, indices=None, *, material=None, mode=None, **attrs) -> int:
        prim: dict = {"attributes": {"POSITION": self.accessor(np.asarray(positions, np.float32))}}
        for key, val in attrs.items():
            prim["attributes"][key] = self.accessor(np.asarray(val, np.float32))
        if indices is not None:
            prim["indices"] = self.accessor(np.asarray(indices, np.uint16))
        if material is not None:
            prim["material"] = material
        if mode is not None:
            prim["mode"] = mode
        self.doc["meshes"].append({"primitives": [prim]})
        return len(self.doc["meshes"]) - 1

    def node(self, root: bool = True, **kw) -> int:
        self.doc["nodes"].append(kw)
        idx = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(idx)
        return idx

    def image(self, png: bytes) -> int:
        self.images.append(png)
        self.doc.setdefault("textures", []).append({"source": len(self.images) - 1})
        return len(self.doc["textures"]) - 1


def png_bytes(w=4, h=2, color=(200, 100, 50, 255)) -> bytes:
    buf = io.BytesIO()
    img = Image.new("RGBA", (w, h), color)
    img.putpixel((0, 0), (1, 2, 3, 4))
    img.save(buf, "PNG")
    return buf.getvalue()


def png_header_only(w: int, h: int) -> bytes:
    """A PNG that declares w x h pixels but carries no pixel data."""

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))

    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0)) + chunk(b"IEND", b"")


def glb_bytes(doc: dict, bin_: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    bin_ = bytes(bin_) + b"\0" * (-len(bin_) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    if bin_:
        body += struct.pack("<II", len(bin_), 0x004E4942) + bin_
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def write_glb(path: Path, g: Gltf) -> Path:
    """Images go into buffer views of the BIN chunk."""
    g = copy.deepcopy(g)
    for png in g.images:
        mime = "image/ktx2" if png[: len(KTX2_MAGIC)] == KTX2_MAGIC else "image/png"
        g.doc.setdefault("images", []).append({"bufferView": g.view(png), "mimeType": mime})
    g.doc["buffers"] = [{"byteLength": len(g.bin)}]
    path.write_bytes(glb_bytes(g.doc, g.bin))
    return path


def write_gltf(path: Path, g: Gltf) -> Path:
    """Buffer and images as data: URIs."""
    doc = copy.deepcopy(g.doc)
    doc["buffers"] = [
        {
            "byteLength": len(g.bin),
            "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(g.bin)).decode(),
        }
    ]
    if g.images:
        doc["images"] = [{"uri": "data:image/png;base64," + base64.b64encode(p).decode()} for p in g.images]
    path.write_text(json.dumps(doc, indent=1))
    return path


def write_zip(path: Path, g: Gltf, *, bin_name="data/scene.bin", image_names=None, extra=None, skip=()) -> Path:
    """A .gltf in a folder of the zip, its buffer and images as files beside it (URIs percent-encoded)."""
    doc = copy.deepcopy(g.doc)
    image_names = image_names or [f"textures/image {i}.png" for i in range(len(g.images))]
    doc["buffers"] = [{"byteLength": len(g.bin), "uri": urllib.parse.quote(bin_name)}]
    if g.images:
        doc["images"] = [{"uri": urllib.parse.quote(n)} for n in image_names]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("model/scene.gltf", json.dumps(doc))
        if bin_name not in skip:
            z.writestr("model/" + bin_name, bytes(g.bin))
        for name, png in zip(image_names, g.images, strict=False):
            if name not in skip:
                z.writestr("model/" + name, png)
        for name, data in (extra or {}).items():
            z.writestr(name, data)
    return path


def raw_gltf(path: Path, doc: dict) -> Path:
    path.write_text(json.dumps(doc))
    return path


QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)  # in z=0, CCW seen from +Z


QUAD_UV = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)


def sample_scene() -> Gltf:
    """Two textured/untextured quads, a triangle without material, lights; used by the format tests."""
    g = Gltf()
    tex = g.image(png_bytes())
    g.doc["materials"] = [
        {
            "name": "wall",
            "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 1.0], "baseColorTexture": {"index": tex}},
        },
        {
            "name": "lamp",
            "emissiveFactor": [1.0, 0.5, 0.25],
            "doubleSided": True,
            "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}},
        },
    ]
    g.doc["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_emissive_strength"]
    g.doc["extensions"] = {
        "KHR_lights_punctual": {"lights": [{"type": "point", "color": [1, 0.5, 0.5], "intensity": 3.0}]}
    }
    m0 = g.mesh(QUAD, [0, 1, 2, 0, 2, 3], material=0, NORMAL=np.tile([0, 0, 1], (4, 1)), TEXCOORD_0=QUAD_UV)
    m1 = g.mesh(QUAD, [0, 1, 2, 0, 2, 3], material=1)
    m2 = g.mesh(QUAD[:3])
    g.node(mesh=m0, translation=[0, 0, -2])
    g.node(mesh=m1, rotation=[0.7071068, 0, 0, 0.7071068], translation=[0, 3, 0])
    g.node(mesh=m2, scale=[2, 2, 2])
    g.node(translation=[0, 2, 0], extensions={"KHR_lights_punctual": {"light": 0}})
    return g


def face_normals(s: NormalizedScene) -> np.ndarray:
    t = s.triangles.astype(np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def oriented(tris: np.ndarray, decimals: int = 3) -> Counter:
    """Multiset of triangles keyed by their corner set and winding parity (ordering-independent)."""
    out: Counter = Counter()
    for tri in np.round(np.asarray(tris, np.float64), decimals):
        rows = [tuple(r) for r in tri]
        order = sorted(range(3), key=lambda i: rows[i])
        parity = sum(order[i] > order[j] for i in range(3) for j in range(i + 1, 3)) % 2
        out[(tuple(rows[i] for i in order), parity)] += 1
    return out


def expect_error(code: str, path: Path, limits: IngestLimits | None = None, contains: str | None = None) -> IngestError:
    with pytest.raises(IngestError) as info:
        ingest_file(path, limits)
    err = info.value
    assert err.code == code, f"expected {code}, got {err.code}: {err.message}"
    assert err.status == ERROR_CODES[code] and 400 <= err.status < 500
    assert err.message
    if contains is not None:
        assert contains in err.message
    return err


def minimal(**over) -> Gltf:
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3]))
    g.doc.update(over)
    return g


LFS_POINTER = (b"version https://git-lfs.github.com/spec/v1\n"
               b"oid sha256:4d7a214614ab2935c943f9e0ff69d22eadbb8f32b1258daaa5e2ca24d17e2393\n"
               b"size 12345\n")
