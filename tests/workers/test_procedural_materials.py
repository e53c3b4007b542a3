"""Material scenes of workers/procedural.py (two-rooms-vc, metal-room): valid GLB, vertex colours, textures, metals."""
from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import trimesh
from PIL import Image

from workers.procedural import (ALL_SCENES, MATERIAL_SCENES, METAL_ROOM_MATERIALS, SCENES, TWO_ROOMS_VC_COLORS,
                                make_scene)

_DTYPE = {5126: np.float32, 5125: np.uint32, 5121: np.uint8}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def parse(data: bytes) -> tuple[dict, bytes]:
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    js_len, js_type = struct.unpack_from("<II", data, 12)
    assert js_type == 0x4E4F534A and js_len % 4 == 0
    off = 20 + js_len
    bin_len, bin_type = struct.unpack_from("<II", data, off)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0 and off + 8 + bin_len == len(data)
    return json.loads(data[20:off]), data[off + 8:]


def accessor(doc, blob, i) -> np.ndarray:
    a = doc["accessors"][i]
    v = doc["bufferViews"][a["bufferView"]]
    dt = np.dtype(_DTYPE[a["componentType"]])
    n = a["count"] * _WIDTH[a["type"]]
    assert v["byteOffset"] % 4 == 0 and n * dt.itemsize <= v["byteLength"]
    return np.frombuffer(blob, dt, n, v["byteOffset"]).reshape(a["count"], -1)


def prims(doc, blob):
    for mesh in doc["meshes"]:
        for p in mesh["primitives"]:
            attrs = {k: accessor(doc, blob, i) for k, i in p["attributes"].items()}
            idx = accessor(doc, blob, p["indices"]).reshape(-1, 3)
            yield doc["materials"][p["material"]], attrs, idx, p


@pytest.fixture(scope="module")
def glbs():
    return {n: make_scene(n) for n in MATERIAL_SCENES}


def test_registry():
    assert set(MATERIAL_SCENES) == {"two-rooms-vc", "metal-room"}
    assert not set(MATERIAL_SCENES) & set(SCENES) and set(ALL_SCENES) == set(SCENES) | set(MATERIAL_SCENES)
    for n in MATERIAL_SCENES:
        assert make_scene(n) == make_scene(n)


@pytest.mark.parametrize("name", sorted(MATERIAL_SCENES))
def test_valid_closed_geometry(glbs, name):
    doc, blob = parse(glbs[name])
    assert doc["buffers"] == [{"byteLength": len(blob)}]
    tris = []
    for mat, attrs, idx, p in prims(doc, blob):
        assert p["mode"] == 4 and idx.max() < len(attrs["POSITION"])
        for k, a in attrs.items():
            assert len(a) == len(attrs["POSITION"]), k
            view = doc["bufferViews"][doc["accessors"][p["attributes"][k]]["bufferView"]]
            assert view["target"] == 34962
        pos = attrs["POSITION"].astype(np.float64)
        t = pos[idx]
        geo = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        geo /= np.linalg.norm(geo, axis=1, keepdims=True)
        np.testing.assert_allclose(attrs["NORMAL"][idx[:, 0]], geo, atol=1e-6)
        tris.append(t)
    mesh = trimesh.Trimesh(**trimesh.triangles.to_kwargs(np.concatenate(tris)))
    assert mesh.is_watertight and mesh.is_winding_consistent
    volume = {"two-rooms-vc": 8.15 * 3.1 * 4.1 - 2 * 48.0 - 0.05 * 2.0 * 0.9,
              "metal-room": 4.1 * 2.6 * 3.1 - 4 * 2.5 * 3 + 0.8 ** 3}[name]
    assert mesh.volume == pytest.approx(volume, rel=1e-5)
    scene = trimesh.load(io.BytesIO(glbs[name]), file_type="glb", force="scene")
    assert len(scene.to_mesh().faces) == len(mesh.faces)


def test_two_rooms_vc(glbs):
    doc, blob = parse(glbs["two-rooms-vc"])
    ref_doc, ref_blob = parse(make_scene("two-rooms"))
    assert doc["extensions"] == ref_doc["extensions"]  # the same light
    colours = set()
    tris = []
    for mat, attrs, idx, p in prims(doc, blob):
        pbr = mat["pbrMetallicRoughness"]
        assert pbr["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0] and pbr["metallicFactor"] == 0.0
        assert "baseColorTexture" not in pbr
        c = attrs["COLOR_0"]
        acc = doc["accessors"][p["attributes"]["COLOR_0"]]
        if mat["name"] == "vc-ubyte":
            assert acc["type"] == "VEC4" and acc["componentType"] == 5121 and acc["normalized"] is True
            assert (c[:, 3] == 255).all()
            rgb = c[:, :3].astype(np.float64) / 255.0
        else:
            assert mat["name"] == "vc-float" and acc["type"] == "VEC3" and acc["componentType"] == 5126
            rgb = c.astype(np.float64)
        colours |= {tuple(np.round(x, 3)) for x in rgb}
        tris.append(attrs["POSITION"][idx])
    assert colours == {tuple(np.round(v, 3)) for v in TWO_ROOMS_VC_COLORS.values()}
    ref = np.concatenate([a["POSITION"][i] for _, a, i, _ in prims(ref_doc, ref_blob)])
    key = lambda t: np.sort(t.reshape(len(t), -1), axis=0)  # noqa: E731
    np.testing.assert_array_equal(key(np.concatenate(tris)), key(ref))  # the two-rooms geometry


def test_metal_room(glbs):
    doc, blob = parse(glbs["metal-room"])
    assert len(doc["images"]) == len(doc["textures"]) == 2 and len(doc["samplers"]) == 1
    for img in doc["images"]:
        v = doc["bufferViews"][img["bufferView"]]
        assert "target" not in v and img["mimeType"] == "image/png"
        im = Image.open(io.BytesIO(blob[v["byteOffset"]:v["byteOffset"] + v["byteLength"]]))
        assert max(im.size) <= 64
    by_name = {}
    for mat, attrs, idx, p in prims(doc, blob):
        by_name[mat["name"]] = (mat, attrs)
    assert set(by_name) == set(METAL_ROOM_MATERIALS)
    for name, spec in METAL_ROOM_MATERIALS.items():
        mat, attrs = by_name[name]
        pbr = mat["pbrMetallicRoughness"]
        assert pbr["baseColorFactor"][:3] == list(spec["base_color"])
        assert pbr["metallicFactor"] == spec.get("metallic", 0.0)
        assert pbr["roughnessFactor"] == spec.get("roughness", 1.0)
        tex = spec.get("texture")
        assert ("TEXCOORD_0" in attrs) == (tex is not None)
        for slot in ("baseColorTexture", "metallicRoughnessTexture"):
            assert (slot in pbr) == (slot == tex)
    # the striped box: B = metallic in 4-texel stripes, G = roughness 0.5
    mr = doc["textures"][by_name["striped-metal"][0]["pbrMetallicRoughness"]["metallicRoughnessTexture"]["index"]]
    v = doc["bufferViews"][doc["images"][mr["source"]]["bufferView"]]
    px = np.asarray(Image.open(io.BytesIO(blob[v["byteOffset"]:v["byteOffset"] + v["byteLength"]])).convert("RGB"))
    assert px.shape == (8, 8, 3) and (px[..., 1] == 128).all() and px[..., 2].mean() == 127.5
    # the metal wall is the inside of x = 4
    pos = by_name["metal"][1]["POSITION"]
    np.testing.assert_allclose(pos[:, 0], 4.0)
    np.testing.assert_allclose(by_name["metal"][1]["NORMAL"], [[-1, 0, 0]] * len(pos), atol=1e-6)
    # the floor's TEXCOORD_0 is (z, x) / 2 m
    a = by_name["checker"][1]
    np.testing.assert_allclose(a["TEXCOORD_0"], a["POSITION"][:, [2, 0]] / 2.0, atol=1e-6)
    np.testing.assert_allclose(a["POSITION"][:, 1], 0.0)


@pytest.mark.parametrize("name", sorted(MATERIAL_SCENES))
def test_ingest_reads_them(tmp_path, glbs, name):
    from workers.gltf import ingest_file

    path = tmp_path / f"{name}.glb"
    path.write_bytes(glbs[name])
    scene = ingest_file(path)
    assert scene.n_triangles == 352
