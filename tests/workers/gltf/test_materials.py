"""Tests for workers.gltf.materials: materials, textures and their UV sets, images."""

from __future__ import annotations

import io
import math

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.workers.gltf.builders import (
    Gltf, png_bytes, png_header_only, write_glb, write_zip, QUAD, QUAD_UV, sample_scene, expect_error,
)
from workers.gltf import IngestLimits, ingest_file


def test_webp_textures_decode(tmp_path):
    buf = io.BytesIO()
    Image.new("RGB", (8, 4), (10, 200, 30)).save(buf, "WEBP", lossless=True)
    g = sample_scene()
    g.images[0] = buf.getvalue()
    g.doc["textures"][0] = {"extensions": {"EXT_texture_webp": {"source": 0}}}
    g.doc["extensionsUsed"].append("EXT_texture_webp")
    g.doc["extensionsRequired"] = ["EXT_texture_webp"]
    s = ingest_file(write_zip(tmp_path / "s.zip", g, image_names=["textures/a%20b.webp"]))
    assert s.textures[0].shape == (4, 8, 4)
    assert s.textures[0][0, 0].tolist() == [10, 200, 30, 255]


KTX2_DIR = Path(__file__).resolve().parents[2] / "data" / "ktx2"


def _ktx2_scene(name: str, fallback: bytes | None = None) -> Gltf:
    """sample_scene with its texture a KHR_texture_basisu KTX2 (tests/data/ktx2), optionally a PNG fallback."""
    g = sample_scene()
    g.images[0] = (KTX2_DIR / name).read_bytes()
    tex = {"extensions": {"KHR_texture_basisu": {"source": 0}}}
    if fallback is not None:
        g.images.append(fallback)
        tex["source"] = 1
    else:
        g.doc["extensionsRequired"] = ["KHR_texture_basisu"]
    g.doc["textures"][0] = tex
    g.doc["extensionsUsed"].append("KHR_texture_basisu")
    return g


@pytest.mark.parametrize("name, tol", [("quadrants-etc1s.ktx2", 4), ("quadrants-uastc-zstd.ktx2", 1)])
def test_ktx2_basisu_textures_decode(tmp_path, name, tol):
    # ETC1S (BasisLZ) and UASTC (Zstandard), both with mipmaps: level 0 is the picture encoded, top row first,
    # within the codec's error; as a GLB buffer view and as a file beside a .gltf
    from tests.data.ktx2.make_fixtures import quadrants

    g = _ktx2_scene(name)
    for path in (write_glb(tmp_path / "s.glb", g), write_zip(tmp_path / "s.zip", g, image_names=["t/a b.ktx2"])):
        s = ingest_file(path)
        assert s.textures[0].shape == (16, 16, 4) and s.textures[0].dtype == np.uint8
        assert np.abs(s.textures[0].astype(int) - quadrants()).max() <= tol
        assert not any("basisu" in w for w in s.warnings), s.warnings


def test_ktx2_source_is_preferred_to_the_fallback(tmp_path):
    # what an engine reading the extension shows; without the extension the fallback is read
    g = _ktx2_scene("quadrants-uastc-zstd.ktx2", fallback=png_bytes(4, 2, (0, 0, 0, 255)))
    assert ingest_file(write_glb(tmp_path / "a.glb", g)).textures[0].shape == (16, 16, 4)
    del g.doc["textures"][0]["extensions"]
    assert ingest_file(write_glb(tmp_path / "b.glb", g)).textures[0].shape == (2, 4, 4)


def test_ktx2_limits_and_bad_files(tmp_path):
    g = _ktx2_scene("quadrants-etc1s.ktx2")
    e = expect_error("image_too_large", write_glb(tmp_path / "big.glb", g), IngestLimits(max_image_pixels=16 * 15))
    assert "16x16" in e.message  # from the header, before transcoding
    good = (KTX2_DIR / "quadrants-etc1s.ktx2").read_bytes()
    g.images[0] = good[:12] + b"\0" * 100  # the magic, then nothing a transcoder reads
    assert "KTX2" in expect_error("invalid_image", write_glb(tmp_path / "junk.glb", g)).message
    g.images[0] = good[:12] + (37).to_bytes(4, "little") + good[16:]  # vkFormat R8G8B8A8_UNORM: no Basis payload
    expect_error("invalid_image", write_glb(tmp_path / "raw.glb", g))
    g.images[0] = good[: len(good) // 2]  # truncated: its levels lie past the end
    expect_error("invalid_image", write_glb(tmp_path / "cut.glb", g))


def test_texture_transform_and_texcoord_choice(tmp_path):
    g = Gltf()
    tex = g.image(png_bytes())
    g.doc["materials"] = [
        {
            "pbrMetallicRoughness": {
                "baseColorTexture": {
                    "index": tex,
                    "texCoord": 1,
                    "extensions": {
                        "KHR_texture_transform": {"offset": [0.5, 0.25], "scale": [2, 3], "rotation": math.pi / 2}
                    },
                }
            }
        }
    ]
    g.doc["extensionsUsed"] = ["KHR_texture_transform"]
    g.node(mesh=g.mesh(QUAD[:3], material=0, TEXCOORD_0=np.zeros((3, 2)), TEXCOORD_1=QUAD_UV[:3]))
    s = ingest_file(write_glb(tmp_path / "t.glb", g))
    uv = QUAD_UV[:3].astype(np.float64) * [2, 3]
    c, sn = 0.0, 1.0  # cos, sin of pi/2: u' = c u + s v, v' = -s u + c v (sample viewer / three.js)
    expected = np.stack([c * uv[:, 0] + sn * uv[:, 1], -sn * uv[:, 0] + c * uv[:, 1]], 1) + [0.5, 0.25]
    np.testing.assert_allclose(s.uv0[0], expected, atol=1e-6)
    assert any("uv0 holds TEXCOORD_1" in w for w in s.warnings)


def test_textures_are_deduplicated_per_image(tmp_path):
    g = Gltf()
    t0 = g.image(png_bytes(color=(1, 1, 1, 255)))
    t1 = g.image(png_bytes(color=(9, 9, 9, 255)))
    g.doc["textures"].append({"source": 0})  # a third texture reusing image 0
    g.doc["materials"] = [
        {"pbrMetallicRoughness": {"baseColorTexture": {"index": t1}}},
        {
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 2}},
            "emissiveTexture": {"index": t0},
            "emissiveFactor": [1, 1, 1],
        },
    ]
    g.node(mesh=g.mesh(QUAD[:3], material=1, TEXCOORD_0=QUAD_UV[:3]))
    s = ingest_file(write_glb(tmp_path / "t.glb", g))
    assert len(s.textures) == 2
    assert s.materials[0]["base_color_texture"] == 0 and s.textures[0][1, 1, 0] == 9
    assert s.materials[1]["base_color_texture"] == 1 and s.materials[1]["emissive_texture"] == 1
    assert s.textures[1][1, 1, 0] == 1


def test_material_details(tmp_path):
    g = Gltf()
    g.doc["materials"] = [
        {"name": "sg", "extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0.1, 0.2, 0.3, 1]}}},
        {"alphaMode": "MASK"},
    ]
    g.doc["extensionsRequired"] = g.doc["extensionsUsed"] = ["KHR_materials_pbrSpecularGlossiness"]
    g.node(mesh=g.mesh(QUAD[:3], material=0))
    g.node(mesh=g.mesh(QUAD[:3], material=1, COLOR_0=np.ones((3, 4))))
    s = ingest_file(write_glb(tmp_path / "m.glb", g))
    assert s.materials[0]["base_color"] == [0.1, 0.2, 0.3, 1] and s.materials[0]["name"] == "sg"
    assert s.materials[1] == {
        "name": "material_1",
        "base_color": [1, 1, 1, 1],
        "base_color_texture": None,
        "emissive": [0, 0, 0],
        "emissive_texture": None,
        "double_sided": False,
        "metallic": 1.0,                      # glTF's defaults: metallicFactor 1, roughnessFactor 1
        "roughness": 1.0,
        "metallic_roughness_texture": None,
        "alpha_mode": "MASK",                 # a cutout for every ray (workers.raycast.cutout)
        "alpha_cutoff": 0.5,
    }
    assert s.materials[0]["metallic"] == 0.0  # specular-glossiness: the diffuse factor is the albedo
    assert not any("MASK" in w for w in s.warnings)
    np.testing.assert_array_equal(s.colors[1], 1.0)   # COLOR_0 kept (RGBA, per corner)


def test_image_too_large_is_checked_from_the_header(tmp_path):
    for w, h in [(9000, 9000), (100_000, 100_000)]:  # below and above PIL's own bomb threshold
        g = sample_scene()
        g.images[0] = png_header_only(w, h)
        expect_error("image_too_large", write_glb(tmp_path / f"{w}.glb", g))
    g = sample_scene()
    g.images[0] = png_bytes(64, 64)
    expect_error("image_too_large", write_glb(tmp_path / "small.glb", g), IngestLimits(max_image_pixels=64 * 63))


def test_invalid_image(tmp_path):
    g = sample_scene()
    g.images[0] = b"\x89PNG\r\n\x1a\nthis is not a png"
    expect_error("invalid_image", write_glb(tmp_path / "a.glb", g))
    g.images[0] = b"GIF89a" + bytes(30)
    expect_error("invalid_image", write_glb(tmp_path / "b.glb", g))


# ---------------------------------------------------------------------------------------------- unit: UV transforms


def test_texture_transform_matrix_is_translation_rotation_scale():
    from workers.gltf.materials import same_transform, texture_transform_matrix

    m = texture_transform_matrix({"offset": [0.5, 0.25], "rotation": math.pi / 2, "scale": [2, 1]}, "m")
    # u' = cos r * su + sin r * v, v' = -sin r * su + cos r * v, then the offset
    assert np.allclose(m @ [1, 0, 1], [0.5, -1.75]) and np.allclose(m @ [0, 1, 1], [1.5, 0.25])
    assert np.allclose(texture_transform_matrix({}, "m"), [[1, 0, 0], [0, 1, 0]])
    assert same_transform(None, None) and not same_transform(m, None) and same_transform(m, m.copy())


def test_transmissive_glass_is_named_in_its_own_warning(tmp_path):
    """KHR_materials_transmission is not honoured (the glass blocks light, as in the Cycles Lambert reference): the
    warning names the materials and says so, instead of a bare "extensions ignored"; a factor of 0 is no glass."""
    g = Gltf()
    glass = {"KHR_materials_transmission": {"transmissionFactor": 1.0}}
    g.doc["materials"] = [{"name": "window", "extensions": glass},
                          {"name": "frosted", "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.4},
                                                             "KHR_materials_volume": {"thicknessFactor": 0.01}}},
                          {"name": "off", "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0}}},
                          {"name": "odd", "extensions": {"KHR_materials_transmission": {"transmissionFactor": "x"}}}]
    g.doc["extensionsUsed"] = ["KHR_materials_transmission", "KHR_materials_volume", "EXT_foo"]
    for i in range(4):
        g.node(mesh=g.mesh(QUAD[:3], material=i))
    s = ingest_file(write_glb(tmp_path / "g.glb", g))
    glassy = [w for w in s.warnings if "KHR_materials_transmission" in w]
    assert len(glassy) == 1 and "2 materials ('window', 'frosted')" in glassy[0], s.warnings
    assert "opaque" in glassy[0] and "alphaMode MASK" in glassy[0]
    assert "extensions ignored: EXT_foo" in s.warnings        # the others are still listed
    # no transmissive material (a factor of 0, a factor that is not a number): nothing said about glass
    h = Gltf()
    h.doc["materials"] = g.doc["materials"][2:]
    h.doc["extensionsUsed"] = ["KHR_materials_transmission"]
    h.node(mesh=h.mesh(QUAD[:3], material=0))
    h.node(mesh=h.mesh(QUAD[:3], material=1))
    s = ingest_file(write_glb(tmp_path / "h.glb", h))
    assert not any("KHR_materials_transmission" in w for w in s.warnings), s.warnings
    # required, it is still refused (the bake cannot honour it)
    g.doc["extensionsRequired"] = ["KHR_materials_transmission"]
    expect_error("unsupported_extension", write_glb(tmp_path / "r.glb", g))


def test_unlit_primitives_are_left_out_of_the_bake(tmp_path):
    """KHR_materials_unlit (a sky dome, a background, a baked-lighting mesh): an engine draws it without lighting and
    Blender's importer makes it transparent to every ray but the camera's, so the Cycles oracle's light passes through
    it. Kept in, a sky dome around a level blocked the config's sky and sun and became the scene's bounds. The bake
    leaves unlit primitives out (named in a warning), unless every primitive is unlit; required, it is honoured."""
    g = Gltf()
    g.doc["materials"] = [{"name": "floor"},
                          {"name": "SkyDome", "extensions": {"KHR_materials_unlit": {}},
                           "pbrMetallicRoughness": {"baseColorFactor": [0.4, 0.6, 1.0, 1.0], "metallicFactor": 0}}]
    g.doc["extensionsUsed"] = ["KHR_materials_unlit"]
    g.node(mesh=g.mesh(QUAD[:3], material=0))
    g.node(mesh=g.mesh(QUAD * 1000.0 - 500.0, np.array([0, 1, 2, 0, 2, 3], np.uint32), material=1))
    s = ingest_file(write_glb(tmp_path / "dome.glb", g))
    assert s.triangles.shape[0] == 1 and set(np.asarray(s.material).tolist()) == {0}
    assert float(np.abs(s.triangles).max()) <= 1.0                     # the dome is not the scene's bounds
    said = [w for w in s.warnings if "KHR_materials_unlit" in w]
    assert len(said) == 1 and "2 primitives" not in said[0] and "'SkyDome'" in said[0] and "scene.sky" in said[0]
    assert not any(w.startswith("extensions ignored") for w in s.warnings), s.warnings
    assert s.materials[1].get("unlit") is True and not s.materials[0].get("unlit")
    g.doc["extensionsRequired"] = ["KHR_materials_unlit"]                 # required: honoured, not refused
    assert ingest_file(write_glb(tmp_path / "req.glb", g)).triangles.shape[0] == 1
    # every primitive unlit (a scan with its lighting in the texture): kept, as diffuse surfaces, and said so
    h = Gltf()
    h.doc["materials"] = g.doc["materials"][1:]
    h.doc["extensionsUsed"] = ["KHR_materials_unlit"]
    h.node(mesh=h.mesh(QUAD[:3], material=0))
    s = ingest_file(write_glb(tmp_path / "scan.glb", h))
    assert s.triangles.shape[0] == 1
    assert any("every primitive is unlit" in w for w in s.warnings), s.warnings
    # a material index that is not an integer: refused with a sentence, not a crash, unlit materials or not
    h.doc["meshes"][0]["primitives"][0]["material"] = [0]
    expect_error("invalid_gltf", write_glb(tmp_path / "bad.glb", h))
