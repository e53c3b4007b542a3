"""Tests for workers.gltf.errors: codes and statuses, messages without temporary paths or addresses."""

from __future__ import annotations

import tempfile

import pytest

from tests.workers.gltf.builders import png_bytes, write_glb, write_zip, minimal, LFS_POINTER
from workers.gltf import ERROR_CODES, IngestError, ingest_file


def test_new_codes_are_4xx():
    for code in ("absurd_magnitude", "negative_emissive", "negative_light", "zero_extent", "degenerate_triangles",
                 "text_buffer"):
        assert ERROR_CODES[code] == 422


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

    from workers.gltf.errors import scrub

    msg = scrub(f"cannot identify image file <_io.BytesIO object at 0x7f3a2b1c0d90> or "
                f"'{tempfile.gettempdir()}/kiln-ingest-abc123/member-00002'")
    assert " at 0x" not in msg and tempfile.gettempdir() not in msg and "kiln-ingest" not in msg


def test_err_takes_the_status_of_its_code_and_plural_words():
    from workers.gltf.errors import err, invalid, plural

    e = err("zip_bomb", "too big")
    assert (e.code, e.status, e.message, str(e)) == ("zip_bomb", 413, "too big", "zip_bomb: too big")
    assert invalid("bad").status == 422 and invalid("bad").code == "invalid_gltf"
    assert plural(1, "point primitive(s) ignored") == "1 point primitive ignored"
    assert plural(3, "point primitive(s) ignored") == "3 point primitives ignored"
