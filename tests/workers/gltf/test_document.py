"""Tests for workers.gltf.document: asset version and required extensions."""

from __future__ import annotations

import pytest

from tests.workers.gltf.builders import Gltf, glb_bytes, write_glb, QUAD, expect_error, minimal
from workers.gltf import IngestError, ingest_file


@pytest.mark.parametrize(
    "ext",
    [
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
    # decoded, not refused (workers.gltf.compression; tests/workers/gltf/test_compression.py); a file
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


# ---------------------------------------------------------------------------------------------- unit: document


def test_checked_access_and_number_fields():
    from workers.gltf.document import Document, lookup, num, vec

    doc = Document({"asset": {"version": "2.0"}, "meshes": [{"name": "m"}, 3], "nodes": {}})
    assert doc.item("meshes", 0, "nodes[0]") == {"name": "m"}
    for idx, text in ((2, "meshes[2], but the file has 2 meshes"), ("0", "not an integer"), (1, "is not an object")):
        with pytest.raises(IngestError) as info:
            doc.item("meshes", idx, "nodes[0]")
        assert info.value.code == "invalid_gltf" and text in info.value.message
    with pytest.raises(IngestError):
        doc.array("nodes")
    assert doc.array("textures") == [] and Document.exts({"extensions": []}) == {}
    assert vec(None, 3, [0, 0, 1], "t") == [0.0, 0.0, 1.0] and vec([1, 2], 2, None, "t") == [1.0, 2.0]
    assert num(None, 0.5, "x") == 0.5 and num(2, None, "x") == 2.0
    for bad in ([1, True], [1], "ab"):
        with pytest.raises(IngestError):
            vec(bad, 2, None, "t")
    with pytest.raises(IngestError) as info:
        num(float("inf"), 0, "x")
    assert info.value.code == "non_finite"
    assert lookup({1: "a"}, 1) == "a" and lookup({1: "a"}, [1]) is None and lookup({1: "a"}, True) is None


def test_asset_version_and_extensions():
    from workers.gltf.document import Document

    warnings: list[str] = []
    Document({"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_lights_punctual", "EXT_foo"]}).check_extensions(warnings)
    assert warnings == ["extensions ignored: EXT_foo"]
    with pytest.raises(IngestError) as info:
        Document({"asset": {}, "extensionsRequired": ["EXT_foo"]}).check_extensions([])
    assert info.value.code == "unsupported_extension" and "EXT_foo" in info.value.message
    Document({"asset": {}, "extensionsRequired": ["KHR_texture_basisu"]}).check_extensions([])  # read: test_materials
    Document({"asset": {"version": "2.1", "minVersion": "2.0"}}).check_asset()
    for asset, code in (({"version": "1.0"}, "unsupported"), ({"version": "2"}, "invalid_gltf"),
                        ({"version": "2.0", "minVersion": "2.1"}, "unsupported")):
        with pytest.raises(IngestError) as info:
            Document({"asset": asset}).check_asset()
        assert info.value.code == code
