"""Tests for workers.ingest: glTF 2.0 upload -> NormalizedScene.

Crafted files (written in tmp_path) cover every error code and the geometry rules (node transforms,
negative scale, strips/fans, skins, morph targets, instancing, sparse accessors, lights, materials,
texture transforms). The Khronos asset-generator corpus and the real scenes in ../shared are run when
present (skipped, saying why, when not).
"""

from __future__ import annotations

import base64
import copy
import io
import json
import math
import os
import struct
import tempfile
import urllib.parse
import zipfile
import zlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from workers.ingest import ERROR_CODES, IngestError, IngestLimits, ingest_file
from workers.scene import NormalizedScene

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
CORPUS = SHARED / "gltf-corpus"
SCENES = SHARED / "scenes"
needs_corpus = pytest.mark.skipif(
    not (CORPUS / "MANIFEST.json").is_file(), reason=f"glTF corpus not found at {CORPUS} (../shared is absent)"
)
needs_scenes = pytest.mark.skipif(
    not SCENES.is_dir(), reason=f"real scenes not found at {SCENES} (../shared is absent)"
)


# ---------------------------------------------------------------------------------------------- builders


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
        g.doc.setdefault("images", []).append({"bufferView": g.view(png), "mimeType": "image/png"})
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


# ---------------------------------------------------------------------------------------------- formats


def test_same_scene_as_glb_gltf_and_zip_has_same_id(tmp_path):
    g = sample_scene()
    scenes = [
        ingest_file(write_glb(tmp_path / "s.glb", g)),
        ingest_file(write_gltf(tmp_path / "s.gltf", g)),
        ingest_file(write_zip(tmp_path / "s.zip", g)),
    ]
    ids = {s.scene_id() for s in scenes}
    assert len(ids) == 1
    s = scenes[0]
    assert s.n_triangles == 5
    assert s.materials[-1]["name"] == "default" and len(s.materials) == 3  # the bare triangle got one
    assert s.material.tolist() == [0, 0, 1, 1, 2]
    assert len(s.textures) == 1 and s.textures[0].shape == (2, 4, 4) and s.textures[0].dtype == np.uint8
    assert s.textures[0][0, 0].tolist() == [1, 2, 3, 4] and s.textures[0][1, 3].tolist() == [200, 100, 50, 255]
    assert s.materials[0]["base_color"] == [0.5, 0.25, 1.0, 1.0] and s.materials[0]["base_color_texture"] == 0
    assert s.materials[1]["emissive"] == [4.0, 2.0, 1.0] and s.materials[1]["double_sided"] is True
    assert s.materials[1]["emissive_texture"] is None and s.materials[1]["base_color_texture"] is None
    # round trip through the canonical bytes keeps the id
    assert NormalizedScene.from_bytes(s.to_bytes()).scene_id() == s.scene_id()


def test_world_transforms_uvs_and_normals(tmp_path):
    s = ingest_file(write_glb(tmp_path / "s.glb", sample_scene()))
    # node 0: translated to z=-2, vertex normals +Z, UVs carried per corner
    np.testing.assert_allclose(s.triangles[0], [[0, 0, -2], [1, 0, -2], [1, 1, -2]], atol=1e-6)
    np.testing.assert_allclose(s.normals[:2], np.broadcast_to([0, 0, 1], (2, 3, 3)), atol=1e-6)
    np.testing.assert_allclose(s.uv0[0], [[0, 1], [1, 1], [1, 0]])
    # node 1: +90 degrees about X maps the quad's +Y edge to +Z and its normal (+Z) to -Y, then up 3
    np.testing.assert_allclose(s.triangles[2], [[0, 3, 0], [1, 3, 0], [1, 3, 1]], atol=1e-6)
    np.testing.assert_allclose(face_normals(s)[2:4], [[0, -1, 0]] * 2, atol=1e-6)
    np.testing.assert_allclose(s.normals[2:4], np.broadcast_to([0, -1, 0], (2, 3, 3)), atol=1e-6)  # geometric
    # node 2: scaled by 2, no UVs -> zeros
    np.testing.assert_allclose(s.triangles[4], [[0, 0, 0], [2, 0, 0], [2, 2, 0]])
    assert not s.uv0[4].any()
    assert s.uv1 is None
    assert s.triangles.dtype == np.float32 and s.normals.dtype == np.float32 and s.material.dtype == np.int32
    np.testing.assert_allclose(s.bounds, [[0, 0, -2], [2, 3, 1]], atol=1e-6)


def test_percent_encoded_uris_resolve_in_zip(tmp_path):
    g = sample_scene()
    s = ingest_file(
        write_zip(tmp_path / "s.zip", g, bin_name="bin files/scène 1.bin", image_names=["textures/cement lossy.png"])
    )
    assert s.n_triangles == 5 and len(s.textures) == 1


def test_webp_textures_decode(tmp_path):
    buf = io.BytesIO()
    Image.new("RGB", (8, 4), (10, 200, 30)).save(buf, "WEBP", lossless=True)
    g = sample_scene()
    g.images[0] = buf.getvalue()
    g.doc["textures"][0] = {"extensions": {"EXT_texture_webp": {"source": 0}}}
    g.doc["extensionsUsed"].append("EXT_texture_webp")
    g.doc["extensionsRequired"] = ["EXT_texture_webp"]
    s = ingest_file(write_zip(tmp_path / "s.zip", g, image_names=["textures/a%20b.webp"]))
    assert s.textures[0].shape == (4, 8, 4)
    assert s.textures[0][0, 0].tolist() == [10, 200, 30, 255]


def test_zip_extraction_stays_in_a_cleaned_temporary_directory(tmp_path, monkeypatch):
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    upload = write_zip(tmp_path / "s.zip", sample_scene())
    before = set(os.listdir(tmp_path))
    made = []
    real = tempfile.TemporaryDirectory

    def spy(*args, **kw):
        made.append(real(*args, **kw))
        return made[-1]

    monkeypatch.setattr(tempfile, "TemporaryDirectory", spy)
    ingest_file(upload)
    assert len(made) == 1 and Path(made[0].name).parent == scratch
    assert os.listdir(scratch) == []
    assert set(os.listdir(tmp_path)) == before


# ---------------------------------------------------------------------------------------------- lights


def test_lights_follow_node_world_transforms(tmp_path):
    g = Gltf()
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {
        "KHR_lights_punctual": {
            "lights": [
                {"type": "spot", "name": "spot", "intensity": 20, "range": 5, "spot": {"outerConeAngle": 0.5}},
                {"type": "directional", "color": [1, 0.9, 0.8]},
                {"type": "point"},
            ]
        }
    }
    g.node(mesh=g.mesh(QUAD[:3]))
    # parent: translate (1, 2, 3) and scale 2; child spot: +90 degrees about X, offset (0, 0, 1) locally
    q = [math.sin(math.pi / 4), 0, 0, math.cos(math.pi / 4)]
    spot = g.node(root=False, translation=[0, 0, 1], rotation=q, extensions={"KHR_lights_punctual": {"light": 0}})
    g.node(translation=[1, 2, 3], scale=[2, 2, 2], children=[spot])
    # directional light yawed 90 degrees about Y: local -Z turns to -X
    qy = [0, math.sin(math.pi / 4), 0, math.cos(math.pi / 4)]
    g.node(rotation=qy, translation=[5, 5, 5], extensions={"KHR_lights_punctual": {"light": 1}})
    g.node(matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 7, 8, 9, 1], extensions={"KHR_lights_punctual": {"light": 2}})
    s = ingest_file(write_glb(tmp_path / "l.glb", g))
    spot_l, sun, point = s.lights
    assert spot_l["type"] == "spot" and spot_l["name"] == "spot"
    np.testing.assert_allclose(spot_l["position"], [1, 2, 5], atol=1e-9)  # (1,2,3) + 2 * (0,0,1)
    np.testing.assert_allclose(spot_l["direction"], [0, 1, 0], atol=1e-9)  # R_x(90) (0,0,-1) = (0,1,0)
    assert spot_l["inner_cone_angle"] == 0.0 and spot_l["outer_cone_angle"] == 0.5
    assert spot_l["intensity"] == 20 and spot_l["range"] == 5 and spot_l["color"] == [1, 1, 1]
    assert sun["type"] == "directional" and sun["position"] is None
    np.testing.assert_allclose(sun["direction"], [-1, 0, 0], atol=1e-9)
    assert sun["color"] == [1, 0.9, 0.8] and sun["intensity"] == 1.0 and sun["range"] is None
    assert point["position"] == [7, 8, 9] and point["direction"] is None
    assert point["inner_cone_angle"] is None and point["outer_cone_angle"] is None
    json.dumps(s.lights)  # plain JSON


def test_spot_light_defaults(tmp_path):
    g = Gltf()
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "spot"}]}}
    g.node(mesh=g.mesh(QUAD[:3]))
    g.node(extensions={"KHR_lights_punctual": {"light": 0}})
    (light,) = ingest_file(write_glb(tmp_path / "l.glb", g)).lights
    assert light["inner_cone_angle"] == 0 and light["outer_cone_angle"] == pytest.approx(math.pi / 4)
    assert light["direction"] == [0, 0, -1] and light["position"] == [0, 0, 0] and light["intensity"] == 1


# ---------------------------------------------------------------------------------------------- geometry rules


@pytest.mark.parametrize(
    "transform",
    [
        {"scale": [-1, 1, 1]},
        {"scale": [1, -1, 1]},
        {"scale": [-1, -1, -1]},
        {"matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]},
    ],
)
def test_negative_scale_keeps_front_faces(tmp_path, transform):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3], NORMAL=np.tile([0, 0, 1], (4, 1))), **transform)
    s = ingest_file(write_glb(tmp_path / "n.glb", g))
    m = np.eye(3)
    if "scale" in transform:
        m = np.diag(transform["scale"])
    else:
        m[0, 0] = -1
    # The mirrored quad's front face keeps its (inverse-transpose transformed) normal, and the winding
    # is flipped so the counter-clockwise rule still gives that same normal.
    expected_normal = np.linalg.inv(m).T @ [0, 0, 1]
    np.testing.assert_allclose(face_normals(s), [expected_normal] * 2, atol=1e-6)
    np.testing.assert_allclose(s.normals, np.broadcast_to(expected_normal, (2, 3, 3)), atol=1e-6)


def test_strip_and_fan_give_the_same_triangles_as_a_list(tmp_path):
    for name, idx, mode in [("list", [0, 1, 2, 0, 2, 3], 4), ("strip", [0, 1, 3, 2], 5), ("fan", [0, 1, 2, 3], 6)]:
        g = Gltf()
        g.node(mesh=g.mesh(QUAD, idx, mode=mode))
        s = ingest_file(write_glb(tmp_path / f"{name}.glb", g))
        assert s.n_triangles == 2
        np.testing.assert_allclose(face_normals(s), [[0, 0, 1]] * 2, atol=1e-6)
        assert 0.5 * np.linalg.norm(
            np.cross(s.triangles[:, 1] - s.triangles[:, 0], s.triangles[:, 2] - s.triangles[:, 0]), axis=1
        ).sum() == pytest.approx(1.0)


def test_points_and_lines_are_dropped_with_a_warning(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, mode=0))
    g.node(mesh=g.mesh(QUAD, mode=1))
    g.node(mesh=g.mesh(QUAD, mode=1))
    g.node(mesh=g.mesh(QUAD[:3]))
    s = ingest_file(write_glb(tmp_path / "p.glb", g))
    assert s.n_triangles == 1
    assert "1 point primitive ignored" in s.warnings and "2 line primitives ignored" in s.warnings


def test_degenerate_index_triangles_are_dropped(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 0, 3, 0, 2, 3]))
    s = ingest_file(write_glb(tmp_path / "d.glb", g))
    assert s.n_triangles == 2
    assert any("degenerate" in w for w in s.warnings)


def test_uv1_only_when_every_primitive_has_it(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD[:3], TEXCOORD_0=QUAD_UV[:3], TEXCOORD_1=QUAD_UV[:3] * 0.5))
    g.node(mesh=g.mesh(QUAD[:3] + 1, TEXCOORD_1=QUAD_UV[:3] * 0.25))
    s = ingest_file(write_glb(tmp_path / "a.glb", g))
    assert s.uv1 is not None and s.uv1.shape == (2, 3, 2)
    np.testing.assert_allclose(s.uv1[1], QUAD_UV[:3] * 0.25)
    np.testing.assert_allclose(s.uv0[0], QUAD_UV[:3])
    g.node(mesh=g.mesh(QUAD[:3] + 2))
    s = ingest_file(write_glb(tmp_path / "b.glb", g))
    assert s.uv1 is None and "TEXCOORD_1 dropped: not every primitive has it" in s.warnings


def test_texture_transform_and_texcoord_choice(tmp_path):
    g = Gltf()
    tex = g.image(png_bytes())
    g.doc["materials"] = [
        {
            "pbrMetallicRoughness": {
                "baseColorTexture": {
                    "index": tex,
                    "texCoord": 1,
                    "extensions": {
                        "KHR_texture_transform": {"offset": [0.5, 0.25], "scale": [2, 3], "rotation": math.pi / 2}
                    },
                }
            }
        }
    ]
    g.doc["extensionsUsed"] = ["KHR_texture_transform"]
    g.node(mesh=g.mesh(QUAD[:3], material=0, TEXCOORD_0=np.zeros((3, 2)), TEXCOORD_1=QUAD_UV[:3]))
    s = ingest_file(write_glb(tmp_path / "t.glb", g))
    uv = QUAD_UV[:3].astype(np.float64) * [2, 3]
    c, sn = 0.0, 1.0  # cos, sin of pi/2: u' = c u + s v, v' = -s u + c v (sample viewer / three.js)
    expected = np.stack([c * uv[:, 0] + sn * uv[:, 1], -sn * uv[:, 0] + c * uv[:, 1]], 1) + [0.5, 0.25]
    np.testing.assert_allclose(s.uv0[0], expected, atol=1e-6)
    assert any("uv0 holds TEXCOORD_1" in w for w in s.warnings)


def test_textures_are_deduplicated_per_image(tmp_path):
    g = Gltf()
    t0 = g.image(png_bytes(color=(1, 1, 1, 255)))
    t1 = g.image(png_bytes(color=(9, 9, 9, 255)))
    g.doc["textures"].append({"source": 0})  # a third texture reusing image 0
    g.doc["materials"] = [
        {"pbrMetallicRoughness": {"baseColorTexture": {"index": t1}}},
        {
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 2}},
            "emissiveTexture": {"index": t0},
            "emissiveFactor": [1, 1, 1],
        },
    ]
    g.node(mesh=g.mesh(QUAD[:3], material=1, TEXCOORD_0=QUAD_UV[:3]))
    s = ingest_file(write_glb(tmp_path / "t.glb", g))
    assert len(s.textures) == 2
    assert s.materials[0]["base_color_texture"] == 0 and s.textures[0][1, 1, 0] == 9
    assert s.materials[1]["base_color_texture"] == 1 and s.materials[1]["emissive_texture"] == 1
    assert s.textures[1][1, 1, 0] == 1


def test_sparse_accessor_morph_target_and_gpu_instancing(tmp_path):
    g = Gltf()
    pos = g.accessor(QUAD[:3])
    doc = g.doc
    # sparse: vertex 2 replaced by (0, 2, 0)
    doc["accessors"][pos]["sparse"] = {
        "count": 1,
        "indices": {"bufferView": g.view(np.array([2], np.uint16).tobytes()), "componentType": 5123},
        "values": {"bufferView": g.view(np.array([[0, 2, 0]], np.float32).tobytes())},
    }
    target = g.accessor(np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1]], np.float32))
    doc["meshes"].append(
        {"primitives": [{"attributes": {"POSITION": pos}, "targets": [{"POSITION": target}]}], "weights": [0.5]}
    )
    t = g.accessor(np.array([[0, 0, 0], [10, 0, 0], [20, 0, 0]], np.float32))
    doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    g.node(mesh=0, extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": t}}})
    s = ingest_file(write_glb(tmp_path / "x.glb", g))
    assert s.n_triangles == 3
    for k in range(3):
        np.testing.assert_allclose(
            s.triangles[k], [[10 * k, 0, 0.5], [10 * k + 1, 0, 0.5], [10 * k, 2, 0.5]], atol=1e-6
        )


def test_skin_at_static_pose_ignores_the_mesh_node_transform(tmp_path):
    g = Gltf()
    pos = QUAD[:3]
    mesh = g.mesh(pos, JOINTS_0=np.zeros((3, 4)), WEIGHTS_0=np.tile([1, 0, 0, 0], (3, 1)))
    prim = g.doc["meshes"][mesh]["primitives"][0]["attributes"]
    prim["JOINTS_0"] = g.accessor(np.zeros((3, 4), np.uint8))  # joints must be unsigned ints
    ibm = g.accessor(np.eye(4, dtype=np.float32).reshape(1, 16))  # bind pose at the origin
    joint = g.node(translation=[0, 5, 0])
    g.doc["skins"] = [{"joints": [joint], "inverseBindMatrices": ibm}]
    g.node(mesh=mesh, skin=0, translation=[100, 100, 100])  # must be ignored
    s = ingest_file(write_glb(tmp_path / "skin.glb", g))
    np.testing.assert_allclose(s.triangles[0], pos + [0, 5, 0], atol=1e-6)


def test_unreferenced_vertices_do_not_change_the_result(tmp_path):
    """A skinned, morphing primitive using 3 of its 60 vertices gives what the same 3 vertices alone give
    (the per-vertex work is compacted to the referenced vertices)."""
    rng = np.random.default_rng(3)
    n = 60
    data = {
        "POSITION": rng.normal(size=(n, 3)),
        "NORMAL": rng.normal(size=(n, 3)),
        "TEXCOORD_0": rng.random((n, 2)),
        "WEIGHTS_0": np.tile([0.5, 0.5, 0, 0], (n, 1)),
        "target": rng.normal(size=(n, 3)),
    }
    used = [7, 31, 52]
    scenes = []
    for name, rows, indices in [("all", slice(None), used), ("used", used, [0, 1, 2])]:
        d = {k: np.asarray(v, np.float32)[rows] for k, v in data.items()}
        g = Gltf()
        g.doc["skins"] = [{"joints": [g.node(translation=[0, 1, 0]), g.node(rotation=[0, 0, 0.3826834, 0.9238795])]}]
        mesh = g.mesh(d["POSITION"], indices, NORMAL=d["NORMAL"], TEXCOORD_0=d["TEXCOORD_0"], WEIGHTS_0=d["WEIGHTS_0"])
        prim = g.doc["meshes"][mesh]["primitives"][0]
        prim["attributes"]["JOINTS_0"] = g.accessor(np.tile(np.array([0, 1, 0, 0], np.uint8), (len(d["target"]), 1)))
        prim["targets"] = [{"POSITION": g.accessor(d["target"])}]
        g.doc["meshes"][mesh]["weights"] = [0.25]
        g.node(mesh=mesh, skin=0)
        scenes.append(ingest_file(write_glb(tmp_path / f"{name}.glb", g)))
    a, b = scenes
    assert a.n_triangles == b.n_triangles == 1
    np.testing.assert_allclose(a.triangles, b.triangles, atol=1e-6)
    np.testing.assert_allclose(a.normals, b.normals, atol=1e-6)
    np.testing.assert_allclose(a.uv0, b.uv0, atol=1e-7)
    # and the skin really moved it: half joint0 (+1 in y), half joint1 (45 degrees about Z)
    p = d["POSITION"] + 0.25 * d["target"]
    c, s_ = math.cos(math.pi / 4), math.sin(math.pi / 4)
    rz = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(a.triangles[0], 0.5 * (p + [0, 1, 0]) + 0.5 * p @ rz.T, atol=1e-5)


def test_material_details(tmp_path):
    g = Gltf()
    g.doc["materials"] = [
        {"name": "sg", "extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0.1, 0.2, 0.3, 1]}}},
        {"alphaMode": "MASK"},
    ]
    g.doc["extensionsRequired"] = g.doc["extensionsUsed"] = ["KHR_materials_pbrSpecularGlossiness"]
    g.node(mesh=g.mesh(QUAD[:3], material=0))
    g.node(mesh=g.mesh(QUAD[:3], material=1, COLOR_0=np.ones((3, 4))))
    s = ingest_file(write_glb(tmp_path / "m.glb", g))
    assert s.materials[0]["base_color"] == [0.1, 0.2, 0.3, 1] and s.materials[0]["name"] == "sg"
    assert s.materials[1] == {
        "name": "material_1",
        "base_color": [1, 1, 1, 1],
        "base_color_texture": None,
        "emissive": [0, 0, 0],
        "emissive_texture": None,
        "double_sided": False,
        "metallic": 1.0,                      # glTF's defaults: metallicFactor 1, roughnessFactor 1
        "roughness": 1.0,
        "metallic_roughness_texture": None,
        "alpha_mode": "MASK",                 # a cutout for every ray (workers.raycast.cutout)
        "alpha_cutoff": 0.5,
    }
    assert s.materials[0]["metallic"] == 0.0  # specular-glossiness: the diffuse factor is the albedo
    assert not any("MASK" in w for w in s.warnings)
    np.testing.assert_array_equal(s.colors[1], 1.0)   # COLOR_0 kept (RGBA, per corner)


# ---------------------------------------------------------------------------------------------- bad inputs


def minimal(**over) -> Gltf:
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3]))
    g.doc.update(over)
    return g


def test_not_gltf(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0\nf 1 1 1\n")
    expect_error("not_gltf", tmp_path / "a.obj")
    expect_error("not_gltf", raw_gltf(tmp_path / "b.gltf", {"meshes": []}))
    expect_error("not_gltf", raw_gltf(tmp_path / "c.gltf", {"asset": "2.0"}))
    (tmp_path / "e.bin").write_bytes(b"")
    expect_error("not_gltf", tmp_path / "e.bin")
    with zipfile.ZipFile(tmp_path / "d.zip", "w") as z:
        z.writestr("readme.txt", "no model here")
    expect_error("not_gltf", tmp_path / "d.zip")


def test_truncated_glb(tmp_path):
    g = minimal()
    g.doc["buffers"] = [{"byteLength": len(g.bin)}]
    good = glb_bytes(g.doc, g.bin)
    (tmp_path / "a.glb").write_bytes(good[:-10])  # header length now past the end
    expect_error("truncated_glb", tmp_path / "a.glb")
    # a chunk claiming 4 GB inside a file whose header length is honest
    js_len = struct.unpack_from("<I", good, 12)[0]
    bad = bytearray(good)
    struct.pack_into("<I", bad, 12 + 8 + js_len, 0xFFFFFFF0)
    (tmp_path / "b.glb").write_bytes(bytes(bad))
    expect_error("truncated_glb", tmp_path / "b.glb", contains="chunk 1")
    (tmp_path / "c.glb").write_bytes(b"glTF\x02\x00")
    expect_error("truncated_glb", tmp_path / "c.glb")


def test_broken_json(tmp_path):
    (tmp_path / "a.gltf").write_text('{"asset": {"version": "2.0"}, "nodes": [')
    expect_error("broken_json", tmp_path / "a.gltf", contains="line 1")
    (tmp_path / "b.gltf").write_text('{"asset": {"version": "2.0"}, "x": NaN}')
    expect_error("broken_json", tmp_path / "b.gltf")
    (tmp_path / "c.gltf").write_bytes(b'{"asset": {"version": "2.0\xff"}}')
    expect_error("broken_json", tmp_path / "c.gltf")
    data = bytearray(glb_bytes({"asset": {"version": "2.0"}}, b""))
    data[20:21] = b"["
    (tmp_path / "e.glb").write_bytes(bytes(data))
    expect_error("broken_json", tmp_path / "e.glb")


def test_json_too_deep(tmp_path):
    deep = "[" * 500 + "]" * 500
    (tmp_path / "a.gltf").write_text('{"asset": {"version": "2.0"}, "extras": %s}' % deep)
    expect_error("json_too_deep", tmp_path / "a.gltf")
    # brackets inside strings do not count
    g = minimal(extras={"note": "[[[[" * 100})
    assert ingest_file(write_gltf(tmp_path / "b.gltf", g)).n_triangles == 2
    deep = "[" * 200_000 + "]" * 200_000  # would overflow a recursive parser
    (tmp_path / "c.gltf").write_text('{"asset": {"version": "2.0"}, "extras": %s}' % deep)
    expect_error("json_too_deep", tmp_path / "c.gltf")


@pytest.mark.parametrize(
    "uri",
    [
        "http://example.com/a.bin",
        "https://x/y.bin",
        "file:///etc/passwd",
        "\\\\server\\share\\a.bin",
        "/etc/passwd",
        "C:\\models\\a.bin",
        "c:/a.bin",
        "%2Fetc%2Fpasswd",
        "//host/a.bin",
        "ftp://x/a.bin",
    ],
)
def test_external_uri(tmp_path, uri):
    g = minimal()
    write_gltf(tmp_path / "a.gltf", g)
    doc = json.loads((tmp_path / "a.gltf").read_text())
    doc["buffers"][0]["uri"] = uri
    expect_error("external_uri", raw_gltf(tmp_path / "a.gltf", doc))
    doc["images"] = [{"uri": uri}]
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(g.bin)).decode()
    expect_error("external_uri", raw_gltf(tmp_path / "b.gltf", doc))


# The model is in model/ of the zip: one '..' reaches the zip's root (allowed: tests/workers/test_ingest_hostile.py),
# a second climbs out of the upload.
@pytest.mark.parametrize("uri", ["../../a.bin", "x/../../../a.bin", "%2e%2e/%2e%2e/a.bin", "..\\..\\a.bin",
                                 "x/%2E%2E%2F..%2F..%2Fa.bin"])
def test_path_traversal_in_uris(tmp_path, uri):
    g = minimal()
    write_zip(tmp_path / "a.zip", g)
    with zipfile.ZipFile(tmp_path / "a.zip") as z:
        doc = json.loads(z.read("model/scene.gltf"))
        bin_ = z.read("model/data/scene.bin")
    doc["buffers"][0]["uri"] = uri
    with zipfile.ZipFile(tmp_path / "b.zip", "w") as z:
        z.writestr("model/scene.gltf", json.dumps(doc))
        z.writestr("a.bin", bin_)
    expect_error("path_traversal", tmp_path / "b.zip")


@pytest.mark.parametrize("member", ["../evil.bin", "a/../../evil.bin", "/abs/evil.bin", "C:/evil.bin", "..\\evil.bin"])
def test_path_traversal_in_zip_members(tmp_path, member):
    write_zip(tmp_path / "a.zip", minimal(), extra={member: b"x"})
    expect_error("path_traversal", tmp_path / "a.zip")


def test_missing_resource(tmp_path):
    g = minimal()
    write_zip(tmp_path / "a.zip", g)
    with zipfile.ZipFile(tmp_path / "a.zip") as z:
        doc = json.loads(z.read("model/scene.gltf"))
    # a loose .gltf cannot bring its .bin
    expect_error("missing_resource", raw_gltf(tmp_path / "scene.gltf", doc), contains="data/scene.bin")
    # a zip without the (percent-encoded) texture: the message names the decoded file
    g = sample_scene()
    write_zip(tmp_path / "b.zip", g, image_names=["textures/cement lossy.webp"], skip=("textures/cement lossy.webp",))
    with zipfile.ZipFile(tmp_path / "b.zip") as z:
        assert json.loads(z.read("model/scene.gltf"))["images"][0]["uri"] == "textures/cement%20lossy.webp"
    expect_error("missing_resource", tmp_path / "b.zip", contains="textures/cement lossy.webp")
    # an unused image must exist too
    g = minimal()
    g.images.append(png_bytes())
    write_zip(tmp_path / "c.zip", g, image_names=["unused.png"], skip=("unused.png",))
    expect_error("missing_resource", tmp_path / "c.zip", contains="unused.png")
    # a GLB whose buffer points to a file
    g = minimal()
    g.doc["buffers"] = [{"byteLength": len(g.bin), "uri": "other.bin"}]
    (tmp_path / "d.glb").write_bytes(glb_bytes(g.doc, b""))
    expect_error("missing_resource", tmp_path / "d.glb", contains="other.bin")


def test_non_finite(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0]], np.float32)))
    expect_error("non_finite", write_glb(tmp_path / "a.glb", g))
    g = Gltf()
    g.node(mesh=g.mesh(QUAD[:3] * 1e30), scale=[1e20, 1, 1])  # overflows float32 after the transform
    expect_error("non_finite", write_glb(tmp_path / "b.glb", g))
    g = Gltf()
    g.node(mesh=g.mesh(QUAD[:3], TEXCOORD_0=np.array([[0, 0], [np.inf, 0], [0, 0]])))
    expect_error("non_finite", write_glb(tmp_path / "c.glb", g))
    g = minimal()
    g.doc["nodes"][0]["translation"] = [0, 12345.5, 0]
    text = write_gltf(tmp_path / "d.gltf", g).read_text().replace("12345.5", "1e999")  # parses to inf
    (tmp_path / "d.gltf").write_text(text)
    expect_error("non_finite", tmp_path / "d.gltf")


def test_no_triangles(tmp_path):
    g = Gltf()
    g.node(name="empty")
    expect_error("no_triangles", write_glb(tmp_path / "a.glb", g))
    g = Gltf()
    g.doc["meshes"].append({"primitives": [{"attributes": {"NORMAL": g.accessor(QUAD[:3])}}]})
    g.node(mesh=0)
    expect_error("no_triangles", write_glb(tmp_path / "b.glb", g), contains="without POSITION")


def test_size_limits(tmp_path):
    path = write_glb(tmp_path / "a.glb", minimal())
    expect_error("too_large", path, IngestLimits(max_bytes=100))
    expect_error("too_many_triangles", path, IngestLimits(max_triangles=1))
    assert ingest_file(path, IngestLimits(max_triangles=2)).n_triangles == 2
    g = Gltf()
    g.node(
        mesh=g.mesh(QUAD[:3]),
        extensions={
            "EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": g.accessor(np.zeros((1000, 3), np.float32))}}
        },
    )
    expect_error("too_many_triangles", write_glb(tmp_path / "b.glb", g), IngestLimits(max_triangles=999))
    # an accessor without data (all zeros) may not declare more bytes than an upload may hold
    g = minimal()
    del g.doc["accessors"][0]["bufferView"]
    g.doc["accessors"][0]["count"] = 10**9
    expect_error("too_large", write_glb(tmp_path / "c.glb", g))


def test_zip_bombs(tmp_path):
    # one member expanding ~1000x
    write_zip(tmp_path / "a.zip", minimal(), extra={"zeros.bin": bytes(16 << 20)})
    expect_error("zip_bomb", tmp_path / "a.zip")
    # total expanded size over the limit
    write_zip(tmp_path / "b.zip", minimal(), extra={"pad.bin": os.urandom(4096)})
    expect_error("zip_bomb", tmp_path / "b.zip", IngestLimits(max_expanded_bytes=4000))
    # too many members
    write_zip(tmp_path / "c.zip", minimal(), extra={f"f{i}": b"" for i in range(20)})
    expect_error("zip_bomb", tmp_path / "c.zip", IngestLimits(max_zip_members=10))


def test_image_too_large_is_checked_from_the_header(tmp_path):
    for w, h in [(9000, 9000), (100_000, 100_000)]:  # below and above PIL's own bomb threshold
        g = sample_scene()
        g.images[0] = png_header_only(w, h)
        expect_error("image_too_large", write_glb(tmp_path / f"{w}.glb", g))
    g = sample_scene()
    g.images[0] = png_bytes(64, 64)
    expect_error("image_too_large", write_glb(tmp_path / "small.glb", g), IngestLimits(max_image_pixels=64 * 63))


def test_invalid_image(tmp_path):
    g = sample_scene()
    g.images[0] = b"\x89PNG\r\n\x1a\nthis is not a png"
    expect_error("invalid_image", write_glb(tmp_path / "a.glb", g))
    g.images[0] = b"GIF89a" + bytes(30)
    expect_error("invalid_image", write_glb(tmp_path / "b.glb", g))


@pytest.mark.parametrize(
    "ext",
    [
        "KHR_texture_basisu",
        "FAKE_quantum_rendering",
        "KHR_materials_transmission",
    ],
)
def test_unsupported_extension(tmp_path, ext):
    g = minimal(extensionsUsed=[ext], extensionsRequired=[ext])
    expect_error("unsupported_extension", write_glb(tmp_path / "a.glb", g), contains=ext)


@pytest.mark.parametrize(
    "ext", ["KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression"]
)
def test_compression_extensions_are_honoured_when_required(tmp_path, ext):
    # decoded, not refused (workers.gltf_compression; tests/workers/test_ingest_compression.py); a file
    # that only names them reads normally
    s = ingest_file(write_glb(tmp_path / "a.glb", minimal(extensionsUsed=[ext], extensionsRequired=[ext])))
    assert s.n_triangles == 2 and not any("extensions ignored" in w for w in s.warnings)


def test_draco_primitive_is_decoded_even_with_fallback(tmp_path):
    # Draco is preferred over the uncompressed fallback: a bufferView that is not Draco data is an error
    # (invalid_gltf), whether the accessors have a fallback bufferView or not
    g = minimal(extensionsUsed=["KHR_draco_mesh_compression"])
    prim = g.doc["meshes"][0]["primitives"][0]
    prim["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}}
    expect_error("invalid_gltf", write_glb(tmp_path / "a.glb", g), contains="Draco")
    del g.doc["accessors"][prim["attributes"]["POSITION"]]["bufferView"]
    expect_error("invalid_gltf", write_glb(tmp_path / "b.glb", g), contains="Draco")


def test_unsupported(tmp_path):
    expect_error("unsupported", write_glb(tmp_path / "a.glb", minimal(asset={"version": "1.0"})))
    expect_error("unsupported", write_glb(tmp_path / "b.glb", minimal(asset={"version": "2.0", "minVersion": "2.1"})))
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, mode=0))
    expect_error("unsupported", write_glb(tmp_path / "c.glb", g), contains="point")
    data = bytearray(glb_bytes(minimal().doc, b""))
    data[4] = 1
    (tmp_path / "d.glb").write_bytes(bytes(data))
    expect_error("unsupported", tmp_path / "d.glb")


def _broken(edit):
    g = minimal()
    edit(g.doc, g)
    return g


@pytest.mark.parametrize(
    "name,edit",
    [
        ("accessor index", lambda d, g: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=99)),
        ("view past buffer", lambda d, g: d["bufferViews"][0].update(byteLength=10_000)),
        ("accessor past view", lambda d, g: d["accessors"][0].update(count=100)),
        ("index out of range", lambda d, g: d["accessors"][0].update(count=3)),
        ("bad component", lambda d, g: d["accessors"][0].update(componentType=5130)),
        ("stride too small", lambda d, g: d["bufferViews"][0].update(byteStride=4)),
        ("node cycle", lambda d, g: d["nodes"].append({"children": [1]}) or d["nodes"][0].update(children=[1])),
        ("child twice", lambda d, g: d["nodes"].append({}) or d["nodes"][0].update(children=[1, 1])),
        ("bad mode", lambda d, g: d["meshes"][0]["primitives"][0].update(mode=9)),
        ("bad material", lambda d, g: d["meshes"][0]["primitives"][0].update(material=3)),
        ("scene index", lambda d, g: d.update(scene=5)),
        ("zero quaternion", lambda d, g: d["nodes"][0].update(rotation=[0, 0, 0, 0])),
        ("bad light", lambda d, g: d["nodes"][0].update(extensions={"KHR_lights_punctual": {"light": 0}})),
        ("string count", lambda d, g: d["accessors"][0].update(count="4")),
        ("nodes not a list", lambda d, g: d.update(nodes={"a": 1})),
    ],
)
def test_invalid_gltf(tmp_path, name, edit):
    expect_error("invalid_gltf", write_glb(tmp_path / "a.glb", _broken(edit)))


def test_primitive_restart_value_is_invalid(tmp_path):
    g = Gltf()
    pos = np.zeros((256, 3), np.float32)
    pos[1], pos[255] = [1, 0, 0], [0, 1, 0]
    g.node(mesh=g.mesh(pos))
    g.doc["meshes"][0]["primitives"][0]["indices"] = g.accessor(np.array([0, 1, 255], np.uint8))
    expect_error("invalid_gltf", write_glb(tmp_path / "a.glb", g), contains="restart")


def test_broken_zip_and_multiple_models(tmp_path):
    (tmp_path / "a.zip").write_bytes(b"PK\x03\x04" + os.urandom(200))
    expect_error("broken_zip", tmp_path / "a.zip")
    write_zip(tmp_path / "b.zip", minimal(), extra={"other/x.glb": b"glTF"})
    expect_error("multiple_models", tmp_path / "b.zip")
    # CRC damage inside a stored member
    g = minimal()
    write_zip(tmp_path / "c.zip", g)
    with zipfile.ZipFile(tmp_path / "c.zip") as z:
        doc = json.loads(z.read("model/scene.gltf"))
    with zipfile.ZipFile(tmp_path / "d.zip", "w", zipfile.ZIP_STORED) as z:
        z.writestr("model/scene.gltf", json.dumps(doc))
        z.writestr("model/data/scene.bin", bytes(g.bin))
    data = bytearray((tmp_path / "d.zip").read_bytes())
    pos = data.find(bytes(g.bin[12:24]))  # vertex (1, 0, 0) inside the stored .bin
    assert pos > 0
    data[pos + 4] ^= 0xFF
    (tmp_path / "d.zip").write_bytes(bytes(data))
    expect_error("broken_zip", tmp_path / "d.zip")


def test_random_damage_raises_only_ingest_errors(tmp_path):
    """Truncations and byte flips of a valid GLB and zip: every outcome is a scene or an IngestError."""
    rng = np.random.default_rng(7)
    sources = [
        write_glb(tmp_path / "s.glb", sample_scene()).read_bytes(),
        write_zip(tmp_path / "s.zip", sample_scene()).read_bytes(),
        write_gltf(tmp_path / "s.gltf", sample_scene()).read_bytes(),
    ]
    codes: Counter = Counter()
    for i in range(150):
        data = bytearray(sources[i % 3])
        if i % 2:
            data = data[: int(rng.integers(1, len(data)))]
        else:
            for _ in range(int(rng.integers(1, 6))):
                data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        path = tmp_path / f"m{i}"
        path.write_bytes(bytes(data))
        try:
            s = ingest_file(path)
            codes["ok"] += 1
            assert np.isfinite(s.triangles).all()
        except IngestError as err:
            assert 400 <= err.status < 500
            codes[err.code] += 1
    assert sum(codes.values()) == 150 and len(codes) > 3, codes


def _json_slots(obj, path=()):
    """Every (container path, key) in a JSON document, depth first."""
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for key, val in items:
        yield from _json_slots(val, path + (key,))
        yield path + (key,)


def feature_scene() -> Gltf:
    """sample_scene plus a skinned morphing strip, sparse positions, GPU instancing, a texture transform, a spot."""
    g = sample_scene()
    d = g.doc
    pos = g.accessor(QUAD[:3])
    d["accessors"][pos]["sparse"] = {
        "count": 1,
        "indices": {"bufferView": g.view(np.array([2], np.uint16).tobytes()), "componentType": 5123},
        "values": {"bufferView": g.view(np.array([[0, 2, 0]], np.float32).tobytes())},
    }
    target = g.accessor(np.ones((3, 3), np.float32))
    joints = g.accessor(np.zeros((3, 4), np.uint8))
    weights = g.accessor(np.tile(np.array([1, 0, 0, 0], np.float32), (3, 1)))
    d["meshes"].append(
        {
            "primitives": [
                {
                    "attributes": {"POSITION": pos, "JOINTS_0": joints, "WEIGHTS_0": weights},
                    "targets": [{"POSITION": target}],
                    "mode": 5,
                }
            ],
            "weights": [0.5],
        }
    )
    d["skins"] = [
        {
            "joints": [g.node(translation=[0, 5, 0])],
            "inverseBindMatrices": g.accessor(np.eye(4, dtype=np.float32).reshape(1, 16)),
        }
    ]
    g.node(mesh=len(d["meshes"]) - 1, skin=0)
    t = g.accessor(np.array([[0, 0, 0], [10, 0, 0]], np.float32))
    g.node(mesh=0, extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": t}}})
    d["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
        "KHR_texture_transform": {"offset": [0.5, 0.25], "scale": [2, 3], "rotation": 1.0}
    }
    d["extensions"]["KHR_lights_punctual"]["lights"].append({"type": "spot", "spot": {"outerConeAngle": 0.3}})
    g.node(rotation=[0, 0.7071068, 0, 0.7071068], extensions={"KHR_lights_punctual": {"light": 1}})
    return g


def test_feature_scene(tmp_path):
    s = ingest_file(write_glb(tmp_path / "f.glb", feature_scene()))
    assert s.n_triangles == 5 + 1 + 2 * 2  # sample scene, the skinned strip, two instances of the quad
    # strip vertex 2 replaced by the sparse (0, 2, 0), morphed by 0.5 * (1, 1, 1), carried by the joint at y = 5
    np.testing.assert_allclose(s.triangles[5], [[0.5, 5.5, 0.5], [1.5, 5.5, 0.5], [0.5, 7.5, 0.5]], atol=1e-6)
    np.testing.assert_allclose(s.triangles[6:, 0, 0], [0, 0, 10, 10], atol=1e-6)
    # the texture transform moved the quad's UVs: corner uv (0, 1) -> (sin 1 * 3 + 0.5, cos 1 * 3 + 0.25)
    np.testing.assert_allclose(s.uv0[0, 0], [3 * math.sin(1.0) + 0.5, 3 * math.cos(1.0) + 0.25], atol=1e-6)
    assert [light["type"] for light in s.lights] == ["point", "spot"]


def test_mutated_json_raises_only_specific_ingest_errors(tmp_path):
    """Seeded structural fuzz: random JSON values replaced or deleted, random BIN bytes flipped.

    Every outcome is a scene or an IngestError, and none falls through to the generic
    "could not be read" wrapper: each bad value is caught by an explicit check.
    """
    data = write_glb(tmp_path / "base.glb", feature_scene()).read_bytes()
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + json_len])
    bin_ = data[20 + json_len + 8 :]
    slots = list(_json_slots(doc))
    bad_values = [-1, 0, 1, 2, 3, 99999, 2**40, 1.5, 1e300, "x", None, [], {}, [1, 2], True, {"index": 0}]
    rng = np.random.default_rng(11)
    codes: Counter = Counter()
    for i in range(400):
        d = copy.deepcopy(doc)
        for _ in range(int(rng.integers(1, 3))):
            path = slots[int(rng.integers(len(slots)))]
            parent = d
            try:
                for key in path[:-1]:
                    parent = parent[key]
                if isinstance(parent, dict) and rng.random() < 0.2:
                    del parent[path[-1]]
                else:
                    parent[path[-1]] = bad_values[int(rng.integers(len(bad_values)))]
            except (KeyError, IndexError, TypeError):
                pass  # an earlier mutation removed the path
        b = bytearray(bin_)
        if i % 3 == 0:
            for _ in range(4):
                b[int(rng.integers(len(b)))] = int(rng.integers(256))
        (tmp_path / "m.glb").write_bytes(glb_bytes(d, bytes(b)))
        try:
            ingest_file(tmp_path / "m.glb")
            codes["ok"] += 1
        except IngestError as err:
            assert 400 <= err.status < 500
            assert "could not be read as glTF 2.0" not in err.message, err.message
            codes[err.code] += 1
    assert codes["ok"] > 20 and codes["invalid_gltf"] > 200, codes


def test_unreadable_path_is_an_ingest_error(tmp_path):
    with pytest.raises(IngestError) as info:
        ingest_file(tmp_path / "does-not-exist.glb")
    assert info.value.code == "unreadable_upload"


# ---------------------------------------------------------------------------------------------- corpus


def _zip_model(gltf_path: Path, dest: Path, extra: dict | None = None) -> Path:
    """Zip a corpus .gltf with every referenced file that exists beside it (as a user would upload it)."""
    doc = json.loads(gltf_path.read_text())
    with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as z:
        z.write(gltf_path, gltf_path.name)
        for key in ("buffers", "images"):
            for obj in doc.get(key, []):
                uri = obj.get("uri", "")
                rel = urllib.parse.unquote(uri)
                if uri and not uri.startswith("data:") and (gltf_path.parent / rel).is_file():
                    z.write(gltf_path.parent / rel, rel)
        for name, data in (extra or {}).items():
            z.writestr(name, data)
    return dest


def _missing_files(gltf_path: Path) -> list[str]:
    doc = json.loads(gltf_path.read_text())
    return [
        urllib.parse.unquote(o["uri"])
        for k in ("buffers", "images")
        for o in doc.get(k, [])
        if "uri" in o
        and not o["uri"].startswith("data:")
        and not (gltf_path.parent / urllib.parse.unquote(o["uri"])).is_file()
    ]


def _manifest() -> list[dict]:
    try:
        return json.loads((CORPUS / "MANIFEST.json").read_text())
    except OSError:
        return []


# trimesh 5.2.0 quirks: it drops TRIANGLE_FAN primitives and ignores skins, so its counts differ there.
_TRIMESH_COUNT_DIFFERS = {"Mesh_PrimitiveMode_05", "Mesh_PrimitiveMode_12"}


def _check_corpus_model(entry: dict, upload_dir: Path) -> tuple[str, str | None]:
    """Ingest one corpus model zipped as a user would; returns (outcome, problem or None)."""
    gltf = CORPUS / entry["file"]
    missing = _missing_files(gltf)
    upload = _zip_model(gltf, upload_dir / "model.zip")
    try:
        scene = ingest_file(upload, filename=gltf.name)
    except IngestError as err:
        if not 400 <= err.status < 500:
            return err.code, f"status {err.status}"
        if missing and not (err.code == "missing_resource" and missing[0] in err.message):
            return err.code, f"expected missing_resource naming {missing[0]}, got {err.message}"
        if not missing and entry["expected"] == "valid" and err.code not in ("unsupported", "unsupported_extension"):
            return err.code, f"valid model refused: {err.message}"
        return err.code, None
    except Exception as exc:  # noqa: BLE001 - the point of the test
        return "crash", f"{type(exc).__name__}: {exc}"
    if missing:
        return "ok", f"ingested although {missing} is missing"
    if entry["expected"] not in ("valid", "warning-only"):
        return "ok", f"invalid model ingested ({entry['validator']})"
    if not (scene.n_triangles > 0 and np.isfinite(scene.triangles).all()):
        return "ok", "empty or non-finite scene"
    if not np.allclose(np.linalg.norm(scene.normals, axis=-1), 1.0, atol=1e-5):
        return "ok", "normals not unit"
    if scene.material.min() < 0 or scene.material.max() >= len(scene.materials):
        return "ok", "material index out of range"
    for m in scene.materials:
        for key in ("base_color_texture", "emissive_texture"):
            if m[key] is not None and not 0 <= m[key] < len(scene.textures):
                return "ok", f"{key} out of range"
    if (
        entry["trimesh"].get("loaded")
        and gltf.stem not in _TRIMESH_COUNT_DIFFERS
        and scene.n_triangles != entry["trimesh"]["triangles"]
    ):
        return "ok", f"{scene.n_triangles} triangles, trimesh found {entry['trimesh']['triangles']}"
    return "ok", None


@needs_corpus
def test_corpus(tmp_path):
    """Every MANIFEST.json model: valid ones ingest (or get a named unsupported*), invalid ones raise
    IngestError (warning-only ones may ingest), missing-texture ones name the missing file; nothing but
    IngestError ever escapes. Triangle counts match trimesh's where trimesh reads the model right."""
    entries = _manifest()
    assert len(entries) > 200
    outcomes: Counter = Counter()
    problems = []
    for entry in entries:
        outcome, problem = _check_corpus_model(entry, tmp_path)
        outcomes[(entry["expected"], outcome)] += 1
        if problem:
            problems.append(f"{entry['file']}: {problem}")
    assert not problems, "\n".join(problems)
    # What the corpus gave when this test was written (trimesh 5.2.0 era): pinned to catch regressions.
    assert outcomes[("valid", "ok")] == 159
    assert outcomes[("valid", "unsupported")] == 9  # 8 points/lines-only models, 1 minVersion 2.1
    assert outcomes[("valid", "unsupported_extension")] == 1  # FAKE_materials_quantumRendering
    assert outcomes[("invalid", "missing_resource")] == 22
    assert outcomes[("invalid", "invalid_gltf")] == 14  # primitive restart values
    assert outcomes[("warning-only", "no_triangles")] == 2  # no POSITION: skipped per spec, nothing left


@needs_corpus
def test_corpus_negative_scale_matches_trimesh_winding(tmp_path):
    """Node_NegativeScale models (texture supplied): same triangles and winding as trimesh, normals agree."""
    trimesh = pytest.importorskip("trimesh")
    folder = CORPUS / "invalid/asset-generator-missing-texture/Positive/Node_NegativeScale"
    # matrix mirrors (01-03), TRS mirrors on 1-3 axes (04-06), the same with vertex normals (10-12)
    models = [folder / f"Node_NegativeScale_{i:02d}.gltf" for i in (1, 2, 3, 4, 5, 6, 10, 11, 12)]
    assert all(m.is_file() for m in models)
    for gltf in models:
        upload = _zip_model(gltf, tmp_path / "n.zip", extra={m: png_bytes() for m in _missing_files(gltf)})
        s = ingest_file(upload)
        ref = trimesh.load(gltf, force="scene").to_geometry()
        assert oriented(s.triangles, 2) == oriented(ref.triangles, 2), gltf.name
        dots = np.einsum("tj,tcj->tc", face_normals(s), s.normals)
        assert dots.min() > 0.99, gltf.name  # vertex normals agree with the (possibly flipped) winding


@needs_corpus
def test_corpus_skin_is_posed(tmp_path):
    """Animation_Skin_00: joint0 stands the plane up (-90 deg about X), joint1 bends the top half by 30 deg."""
    gltf = CORPUS / "valid/asset-generator/Positive/Animation_Skin/Animation_Skin_00.gltf"
    s = ingest_file(_zip_model(gltf, tmp_path / "s.zip"))
    v = np.unique(s.triangles.reshape(-1, 3).round(3), axis=0)
    np.testing.assert_allclose(v[:, 1], [-0.2, 0, 0.173, -0.2, 0, 0.173], atol=2e-3)
    np.testing.assert_allclose(v[:, 2], [0, 0, -0.1, 0, 0, -0.1], atol=2e-3)
    same = ingest_file(_zip_model(gltf.with_name("Animation_Skin_02.gltf"), tmp_path / "t.zip"))
    np.testing.assert_allclose(same.triangles, s.triangles, atol=1e-6)  # node transforms ignored


# ---------------------------------------------------------------------------------------------- real scenes


@needs_scenes
def test_cornell_box_khr_lights(tmp_path):
    gltf = SCENES / "cornell-box-mcguire-khr-lights/CornellBox-Original.gltf"
    s = ingest_file(_zip_model(gltf, tmp_path / "c.zip"), filename="cornell.zip")
    assert s.n_triangles == 36
    np.testing.assert_allclose(s.bounds, [[-1.02, 0, -1.04], [1.0, 1.99, 0.99]], atol=1e-6)
    (light,) = s.lights
    assert light["type"] == "point" and light["intensity"] == 5.0 and light["range"] == 10.0
    assert light["color"] == [1.0, 0.706, 0.235]
    np.testing.assert_allclose(light["position"], [-0.005, 1.9, -0.03])
    names = [m["name"] for m in s.materials]
    lamp = s.materials[names.index("light")]
    np.testing.assert_allclose(lamp["emissive"], np.array([1.0, 0.70588235, 0.23529412]) * 17.0, rtol=1e-6)
    left = s.materials[names.index("leftWall")]
    assert left["base_color"] == [1.0, 0.065, 0.05, 1.0]
    assert (s.material == names.index("light")).sum() == 2  # the emissive quad
    assert all(m["double_sided"] for m in s.materials)
    # the same scene as GLB and as .gltf with data URIs gets the same id
    doc = json.loads(gltf.read_text())
    bin_ = (gltf.parent / doc["buffers"][0]["uri"]).read_bytes()
    glb_doc = copy.deepcopy(doc)
    glb_doc["buffers"] = [{"byteLength": len(bin_)}]
    (tmp_path / "c.glb").write_bytes(glb_bytes(glb_doc, bin_))
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bin_).decode()
    raw_gltf(tmp_path / "c.gltf", doc)
    assert ingest_file(tmp_path / "c.glb").scene_id() == s.scene_id() == ingest_file(tmp_path / "c.gltf").scene_id()


@needs_scenes
def test_truck_town_percent_encoded_webp(tmp_path):
    gltf = SCENES / "truck-town/town_model.gltf"
    assert "%2F" in gltf.read_text()  # the URIs really are percent-encoded
    s = ingest_file(_zip_model(gltf, tmp_path / "t.zip"))
    assert s.n_triangles == 30477
    np.testing.assert_allclose(s.bounds, [[-1024, -4.64, -1024], [1024, 17.756, 1024]], atol=1e-3)
    assert len(s.textures) == 2 and all(t.shape == (1024, 1024, 4) for t in s.textures)
    assert all(t[..., 3].min() == 255 and t[..., :3].std() > 1 for t in s.textures)  # real pixels, opaque
    by_name = {m["name"]: m for m in s.materials}
    assert by_name["GrassMaterial"]["base_color_texture"] == 0 and by_name["CementMaterial"]["base_color_texture"] == 1
    grass = s.material == list(by_name).index("GrassMaterial")
    assert grass.any() and np.ptp(s.uv0[grass]) > 1  # UVs reach the textured triangles
    assert s.lights == [] and "extensions ignored: OMI_physics_body, OMI_physics_shape" in s.warnings
    # a loose .gltf upload cannot carry its textures
    with pytest.raises(IngestError) as info:
        ingest_file(gltf)
    assert info.value.code == "missing_resource"


@needs_scenes
def test_zdm2_sauerbraten():
    s = ingest_file(SCENES / "zdm2-sauerbraten/zdm2.glb")
    assert s.n_triangles == 58772
    np.testing.assert_allclose(s.bounds, [[-33.879, -11.968, -29.29], [43.321, 23.984, 30.31]], atol=1e-3)
    assert s.materials == [
        {
            "name": "default",
            "base_color": [1.0, 1.0, 1.0, 1.0],
            "base_color_texture": None,
            "emissive": [0.0, 0.0, 0.0],
            "emissive_texture": None,
            "double_sided": False,
            # glTF 3.9.6's default material: a rough white metal (GI albedo 0.5, workers.kernels.materials)
            "metallic": 1.0,
            "roughness": 1.0,
            "metallic_roughness_texture": None,
            "alpha_mode": "OPAQUE",
            "alpha_cutoff": 0.5,
        }
    ]
    assert (s.material == 0).all() and s.lights == [] and len(s.warnings) == 1
    assert "default material" in s.warnings[0]


@needs_scenes
def test_godot_living_room():
    s = ingest_file(SCENES / "godot-living-room/living_room.glb")
    assert s.n_triangles == 5088
    np.testing.assert_allclose(s.bounds, [[-5, -1.5, -2.5], [5, 4, 12]], atol=1e-5)
    assert [m["name"] for m in s.materials] == [
        "wall",
        "ceiling",
        "window_frame",
        "exterior_wall",
        "grass",
        "top",
        "pole",
    ]
    assert sorted(np.unique(s.material).tolist()) == list(range(7))
    np.testing.assert_allclose(s.materials[3]["base_color"], [0.50667548, 0.80000007, 0.19654307, 1], rtol=1e-6)
    assert s.uv1 is None and s.lights == []
