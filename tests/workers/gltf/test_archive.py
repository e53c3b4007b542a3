"""Tests for workers.gltf.archive: zip uploads (member names, bombs, extraction, URI resolution)."""

from __future__ import annotations

import copy
import json
import os
import struct
import tempfile
import unicodedata
import urllib.parse
import zipfile
from pathlib import Path

import pytest

from tests.workers.gltf.builders import write_zip, sample_scene, expect_error, minimal
from workers.gltf import IngestLimits, ingest_file


def test_percent_encoded_uris_resolve_in_zip(tmp_path):
    g = sample_scene()
    s = ingest_file(
        write_zip(tmp_path / "s.zip", g, bin_name="bin files/scène 1.bin", image_names=["textures/cement lossy.png"])
    )
    assert s.n_triangles == 5 and len(s.textures) == 1


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


@pytest.mark.parametrize("member", ["../evil.bin", "a/../../evil.bin", "/abs/evil.bin", "C:/evil.bin", "..\\evil.bin"])
def test_path_traversal_in_zip_members(tmp_path, member):
    write_zip(tmp_path / "a.zip", minimal(), extra={member: b"x"})
    expect_error("path_traversal", tmp_path / "a.zip")


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
