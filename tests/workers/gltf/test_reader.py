"""Tests for workers.gltf.reader: glTF 2.0 upload -> NormalizedScene, end to end.

Crafted files (written in tmp_path) cover the structural errors and random damage; the Khronos asset-generator
corpus and the real scenes in ../shared are run when present (skipped, saying why, when not).
"""

from __future__ import annotations

import base64
import copy
import json
import math
import struct
import urllib.parse
import zipfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from tests.workers.gltf.builders import (
    CORPUS, SCENES, needs_corpus, needs_scenes, Gltf, png_bytes, glb_bytes, write_glb, write_gltf, write_zip,
    raw_gltf, QUAD, QUAD_UV, sample_scene, face_normals, oriented, expect_error, minimal,
)
from workers.gltf import IngestError, ingest_file


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


def test_no_triangles(tmp_path):
    g = Gltf()
    g.node(name="empty")
    expect_error("no_triangles", write_glb(tmp_path / "a.glb", g))
    g = Gltf()
    g.doc["meshes"].append({"primitives": [{"attributes": {"NORMAL": g.accessor(QUAD[:3])}}]})
    g.node(mesh=0)
    expect_error("no_triangles", write_glb(tmp_path / "b.glb", g), contains="without POSITION")


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
