"""Tests for workers.gltf.limits: size limits and hostile magnitudes (each case builds the exact file it needs)."""

from __future__ import annotations

import copy
import json
import zipfile

import numpy as np
import pytest

from tests.workers.gltf.builders import Gltf, write_glb, write_gltf, write_zip, QUAD, expect_error, minimal, LFS_POINTER
from workers.gltf import IngestError, IngestLimits, MAX_COORD, ingest_file


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


@pytest.mark.parametrize("node", [
    {"scale": [1e20, 1e20, 1e20]},
    {"translation": [0, 2e7, 0]},
    {"matrix": [1e12, 0, 0, 0, 0, 1e12, 0, 0, 0, 0, 1e12, 0, 0, 0, 0, 1]},
])
def test_absurd_node_transforms(tmp_path, node):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3]), **node)
    err = expect_error("absurd_magnitude", write_glb(tmp_path / "a.glb", g))
    assert f"{MAX_COORD:g}" in err.message


def test_absurd_positions(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD * np.float32(3e7), [0, 1, 2, 0, 2, 3]))
    expect_error("absurd_magnitude", write_glb(tmp_path / "a.glb", g))
    # 1e6 m is large but a scene (a terrain tile in metres): accepted
    g = Gltf()
    g.node(mesh=g.mesh(QUAD * np.float32(1e6), [0, 1, 2, 0, 2, 3]))
    assert ingest_file(write_glb(tmp_path / "b.glb", g)).triangles.shape[0] == 2


def _emissive(tmp_path, name, factor, strength=None):
    m = {"emissiveFactor": factor}
    if strength is not None:
        m["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
    g = Gltf()
    g.doc["materials"] = [m]
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3], material=0))
    return write_glb(tmp_path / name, g)


def test_emissive_refusals(tmp_path):
    expect_error("absurd_magnitude", _emissive(tmp_path, "a.glb", [1, 1, 1], 1e60))
    expect_error("absurd_magnitude", _emissive(tmp_path, "b.glb", [1e60, 0, 0]))
    expect_error("negative_emissive", _emissive(tmp_path, "c.glb", [-1, 0, 0]), contains="negative")
    expect_error("negative_emissive", _emissive(tmp_path, "d.glb", [1, 1, 1], -2.0))
    s = ingest_file(_emissive(tmp_path, "e.glb", [1, 0.5, 0], 1000.0))  # a bright lamp is fine
    assert s.materials[0]["emissive"] == [1000.0, 500.0, 0.0]


def _light(tmp_path, name, light, translation=(0, 2, 0)):
    g = minimal()
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [light]}}
    g.node(translation=list(translation), extensions={"KHR_lights_punctual": {"light": 0}})
    return write_glb(tmp_path / name, g)


def test_light_refusals(tmp_path):
    expect_error("absurd_magnitude", _light(tmp_path, "a.glb", {"type": "point", "intensity": 1e39}))
    expect_error("absurd_magnitude", _light(tmp_path, "b.glb", {"type": "point", "color": [1e308, 1, 1]}))
    expect_error("absurd_magnitude", _light(tmp_path, "c.glb", {"type": "point"}, translation=(1e20, 0, 0)))
    expect_error("negative_light", _light(tmp_path, "d.glb", {"type": "point", "color": [1, -1, 1]}))
    expect_error("negative_light", _light(tmp_path, "e.glb", {"type": "spot", "intensity": -5}))
    s = ingest_file(_light(tmp_path, "f.glb", {"type": "directional", "intensity": 1e5}))  # the sun, in lux
    assert s.lights[0]["intensity"] == 1e5


def test_zero_extent(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(np.full((4, 3), 0.5, np.float32), [0, 1, 2, 0, 2, 3]))  # distinct indices, one point
    expect_error("zero_extent", write_glb(tmp_path / "a.glb", g), contains="one point")


@pytest.mark.parametrize("offset, warned", [(0.0, False), (200.0, False), (20_000.0, True)])
def test_a_scene_far_from_the_origin_is_warned_about(tmp_path, offset, warned):
    # a 4 m room 20 km out: float32 positions there are 2 mm apart, the bake's ray offsets 0.6 mm (acne, leaks);
    # 200 m out they are 15 um apart (baked as at the origin)
    g = Gltf()
    room = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 4], [0, 3, 4]], np.float32)
    g.node(mesh=g.mesh(room, [0, 1, 2, 0, 2, 3]), translation=[offset, 0.0, -offset])
    s = ingest_file(write_glb(tmp_path / "far.glb", g))
    far = [w for w in s.warnings if "from the glTF origin" in w]
    assert bool(far) == warned, s.warnings
    if warned:
        assert "20,00" in far[0] and "2 mm apart" in far[0] and "Move the scene near the origin" in far[0]


def test_far_from_origin_is_relative_to_the_scene_size():
    from workers.gltf.limits import far_from_origin

    def far(size, shift):                                       # a box `size` m across, `shift` m out
        return far_from_origin(np.full(3, shift), np.full(3, shift + size))

    assert far(1.0, 10.0) is None
    assert "10,00" in far(1.0, 10_000.0)
    assert far(2000.0, 10_000.0) is None and far(2000.0, 4e6)  # a 3.5 km town (truck-town's size)


def test_only_degenerate_triangles(tmp_path):
    line = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], np.float32)
    g = Gltf()
    g.node(mesh=g.mesh(line, [0, 1, 2, 1, 2, 3]))
    expect_error("degenerate_triangles", write_glb(tmp_path / "a.glb", g), contains="zero area")
    # collinear corners that float32 does not hold exactly are degenerate too
    t = np.linspace(0, 1, 30)[:, None] * np.array([[0.1, 0.7, 0.3]])
    g = Gltf()
    g.node(mesh=g.mesh(t.astype(np.float32), np.arange(30)))
    expect_error("degenerate_triangles", write_glb(tmp_path / "b.glb", g))
    # one real triangle among them: the scene is baked as it is
    g = Gltf()
    g.node(mesh=g.mesh(line, [0, 1, 2, 1, 2, 3]))
    g.node(mesh=g.mesh(QUAD, [0, 1, 2]))
    assert ingest_file(write_glb(tmp_path / "c.glb", g)).triangles.shape[0] == 3


def test_lfs_pointer_as_buffer(tmp_path):
    """A Git LFS pointer committed in place of scene.bin: refused by name, not read as ~1e31 coordinates."""
    g = minimal()
    write_zip(tmp_path / "a.zip", g, skip=("data/scene.bin",), extra={"model/data/scene.bin": LFS_POINTER})
    err = expect_error("text_buffer", tmp_path / "a.zip", contains="Git LFS")
    assert "data/scene.bin" in err.message
    # byteLength matching the pointer's size (the file the issue found baked at ~1e31)
    doc = copy.deepcopy(g.doc)
    doc["buffers"] = [{"byteLength": len(LFS_POINTER), "uri": "scene.bin"}]
    for acc in doc["accessors"]:
        acc.pop("min", None), acc.pop("max", None)
    with zipfile.ZipFile(tmp_path / "b.zip", "w") as z:
        z.writestr("scene.gltf", json.dumps(doc))
        z.writestr("scene.bin", LFS_POINTER)
    expect_error("text_buffer", tmp_path / "b.zip")
    # any text, not only LFS pointers
    with zipfile.ZipFile(tmp_path / "c.zip", "w") as z:
        z.writestr("scene.gltf", json.dumps(doc))
        z.writestr("scene.bin", (b"0.0 1.0 2.0 3.0\n" * 20)[: len(LFS_POINTER)])
    expect_error("text_buffer", tmp_path / "c.zip")


def test_lfs_pointer_as_model(tmp_path):
    (tmp_path / "scene.glb").write_bytes(LFS_POINTER)
    expect_error("not_gltf", tmp_path / "scene.glb", contains="Git LFS")


# ---------------------------------------------------------------------------------------------- unit: checks


def test_check_extent_and_check_binary_directly():
    from workers.gltf.limits import check_binary, check_extent

    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    check_extent(tri, "a.glb")  # one good triangle is enough
    line = np.array([[[0, 0, 0], [1, 0, 0], [2, 0, 0]]] * 2, np.float32)
    with pytest.raises(IngestError) as info:
        check_extent(np.concatenate([line, line]), "a.glb")
    assert info.value.code == "degenerate_triangles" and "4 triangles" in info.value.message
    with pytest.raises(IngestError) as info:
        check_extent(np.zeros((1, 3, 3), np.float32), "a.glb")
    assert info.value.code == "zero_extent" and "1 triangle lie" in info.value.message
    floats = np.frombuffer(np.linspace(-1, 1, 64, dtype=np.float32).tobytes(), np.uint8)
    check_binary(floats, floats.size, 0, {"byteLength": floats.size})
    text = np.frombuffer(b"0.5 0.25 1.0\n" * 8, np.uint8)
    with pytest.raises(IngestError) as info:
        check_binary(text, text.size, 2, {"uri": "data%20.bin"})
    assert info.value.code == "text_buffer" and info.value.message.startswith("buffers[2] ('data .bin') holds text")
    check_binary(text[:20], 20, 0, {})  # too short to judge
