"""A model on disk with the files it references packed into one upload (workers/gltf/pack.py): what `kiln bake
scene.gltf` reads and sends."""
from __future__ import annotations

import json
import struct
import zipfile

import numpy as np
import pytest

from workers.gltf import IngestError, ingest_file
from workers.gltf.pack import MissingFile, embed_glb, pack_model, referenced_files


def _split_glb(glb: bytes) -> tuple[dict, bytes]:
    """(JSON, BIN chunk) of a GLB."""
    n = struct.unpack_from("<I", glb, 12)[0]
    doc = json.loads(glb[20:20 + n])
    m = struct.unpack_from("<I", glb, 20 + n)[0]
    return doc, glb[28 + n:28 + n + m]


@pytest.fixture
def loose_gltf(tmp_path, scene_files):
    """sealed-box as a .gltf whose buffer lies in a sub-folder with a space in its name (percent-encoded URI)."""
    doc, bin_chunk = _split_glb(scene_files["sealed-box"].read_bytes())
    (tmp_path / "data dir").mkdir()
    (tmp_path / "data dir" / "box bin.bin").write_bytes(bin_chunk)
    doc["buffers"] = [{"uri": "data%20dir/box%20bin.bin", "byteLength": len(bin_chunk)}]
    (tmp_path / "box.gltf").write_text(json.dumps(doc))
    return tmp_path / "box.gltf"


def test_a_loose_gltf_packs_and_reads_like_its_glb(tmp_path, loose_gltf, scene_files):
    assert referenced_files(loose_gltf) == [("data dir/box bin.bin", "buffer 0")]
    with pytest.raises(IngestError) as e:              # alone it cannot be read: nothing beside it was uploaded
        ingest_file(loose_gltf)
    assert e.value.code == "missing_resource"
    out = tmp_path / "box.zip"
    assert pack_model(loose_gltf, out)
    assert sorted(zipfile.ZipFile(out).namelist()) == ["box.gltf", "data dir/box bin.bin"]
    got, want = ingest_file(out), ingest_file(scene_files["sealed-box"])
    assert np.array_equal(got.triangles, want.triangles) and got.n_triangles == want.n_triangles > 0


def test_embedded_models_are_not_packed_and_bad_uris_are_left_to_the_reader(tmp_path, scene_files):
    assert not pack_model(scene_files["sealed-box"], tmp_path / "x.zip") and not (tmp_path / "x.zip").exists()
    doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": "../outside.bin", "byteLength": 4},
                                                   {"uri": "https://example.com/a.bin", "byteLength": 4},
                                                   {"uri": "data:application/octet-stream;base64,AAAAAA==",
                                                    "byteLength": 4}],
           "images": [{"uri": "/etc/passwd"}]}
    (tmp_path / "bad.gltf").write_text(json.dumps(doc))
    assert referenced_files(tmp_path / "bad.gltf") == []          # nothing outside the folder is ever read
    (tmp_path / "gone.gltf").write_text(json.dumps({"asset": {"version": "2.0"}, "images": [{"uri": "t.png"}]}))
    with pytest.raises(MissingFile, match="image 0 't.png' does not exist"):
        pack_model(tmp_path / "gone.gltf", tmp_path / "g.zip")
    (tmp_path / "junk.gltf").write_text("{not json")
    assert referenced_files(tmp_path / "junk.gltf") == []


def test_embed_glb_makes_one_deterministic_glb_of_the_same_scene(tmp_path, loose_gltf, scene_files):
    """A .gltf with its buffer (in a percent-encoded sub-folder) and an image beside it becomes one GLB that reads
    as the same scene as the original GLB, byte-identical on every call; the image's file becomes a bufferView."""
    doc = json.loads(loose_gltf.read_text())
    png = b"\x89PNG\r\n\x1a\n" + bytes(range(37))              # never decoded: no texture refers to it
    (tmp_path / "tex.png").write_bytes(png)
    doc["images"] = [{"uri": "tex.png"}]
    loose_gltf.write_text(json.dumps(doc))
    glb = embed_glb(loose_gltf)
    assert glb == embed_glb(loose_gltf) and glb[:4] == b"glTF"
    out, blob = _split_glb(glb)
    assert "uri" not in out["buffers"][0] and out["buffers"][0]["byteLength"] == len(blob)
    img = out["images"][0]
    assert img["mimeType"] == "image/png" and "uri" not in img
    view = out["bufferViews"][img["bufferView"]]
    assert blob[view["byteOffset"]:view["byteOffset"] + view["byteLength"]] == png
    (tmp_path / "one.glb").write_bytes(glb)
    got, want = ingest_file(tmp_path / "one.glb"), ingest_file(scene_files["sealed-box"])
    assert np.array_equal(got.triangles, want.triangles) and got.n_triangles == want.n_triangles > 0
    assert got.materials == want.materials
    assert embed_glb(scene_files["sealed-box"]) == scene_files["sealed-box"].read_bytes()   # a GLB: as it is


def test_embed_glb_refuses_what_it_cannot_read(tmp_path):
    for uri in ("../outside.bin", "https://example.com/a.bin", "/etc/passwd"):
        (tmp_path / "bad.gltf").write_text(json.dumps({"asset": {"version": "2.0"},
                                                       "buffers": [{"uri": uri, "byteLength": 4}]}))
        with pytest.raises(ValueError, match="not a relative path"):
            embed_glb(tmp_path / "bad.gltf")
    (tmp_path / "gone.gltf").write_text(json.dumps({"asset": {"version": "2.0"},
                                                    "buffers": [{"uri": "b.bin", "byteLength": 4}]}))
    with pytest.raises(MissingFile, match="buffer 0 'b.bin' does not exist"):
        embed_glb(tmp_path / "gone.gltf")
    (tmp_path / "b.bin").write_bytes(b"12")
    with pytest.raises(ValueError, match="has 2 bytes, byteLength says 4"):
        embed_glb(tmp_path / "gone.gltf")
