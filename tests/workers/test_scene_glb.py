"""The ``scene`` artifact: the normalized scene as GLB (workers.scene_glb) re-ingests to the same scene."""
from __future__ import annotations

import math

import numpy as np
import pytest

from proto import bundle
from proto.models import BakeConfig
from workers.gltf import ingest_file
from workers.scene import NormalizedScene
from workers.scene_glb import scene_to_glb
from workers.stages.base import StageContext
from workers.stages.lighting import run_lighting


def _rich_scene() -> NormalizedScene:
    """Six triangles over four materials and three UV1 charts (one run without TEXCOORD_1), vertex colours,
    an emissive material brighter than 1, MASK and BLEND alpha, three textures (one metallic-roughness), in
    first-use order as workers.gltf numbers them."""
    rng = np.random.default_rng(3)
    T = 6
    tri = rng.uniform(-2, 2, (T, 3, 3)).astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    nrm = np.repeat(n[:, None], 3, axis=1).astype(np.float32)
    nrm[1, 2] = (nrm[1, 2] + np.array([0.3, 0, 0])) / np.linalg.norm(nrm[1, 2] + np.array([0.3, 0, 0]))  # smooth
    tex = [rng.integers(0, 256, (4, 8, 4), dtype=np.uint8) for _ in range(3)]
    mats = [
        {"name": "textured", "base_color": [1.0, 0.5, 0.25, 1.0], "base_color_texture": 0, "emissive": [0.0, 0.0, 0.0],
         "emissive_texture": None, "double_sided": False, "metallic": 0.0, "roughness": 0.8,
         "metallic_roughness_texture": 1, "alpha_mode": "OPAQUE", "alpha_cutoff": 0.5},
        {"name": "lamp", "base_color": [0.9, 0.9, 0.9, 1.0], "base_color_texture": None, "emissive": [4.0, 3.0, 2.0],
         "emissive_texture": 2, "double_sided": True, "metallic": 0.0, "roughness": 1.0,
         "metallic_roughness_texture": None, "alpha_mode": "OPAQUE", "alpha_cutoff": 0.5},
        {"name": "leaves", "base_color": [0.2, 0.6, 0.1, 1.0], "base_color_texture": 0, "emissive": [0.0, 0.0, 0.0],
         "emissive_texture": None, "double_sided": True, "metallic": 0.0, "roughness": 0.5,
         "metallic_roughness_texture": None, "alpha_mode": "MASK", "alpha_cutoff": 0.3},
        {"name": "metal", "base_color": [0.95, 0.64, 0.54, 0.5], "base_color_texture": None, "emissive": [0.1, 0.0, 0.0],
         "emissive_texture": None, "double_sided": False, "metallic": 1.0, "roughness": 0.25,
         "metallic_roughness_texture": None, "alpha_mode": "BLEND", "alpha_cutoff": 0.5},
    ]
    colors = rng.uniform(0, 1, (T, 3, 4)).astype(np.float32)
    chart = np.array([0, 0, -1, -1, 5, 5], np.int32)
    uv1 = rng.uniform(0, 1, (T, 3, 2)).astype(np.float32)
    uv1[chart < 0] = 0
    return NormalizedScene(
        triangles=tri, normals=nrm, uv0=rng.uniform(-1, 2, (T, 3, 2)).astype(np.float32),
        material=np.array([0, 1, 1, 2, 3, 0], np.int32), materials=mats, textures=tex,
        uv1_partial=uv1, uv1_chart=chart, colors=colors,
        lights=[{"type": "point", "color": [1.0, 0.9, 0.8], "intensity": 100.0, "range": None,
                 "position": [0.5, 1.5, 0.25], "direction": None, "inner_cone_angle": None,
                 "outer_cone_angle": None, "name": "bulb"}])


LIGHTS = [
    {"type": "point", "color": [1.0, 0.9, 0.8], "intensity": 100.0, "range": 12.0, "position": [0.5, 1.5, 0.25],
     "direction": None, "inner_cone_angle": None, "outer_cone_angle": None, "name": "bulb"},
    {"type": "spot", "color": [1.0, 1.0, 1.0], "intensity": 400.0, "range": None, "position": [0.0, 2.0, 0.0],
     "direction": [0.0, -1.0, 0.0], "inner_cone_angle": 0.2, "outer_cone_angle": 0.6, "name": "spot"},
    {"type": "directional", "color": [1.0, 0.95, 0.9], "intensity": 10000.0, "range": None, "position": None,
     "direction": [0.0, 0.0, 1.0], "inner_cone_angle": None, "outer_cone_angle": None, "name": "sun"},
]


def _reingest(tmp_path, scene, lights=None) -> NormalizedScene:
    path = tmp_path / "scene.glb"
    path.write_bytes(scene_to_glb(scene, lights))
    return ingest_file(path)


def _same_geometry(a: NormalizedScene, b: NormalizedScene) -> None:
    np.testing.assert_array_equal(b.triangles, a.triangles)
    np.testing.assert_allclose(b.normals, a.normals, atol=1e-6)
    np.testing.assert_array_equal(b.uv0, a.uv0)
    np.testing.assert_array_equal(b.material, a.material)
    assert (a.colors is None) == (b.colors is None)
    if a.colors is not None:
        np.testing.assert_array_equal(b.colors, a.colors)
    assert len(b.textures) == len(a.textures)
    for x, y in zip(a.textures, b.textures):
        np.testing.assert_array_equal(y, x)
    assert len(b.materials) == len(a.materials)
    for x, y in zip(a.materials, b.materials):
        assert y.keys() == x.keys()
        for k in x:
            if isinstance(x[k], list):
                np.testing.assert_allclose(y[k], x[k], rtol=1e-6, err_msg=f"{x['name']}.{k}")
            else:
                assert y[k] == x[k], (x["name"], k, x[k], y[k])


def test_rich_scene_reingests_to_the_same_triangles_and_materials(tmp_path):
    a = _rich_scene()
    b = _reingest(tmp_path, a, LIGHTS)
    _same_geometry(a, b)
    # TEXCOORD_1 per triangle and the same chart partition (charts are node indices: renumbered)
    ua, ca = a.texcoord1()
    ub, cb = b.texcoord1()
    np.testing.assert_array_equal(ub, ua)
    assert ((cb < 0) == (ca < 0)).all()
    assert len({(int(x), int(y)) for x, y in zip(ca, cb)}) == len(set(ca.tolist()))
    # the lights as baked (KHR_lights_punctual on their own nodes)
    assert len(b.lights) == len(LIGHTS)
    for want, got in zip(LIGHTS, b.lights):
        assert got["type"] == want["type"] and got["name"] == want["name"]
        assert got["intensity"] == pytest.approx(want["intensity"])
        np.testing.assert_allclose(got["color"], want["color"])
        for k in ("position", "direction"):
            if want[k] is None:
                assert got[k] is None, (want["name"], k)
            else:
                np.testing.assert_allclose(got[k], want[k], atol=1e-6, err_msg=f"{want['name']}.{k}")
        if want["type"] == "spot":
            assert got["inner_cone_angle"] == pytest.approx(0.2) and got["outer_cone_angle"] == pytest.approx(0.6)
        assert got["range"] == want["range"]


def test_glb_is_deterministic_and_shares_vertices(tmp_path):
    a = _rich_scene()
    assert scene_to_glb(a, LIGHTS) == scene_to_glb(a, LIGHTS)
    # a closed box: 12 triangles, 24 distinct corners (4 per face) instead of 36
    from tests.gltf_build import box_inward

    pos, nrm, idx = box_inward([0, 0, 0], [1, 1, 1])
    tri = pos[idx]
    box = NormalizedScene(triangles=tri, normals=nrm[idx], uv0=np.zeros((12, 3, 2), np.float32),
                          material=np.zeros(12, np.int32), materials=[_rich_scene().materials[0] | {"base_color_texture": None,
                                                                                                    "metallic_roughness_texture": None}])
    glb = scene_to_glb(box)
    import json
    import struct

    n = struct.unpack("<I", glb[12:16])[0]
    doc = json.loads(glb[20:20 + n])
    pos_acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert pos_acc["count"] == 24
    _same_geometry(box, _reingest(tmp_path, box))


@pytest.mark.parametrize("name", ["cornell", "metal-room", "two-rooms-vc"])
def test_procedural_scenes_reingest(tmp_path, name):
    from workers.procedural import write_scene

    write_scene(name, tmp_path / "in.glb")
    a = ingest_file(tmp_path / "in.glb")
    b = _reingest(tmp_path, a)
    _same_geometry(a, b)
    assert len(b.lights) == len(a.lights)


def test_the_ingest_stage_writes_the_scene_artifact(tmp_path, scene_files):
    scene = ingest_file(scene_files["two-rooms"])
    cfg = BakeConfig.model_validate({"scene": {"lights": [{"type": "spot", "position": [2, 2.5, 2], "direction": [0, -1, 0],
                                                           "intensity": 200, "outer_cone_angle": math.radians(40)}],
                                               "sky": [0.1, 0.1, 0.1]}})
    out = run_lighting(StageContext(config=cfg, scene_loader=lambda: scene, inputs={}, report=lambda f: None))
    arts = {a.name: a for a in out.artifacts}
    assert arts["scene"].format == "glb" and arts["scene"].meta["lights"] == len(scene.lights) + 1
    # written and read back through the bundle format
    info = bundle.write_artifact(tmp_path, "scene", arts["scene"].data, "ingest", format="glb")
    assert info.file == "scene.glb" and info.bytes == out.stats["scene_bytes"]
    back = bundle.load_artifact(tmp_path / info.file, info)
    assert back.tobytes() == arts["scene"].data
    b = ingest_file(tmp_path / info.file)
    _same_geometry(scene, b)
    assert [l["type"] for l in b.lights] == [l["type"] for l in scene.lights] + ["spot"]
    with pytest.raises(ValueError):
        bundle.write_artifact(tmp_path, "bad", b"not a glb", "ingest", format="glb")
