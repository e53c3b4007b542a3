"""Hostile and garbage scenes refused at upload with a code (issue 15, Build 6), valid input that used to be
refused (Build 11), and messages free of temporary paths and object addresses (Build 9).

Each case builds the exact file it needs (tests/workers/test_ingest.py's builders) and asserts the code and
its 4xx status from ``workers.ingest.ERROR_CODES``.
"""
from __future__ import annotations

import copy
import json
import struct
import unicodedata
import urllib.parse
import zipfile

import numpy as np
import pytest

from tests.workers.test_ingest import QUAD, Gltf, expect_error, minimal, png_bytes, write_glb, write_gltf, write_zip
from workers.ingest import ERROR_CODES, MAX_COORD, IngestError, ingest_file

LFS_POINTER = (b"version https://git-lfs.github.com/spec/v1\n"
               b"oid sha256:4d7a214614ab2935c943f9e0ff69d22eadbb8f32b1258daaa5e2ca24d17e2393\n"
               b"size 12345\n")


def test_new_codes_are_4xx():
    for code in ("absurd_magnitude", "negative_emissive", "negative_light", "zero_extent", "degenerate_triangles",
                 "text_buffer"):
        assert ERROR_CODES[code] == 422


# ---------------------------------------------------------------------------------------------- magnitudes


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


# ---------------------------------------------------------------------------------------------- extent


def test_zero_extent(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(np.full((4, 3), 0.5, np.float32), [0, 1, 2, 0, 2, 3]))  # distinct indices, one point
    expect_error("zero_extent", write_glb(tmp_path / "a.glb", g), contains="one point")


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


# ---------------------------------------------------------------------------------------------- text as data


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


# ---------------------------------------------------------------------------------------------- valid input


@pytest.mark.parametrize("uri, member", [
    ("textures/../data/scene.bin", "model/data/scene.bin"),     # '..' inside the model's folder
    ("data/./x/../scene.bin", "model/data/scene.bin"),
    ("../shared/scene.bin", "shared/scene.bin"),                # up to the zip's root: still inside the upload
    ("data/scene.bin", "model/data/x/../scene.bin"),            # a member name with '..' that stays inside
])
def test_dotdot_inside_the_zip_is_accepted(tmp_path, uri, member):
    g = minimal()
    doc = copy.deepcopy(g.doc)
    doc["buffers"] = [{"byteLength": len(g.bin), "uri": urllib.parse.quote(uri)}]
    with zipfile.ZipFile(tmp_path / "a.zip", "w") as z:
        z.writestr("model/scene.gltf", json.dumps(doc))
        z.writestr(member, bytes(g.bin))
    assert ingest_file(tmp_path / "a.zip").triangles.shape[0] == 2


def _unicode_zip(path, g, uri_name, member_name):
    doc = copy.deepcopy(g.doc)
    doc["buffers"] = [{"byteLength": len(g.bin), "uri": urllib.parse.quote(uri_name)}]
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("scene.gltf", json.dumps(doc, ensure_ascii=False))
        z.writestr(member_name, bytes(g.bin))
    return path


@pytest.mark.parametrize("uri_form, member_form", [("NFC", "NFD"), ("NFD", "NFC")])
def test_unicode_normalization_of_names(tmp_path, uri_form, member_form):
    name = "Café Kühl/naïve.bin"
    uri, member = unicodedata.normalize(uri_form, name), unicodedata.normalize(member_form, name)
    assert uri != member
    s = ingest_file(_unicode_zip(tmp_path / "a.zip", minimal(), uri, member))
    assert s.triangles.shape[0] == 2 and not any("case" in w for w in s.warnings)


def test_utf8_member_names_without_the_utf8_flag(tmp_path):
    """Archivers that write UTF-8 names without setting flag bit 11 (zipfile would read them as cp437)."""
    path = _unicode_zip(tmp_path / "a.zip", minimal(), "naïve.bin", "naïve.bin")
    data = bytearray(path.read_bytes())
    for sig, flag_at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        pos = data.find(sig)
        while pos != -1:
            flags = struct.unpack_from("<H", data, pos + flag_at)[0]
            struct.pack_into("<H", data, pos + flag_at, flags & ~0x800)
            pos = data.find(sig, pos + 4)
    path.write_bytes(bytes(data))
    with zipfile.ZipFile(path) as z:
        assert "naïve.bin" not in z.namelist()  # zipfile alone reads mojibake
    assert ingest_file(path).triangles.shape[0] == 2


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


# ---------------------------------------------------------------------------------------------- messages


def _bad_image_glb(tmp_path):
    g = minimal()
    tex = g.image(b"\x89PNG but not really an image" * 4)
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}}]
    g.doc["meshes"][0]["primitives"][0]["material"] = 0
    return write_glb(tmp_path / "a.glb", g)


def _bad_image_zip(tmp_path):
    g = minimal()
    g.image(png_bytes())
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    g.doc["meshes"][0]["primitives"][0]["material"] = 0
    write_zip(tmp_path / "b.zip", g, image_names=["tex/a.png"], skip=("tex/a.png",),
              extra={"model/tex/a.png": b"GIF89a not a png at all" * 8})
    return tmp_path / "b.zip"


def _lfs_image_zip(tmp_path):
    g = minimal()
    g.image(png_bytes())
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    g.doc["meshes"][0]["primitives"][0]["material"] = 0
    write_zip(tmp_path / "c.zip", g, image_names=["tex/a.png"], skip=("tex/a.png",),
              extra={"model/tex/a.png": LFS_POINTER})
    return tmp_path / "c.zip"


@pytest.mark.parametrize("make, code", [(_bad_image_glb, "invalid_image"), (_bad_image_zip, "invalid_image"),
                                        (_lfs_image_zip, "invalid_image")])
def test_messages_carry_no_temp_paths_or_addresses(tmp_path, make, code):
    path = make(tmp_path)
    with pytest.raises(IngestError) as info:
        ingest_file(path, filename="scene.upload")
    err = info.value
    assert err.code == code, err.message
    for text in (err.message, str(err)):
        assert "/tmp" not in text and " at 0x" not in text and str(tmp_path) not in text, text
    if make is _lfs_image_zip:
        assert "Git LFS" in err.message


def test_scrub_removes_reprs_and_temp_paths():
    import tempfile

    from workers.ingest import _scrub

    msg = _scrub(f"cannot identify image file <_io.BytesIO object at 0x7f3a2b1c0d90> or "
                 f"'{tempfile.gettempdir()}/kiln-ingest-abc123/member-00002'")
    assert " at 0x" not in msg and tempfile.gettempdir() not in msg and "kiln-ingest" not in msg
