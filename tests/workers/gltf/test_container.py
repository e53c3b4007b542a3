"""Tests for workers.gltf.container: sniffing, GLB chunks, JSON, URIs and data: URIs."""

from __future__ import annotations

import base64
import json
import struct
import zipfile

import numpy as np
import pytest

from tests.workers.gltf.builders import (
    png_bytes, glb_bytes, write_glb, write_gltf, write_zip, raw_gltf, sample_scene, expect_error, minimal,
)
from workers.gltf import IngestError, IngestLimits, ingest_file
from workers.scene import NormalizedScene


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


def test_integers_written_as_floats(tmp_path):
    """glTF's integers are JSON Schema integers, which 3.0 is (JSON Schema 2020-12 §6.1.1)."""
    g = minimal()
    write_gltf(tmp_path / "a.gltf", g)
    doc = json.loads((tmp_path / "a.gltf").read_text())
    for acc in doc["accessors"]:
        acc["count"] = float(acc["count"])
        acc["componentType"] = float(acc["componentType"])
        acc["bufferView"] = float(acc["bufferView"])
    for view in doc["bufferViews"]:
        view["byteLength"], view["byteOffset"], view["buffer"] = (float(view["byteLength"]),
                                                                  float(view["byteOffset"]), 0.0)
    doc["buffers"][0]["byteLength"] = float(doc["buffers"][0]["byteLength"])
    doc["scene"], doc["scenes"][0]["nodes"] = 0.0, [0.0]
    doc["nodes"][0]["mesh"] = 0.0
    doc["meshes"][0]["primitives"][0]["mode"] = 4.0
    text = json.dumps(doc).replace('"count": 6.0', '"count": 6e0')  # an exponent is a float in JSON too
    (tmp_path / "b.gltf").write_text(text)
    s = ingest_file(tmp_path / "b.gltf")
    assert s.triangles.shape[0] == 2
    np.testing.assert_allclose(s.triangles, ingest_file(tmp_path / "a.gltf").triangles)
    doc["accessors"][0]["count"] = 3.5  # not an integer
    (tmp_path / "c.gltf").write_text(json.dumps(doc))
    expect_error("invalid_gltf", tmp_path / "c.gltf")


# ---------------------------------------------------------------------------------------------- unit: container


def test_sniff_tells_the_kinds_apart():
    from workers.gltf.container import sniff

    assert sniff(b"glTF\x02\x00\x00\x00") == "glb"
    assert sniff(b"PK\x03\x04rest") == "zip" and sniff(b"PK\x05\x06") == "zip"
    assert sniff(b"\xef\xbb\xbf \n{\"asset\": {}}") == "gltf"
    assert sniff(b"solid cube") is None and sniff(b"") is None


def test_read_glb_splits_json_and_bin_chunks(tmp_path):
    from workers.gltf.container import map_file, read_glb

    doc = {"asset": {"version": "2.0"}}
    path = tmp_path / "a.glb"
    path.write_bytes(glb_bytes(doc, b"\x01\x02\x03\x04\x05\x06\x07\x08") + b"junk")
    warnings: list[str] = []
    js, bin_chunk = read_glb(path, "a.glb", warnings)
    assert json.loads(js) == doc
    assert bin_chunk[0] == path and bin_chunk[2] == 8
    assert bytes(map_file(*bin_chunk)) == b"\x01\x02\x03\x04\x05\x06\x07\x08"
    assert warnings == ["4 bytes after the end of the GLB ignored"]
    no_bin = tmp_path / "b.glb"
    no_bin.write_bytes(glb_bytes(doc, b""))
    assert read_glb(no_bin, "b.glb", [])[1] is None


def test_data_uris_and_uri_classification():
    from workers.gltf.container import climbs_out, decode_data_uri, split_uri

    payload = bytes(range(256))
    uri = "data:application/octet-stream;base64," + base64.b64encode(payload).decode()
    assert split_uri(uri, "buffer 0") == ("data", uri)
    assert decode_data_uri(uri, "buffer 0") == payload
    assert decode_data_uri("data:text/plain,a%20b", "buffer 0") == b"a b"  # not base64: percent-decoded
    with pytest.raises(IngestError) as info:
        decode_data_uri("data:application/octet-stream;base64", "buffer 0")
    assert info.value.code == "invalid_gltf" and "','" in info.value.message
    assert split_uri("tex/a%20b.png", "image 0") == ("file", "tex/a b.png")
    assert split_uri("tex\\a.png", "image 0") == ("file", "tex/a.png")
    for bad in ("http://x/a.bin", "file:///a.bin", "/abs/a.bin", "\\\\server\\a.bin", "%2Fabs.bin", "C:/a.bin"):
        with pytest.raises(IngestError) as info:
            split_uri(bad, "buffer 0")
        assert info.value.code == "external_uri"
    assert climbs_out("../a") and climbs_out("a/../../b") and not climbs_out("a/../b")


def test_json_depth_ignores_brackets_in_strings_and_integral_floats_are_ints():
    from workers.gltf.container import json_depth, parse_json

    assert json_depth(b'{"a": [[1], {"b": "[[[[{{"}]}') == 3
    assert json_depth(b"") == 0
    doc = parse_json(b'{"asset": {"version": "2.0"}, "n": 3.0, "x": 0.5, "big": 1e300}', IngestLimits(), "a.gltf")
    assert doc["n"] == 3 and isinstance(doc["n"], int) and doc["x"] == 0.5 and isinstance(doc["big"], float)
