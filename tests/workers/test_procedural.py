"""Procedural known-answer scenes (workers/procedural.py): valid GLB, expected geometry and lights."""
from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import trimesh

from workers.procedural import BAKE_BOXES, SCENES, make_scene, write_scene

# name -> (triangles, bounds min, bounds max), metres
EXPECTED = {
    "cornell": (1036, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
    "furnace": (1, (0.0, -1000.0, 0.0), (0.001, -1000.0, 0.001)),
    "two-rooms": (352, (-0.05, -0.05, -0.05), (8.1, 3.05, 4.05)),
    "sealed-box": (224, (-5.0, -0.1, -5.0), (5.0, 1.0, 5.0)),
}
_COMPONENT = {5126: np.float32, 5125: np.uint32}
_WIDTH = {"SCALAR": 1, "VEC3": 3}


# ------------------------------------------------------------------ helpers
@pytest.fixture(scope="module")
def glbs() -> dict[str, bytes]:
    return {name: make_scene(name) for name in SCENES}


def parse_glb(data: bytes) -> tuple[dict, bytes]:
    """Split a GLB into (JSON document, BIN chunk), checking the container layout."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    js_len, js_type = struct.unpack_from("<II", data, 12)
    assert js_type == 0x4E4F534A and js_len % 4 == 0
    js = data[20:20 + js_len]
    assert js.rstrip(b" ").endswith(b"}")  # padded with spaces only
    bin_off = 20 + js_len
    bin_len, bin_type = struct.unpack_from("<II", data, bin_off)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0
    assert bin_off + 8 + bin_len == len(data)
    return json.loads(js), data[bin_off + 8:]


def accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = _COMPONENT[acc["componentType"]]
    n = acc["count"] * _WIDTH[acc["type"]]
    start = view["byteOffset"] + acc.get("byteOffset", 0)
    assert start + n * 4 <= view["byteOffset"] + view["byteLength"]
    arr = np.frombuffer(blob, dtype=dtype, count=n, offset=start)
    return arr.reshape(acc["count"], -1) if acc["type"] != "SCALAR" else arr


def primitives(doc: dict, blob: bytes):
    """Yield (material dict, triangles (T, 3, 3) float64, vertex normals (T, 3, 3)) per primitive."""
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            pos = accessor(doc, blob, prim["attributes"]["POSITION"]).astype(np.float64)
            nrm = accessor(doc, blob, prim["attributes"]["NORMAL"]).astype(np.float64)
            idx = accessor(doc, blob, prim["indices"]).reshape(-1, 3)
            yield doc["materials"][prim["material"]], pos[idx], nrm[idx]


def all_triangles(doc: dict, blob: bytes) -> np.ndarray:
    return np.concatenate([t for _, t, _ in primitives(doc, blob)])


def lights_by_name(doc: dict) -> dict[str, tuple[dict, dict]]:
    """light name -> (light, node) for every node carrying a KHR_lights_punctual light."""
    lights = doc["extensions"]["KHR_lights_punctual"]["lights"]
    out = {}
    for node in doc["nodes"]:
        ext = node.get("extensions", {}).get("KHR_lights_punctual")
        if ext is not None:
            out[lights[ext["light"]]["name"]] = (lights[ext["light"]], node)
    return out


def rotate(q, v) -> np.ndarray:
    """Rotate v by the unit quaternion q = [x, y, z, w] (glTF order)."""
    u, w = np.asarray(q[:3], float), float(q[3])
    v = np.asarray(v, float)
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def crossings(tris: np.ndarray, origin, direction, t_max: float = np.inf) -> int:
    """How many triangles the ray origin + t*direction, 0 < t < t_max, crosses (Moller-Trumbore)."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
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
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9) & (t < t_max)
    return int(hit.sum())


# An oblique direction, so parity rays never run along a face or through an edge of the grid.
_ODD_DIR = np.array([0.3117, 0.8123, 0.4931])


def inside_geometry(tris: np.ndarray, point) -> bool:
    return crossings(tris, point, _ODD_DIR) % 2 == 1


# ------------------------------------------------------------------ API
def test_scene_names():
    assert set(SCENES) == {"cornell", "furnace", "two-rooms", "sealed-box"}
    assert set(BAKE_BOXES) == set(SCENES)
    assert all(isinstance(d, str) and d for d in SCENES.values())


@pytest.mark.parametrize("bad", ["", "Cornell", "nope", None, 3])
def test_unknown_name_lists_valid_names(bad):
    with pytest.raises(ValueError) as err:
        make_scene(bad)
    for name in SCENES:
        assert name in str(err.value)


def test_deterministic(glbs):
    for name, data in glbs.items():
        assert make_scene(name) == data


def test_write_scene_atomic(tmp_path, glbs):
    path = tmp_path / "scene.glb"
    path.write_bytes(b"old")
    write_scene("cornell", path)
    assert path.read_bytes() == glbs["cornell"]
    write_scene("furnace", str(path))
    assert path.read_bytes() == glbs["furnace"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.glb"]  # no temp file left
    with pytest.raises(ValueError):
        write_scene("nope", tmp_path / "other.glb")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.glb"]


# ------------------------------------------------------------------ container and glTF validity
@pytest.mark.parametrize("name", sorted(SCENES))
def test_glb_structure(glbs, name):
    doc, blob = parse_glb(glbs[name])
    assert doc["asset"]["version"] == "2.0"
    assert doc["buffers"] == [{"byteLength": len(blob)}]
    assert doc["scene"] == 0 and sorted(doc["scenes"][0]["nodes"]) == list(range(len(doc["nodes"])))
    for view in doc["bufferViews"]:
        assert view["buffer"] == 0 and view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + view["byteLength"] <= len(blob)
        assert view["target"] in (34962, 34963)
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            assert prim["mode"] == 4
            pos = doc["accessors"][prim["attributes"]["POSITION"]]
            data = accessor(doc, blob, prim["attributes"]["POSITION"])
            assert pos["min"] == [float(x) for x in data.min(axis=0)]
            assert pos["max"] == [float(x) for x in data.max(axis=0)]
            assert doc["bufferViews"][pos["bufferView"]]["target"] == 34962
            assert doc["bufferViews"][doc["accessors"][prim["indices"]]["bufferView"]]["target"] == 34963
            idx = accessor(doc, blob, prim["indices"])
            assert idx.max() < pos["count"] and len(idx) % 3 == 0
    for mat in doc["materials"]:
        pbr = mat["pbrMetallicRoughness"]
        assert len(pbr["baseColorFactor"]) == 4 and pbr["baseColorFactor"][3] == 1.0
        assert pbr["metallicFactor"] == 0.0 and pbr["roughnessFactor"] == 1.0
        assert len(mat["emissiveFactor"]) == 3 and max(mat["emissiveFactor"]) <= 1.0
    used = doc.get("extensionsUsed", [])
    assert ("KHR_lights_punctual" in used) == ("KHR_lights_punctual" in doc.get("extensions", {}))
    strength = any("KHR_materials_emissive_strength" in m.get("extensions", {}) for m in doc["materials"])
    assert ("KHR_materials_emissive_strength" in used) == strength
    assert "extensionsRequired" not in doc


@pytest.mark.parametrize("name", sorted(SCENES))
def test_flat_normals_match_winding(glbs, name):
    doc, blob = parse_glb(glbs[name])
    for _, tris, nrm in primitives(doc, blob):
        geo = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        geo /= np.linalg.norm(geo, axis=1, keepdims=True)
        np.testing.assert_allclose(np.linalg.norm(nrm, axis=2), 1.0, atol=1e-6)
        np.testing.assert_allclose(nrm, np.repeat(geo[:, None], 3, axis=1), atol=1e-6)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_trimesh_loads_expected_geometry(glbs, name):
    count, lo, hi = EXPECTED[name]
    scene = trimesh.load(io.BytesIO(glbs[name]), file_type="glb", force="scene")
    mesh = scene.to_mesh()
    assert len(mesh.faces) == count
    np.testing.assert_allclose(scene.bounds, [lo, hi], atol=1e-6)
    doc, blob = parse_glb(glbs[name])
    assert len(all_triangles(doc, blob)) == count


# ------------------------------------------------------------------ closed solids
# name -> (volume of the solid, m^3; surface components: outer shell + separate cavities)
SOLIDS = {
    "cornell": (1 - 0.96 * 0.96 * 0.98 + 0.25 * 0.01 * 0.25 + 0.26 * 0.6 * 0.26 + 0.28 ** 3, 1),
    "two-rooms": (8.15 * 3.1 * 4.1 - 2 * 48.0 - 0.05 * 2.0 * 0.9, 2),
    "sealed-box": (10 * 10 * 0.1 + 1.0 - 0.9 ** 3, 2),
}


@pytest.mark.parametrize("name", sorted(SOLIDS))
def test_solids_are_closed_and_outward(glbs, name):
    volume, components = SOLIDS[name]
    doc, blob = parse_glb(glbs[name])
    # Merge the per-face vertices (flat normals duplicate them) into one surface.
    mesh = trimesh.Trimesh(**trimesh.triangles.to_kwargs(all_triangles(doc, blob)))
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(volume, rel=1e-5)  # positive: normals face outward
    assert len(mesh.split(only_watertight=True)) == components


# ------------------------------------------------------------------ per-scene layout and lights
def test_cornell(glbs):
    doc, blob = parse_glb(glbs["cornell"])
    by_mat: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for mat, tris, nrm in primitives(doc, blob):
        by_mat.setdefault(mat["name"], []).append((tris, nrm[:, 0]))
    assert set(by_mat) == {"white", "red", "green", "emitter"}

    def area(tris):
        return 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum()

    (red, red_n), = by_mat["red"]
    np.testing.assert_allclose(red[..., 0], 0.02, atol=1e-6)
    np.testing.assert_allclose(red_n, np.tile([1, 0, 0], (len(red), 1)), atol=1e-6)
    assert area(red) == pytest.approx(0.96 * 0.98, rel=1e-5)
    (green, green_n), = by_mat["green"]
    np.testing.assert_allclose(green[..., 0], 0.98, atol=1e-6)
    np.testing.assert_allclose(green_n, np.tile([-1, 0, 0], (len(green), 1)), atol=1e-6)
    assert area(green) == pytest.approx(0.96 * 0.98, rel=1e-5)
    (quad, quad_n), = by_mat["emitter"]
    assert len(quad) == 2  # one quad, facing down, just under the ceiling
    np.testing.assert_allclose(quad[..., 1], 0.97, atol=1e-6)
    np.testing.assert_allclose(quad_n, [[0, -1, 0]] * 2, atol=1e-6)
    np.testing.assert_allclose(quad.reshape(-1, 3).min(0)[[0, 2]], [0.375, 0.375], atol=1e-6)
    np.testing.assert_allclose(quad.reshape(-1, 3).max(0)[[0, 2]], [0.625, 0.625], atol=1e-6)

    emitter = next(m for m in doc["materials"] if m["name"] == "emitter")
    assert emitter["emissiveFactor"] == [1.0, 1.0, 1.0]
    assert emitter["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] == 10.0
    white = next(m for m in doc["materials"] if m["name"] == "white")
    assert white["emissiveFactor"] == [0.0, 0.0, 0.0] and "extensions" not in white

    lights = lights_by_name(doc)
    assert set(lights) == {"ceiling"}
    light, node = lights["ceiling"]
    assert light["type"] == "point" and light["intensity"] == 1.0 and light["color"] == [1.0, 1.0, 1.0]
    assert node["translation"] == [0.5, 0.96, 0.5]

    tris = all_triangles(doc, blob)
    assert not inside_geometry(tris, [0.5, 0.5, 0.5])  # the room
    assert not inside_geometry(tris, node["translation"])  # the light is in free space
    for p in ([0.01, 0.5, 0.5], [0.99, 0.5, 0.5], [0.5, 0.01, 0.5], [0.5, 0.99, 0.5],
              [0.5, 0.5, 0.01], [0.5, 0.975, 0.5], [0.2, 0.5, 0.2], [0.8, 0.2, 0.8]):
        assert inside_geometry(tris, p), p  # walls, emitter panel, tall box, short box
    # the front is open: from the room centre, a ray along +z leaves without a hit
    assert crossings(tris, [0.5, 0.5, 0.5], [0.0, 0.01, 1.0]) == 0


def test_furnace_has_no_occluder_in_its_box(glbs):
    doc, blob = parse_glb(glbs["furnace"])
    assert "extensions" not in doc and "extensionsUsed" not in doc  # no lights
    assert all("extensions" not in n for n in doc["nodes"])
    tris = all_triangles(doc, blob)
    assert len(tris) == 1
    lo, hi = map(np.asarray, BAKE_BOXES["furnace"])
    assert np.all(tris[..., 1] < lo[1] - 900.0)  # 1 km below the bake box
    assert np.ptp(tris.reshape(-1, 3), axis=0).max() <= 0.001 + 1e-9  # 1 mm
    # the triangle faces away (-Y) from the box above it
    n = np.cross(tris[0, 1] - tris[0, 0], tris[0, 2] - tris[0, 0])
    assert n[1] < 0 and abs(n[0]) < 1e-12 and abs(n[2]) < 1e-12
    assert doc["scenes"][0]["extras"]["kiln_bake_box"] == {"min": list(lo), "max": list(hi)}


def test_two_rooms(glbs):
    doc, blob = parse_glb(glbs["two-rooms"])
    lights = lights_by_name(doc)
    assert set(lights) == {"room-a"}
    light, node = lights["room-a"]
    assert light["type"] == "point" and light["intensity"] == 20.0
    pos = node["translation"]
    assert pos == [1.5, 2.5, 2.0] and 0 < pos[0] < 4 and 0 < pos[1] < 3 and 0 < pos[2] < 4  # room A

    tris = all_triangles(doc, blob)
    for p in ([2, 1.5, 2], [6, 1.5, 2], [4.025, 1.0, 2.0], pos):  # room A, room B, the doorway, the light
        assert not inside_geometry(tris, p), p
    for p in ([4.025, 2.5, 2.0], [4.025, 1.0, 0.5], [4.025, 1.0, 3.5],  # shared wall around the door
              [-0.025, 1, 2], [8.075, 1, 2], [2, -0.025, 2], [6, 3.025, 2], [2, 1, -0.025], [6, 1, 4.025]):
        assert inside_geometry(tris, p), p
    assert not inside_geometry(tris, [-1.0, 1.0, 2.0])  # outside the building

    # Room B sees the light only through the door; the rest of the shared wall blocks it.
    def visible(a, b):
        d = np.subtract(b, a, dtype=float)
        return crossings(tris, a, d, t_max=1.0 - 1e-9) == 0

    assert visible(pos, [6.0, 1.0, 2.0])  # through the doorway
    assert not visible(pos, [6.0, 1.5, 0.5])  # behind the wall
    assert not visible(pos, [6.0, 2.8, 2.0])  # over the door lintel
    assert not visible(pos, [-1.0, 1.5, 2.0])  # outside


def test_sealed_box(glbs):
    doc, blob = parse_glb(glbs["sealed-box"])
    lights = lights_by_name(doc)
    assert set(lights) == {"sun", "lamp"}
    sun, sun_node = lights["sun"]
    assert sun["type"] == "directional" and sun["intensity"] == 3.0
    assert "translation" not in sun_node
    direction = rotate(sun_node["rotation"], [0.0, 0.0, -1.0])  # glTF lights shine along local -Z
    expected = np.array([-0.4, -1.0, -0.3]) / np.linalg.norm([-0.4, -1.0, -0.3])
    np.testing.assert_allclose(direction, expected, atol=1e-12)
    lamp, lamp_node = lights["lamp"]
    assert lamp["type"] == "point" and lamp["intensity"] == 15.0
    assert lamp_node["translation"] == [2.5, 2.0, 2.5]

    tris = all_triangles(doc, blob)
    lamp_pos = lamp_node["translation"]
    assert not inside_geometry(tris, lamp_pos)
    assert not inside_geometry(tris, [0.0, 0.5, 0.0])  # the cavity is free space...
    for p in ([0.475, 0.5, 0.0], [0.0, 0.975, 0.0], [0.0, 0.025, 0.0], [0.0, 0.5, -0.475], [3.0, -0.05, 3.0]):
        assert inside_geometry(tris, p), p  # walls and floor slab
    rng = np.random.default_rng(7)
    for p in rng.uniform(-0.44, 0.44, size=(16, 3)) + [0.0, 0.5, 0.0]:  # ... but sees no light
        assert crossings(tris, p, np.subtract(lamp_pos, p), t_max=1.0) > 0
        assert crossings(tris, p, -expected) > 0  # towards the sun
        assert crossings(tris, p, rng.normal(size=3)) > 0  # nor the sky
    # while the floor next to the box sees both
    assert crossings(tris, [2.0, 1e-4, 0.0], np.subtract(lamp_pos, [2.0, 1e-4, 0.0]), t_max=1.0) == 0
    assert crossings(tris, [2.0, 1e-4, 0.0], -expected) == 0
