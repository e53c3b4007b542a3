"""Bundles (proto/bundle.py): artifacts, manifest, open from folder and zip, integrity, zip determinism."""
from __future__ import annotations

import hashlib
import json
import os
import zipfile

import numpy as np
import pytest

from proto.bundle import (
    DEFAULT_ZSTD_LEVEL,
    MANIFEST_NAME,
    BundleError,
    artifact_file_name,
    load_artifact,
    open_bundle,
    read_manifest,
    with_artifact,
    write_artifact,
    write_manifest,
    zip_bundle,
)
from proto.ktx2 import decode_ktx2
from proto.models import FORMAT_VERSION, ArtifactInfo, Manifest, SceneSummary


def _manifest(artifacts: list[ArtifactInfo]) -> Manifest:
    return Manifest(
        kiln_version="0.1.0",
        bake_id="b1",
        scene=SceneSummary(id="s" * 64, triangles=12, bounds=[[0, 0, 0], [1, 2, 3]], lights=1, materials=2),
        config={"seed": 0},
        grid={"origin": [0.0, 0.0, 0.0], "spacing": [0.5, 0.5, 0.5], "counts": [7, 5, 3]},
        artifacts=artifacts,
    )


@pytest.fixture
def arrays():
    rng = np.random.default_rng(7)
    return {
        "sh_l1": rng.standard_normal((3, 5, 7, 4)).astype(np.float16),  # (z, y, x, c) probe volume
        "masks": rng.integers(0, 256, (6, 10, 14, 4), dtype=np.uint8),
        "states": rng.integers(0, 3, (3, 5, 7), dtype=np.uint8),  # 1-channel volume, no channel axis
        "depth.atlas": rng.random((9, 11, 2), dtype=np.float32),
        "positions": rng.standard_normal((105, 3)),  # float64: npy
    }


@pytest.fixture
def bundle(tmp_path, arrays):
    d = tmp_path / "bundle"
    infos = [
        write_artifact(d, "sh_l1", arrays["sh_l1"], "light", zstd_level=5, description="L1 SH"),
        write_artifact(d, "masks", arrays["masks"], "masks", meta={"k": 4}, zstd_level=0),  # 0: uncompressed
        write_artifact(d, "states", arrays["states"], "probes", vk_format="R8_UINT", volume=True),
        write_artifact(d, "depth.atlas", arrays["depth.atlas"], "probes"),
        write_artifact(d, "positions", arrays["positions"], "probes", format="npy"),
        write_artifact(d, "metrics", {"rmse": {"mask": 0.0125, "leaking": np.float32(0.5)}, "n": np.int64(3)},
                       "evaluate", format="json"),
    ]
    write_manifest(d, _manifest(infos))
    return d, infos


def test_write_artifact_infos_exact(bundle, arrays):
    d, infos = bundle
    by = {i.name: i for i in infos}
    assert [i.file for i in infos] == ["sh_l1.ktx2", "masks.ktx2", "states.ktx2", "depth.atlas.ktx2",
                                       "positions.npy", "metrics.json"]
    for i in infos:
        data = (d / i.file).read_bytes()
        assert i.bytes == len(data) and i.sha256 == hashlib.sha256(data).hexdigest()
    assert by["sh_l1"].shape == [3, 5, 7, 4] and by["sh_l1"].dtype == "float16"
    assert by["sh_l1"].meta == {"ktx2": {"vk_format": 97, "format": "R16G16B16A16_SFLOAT",
                                          "supercompression": "zstd", "pixel_size": 8, "size": [7, 5, 3]}}
    assert by["sh_l1"].stage == "light" and by["sh_l1"].description == "L1 SH" and by["sh_l1"].format == "ktx2"
    assert by["masks"].meta == {"k": 4, "ktx2": {"vk_format": 37, "format": "R8G8B8A8_UNORM",
                                                 "supercompression": "none", "pixel_size": 4, "size": [14, 10, 6]}}
    assert by["states"].shape == [3, 5, 7] and by["states"].dtype == "uint8"
    assert by["states"].meta["ktx2"]["format"] == "R8_UINT" and by["states"].meta["ktx2"]["size"] == [7, 5, 3]
    assert by["depth.atlas"].meta["ktx2"]["size"] == [11, 9, 0]  # 2D: depth 0
    # Zstandard by default, at DEFAULT_ZSTD_LEVEL
    assert by["depth.atlas"].meta["ktx2"]["supercompression"] == "zstd"
    assert decode_ktx2((d / "depth.atlas.ktx2").read_bytes())[1]["kv"]["KTXwriterScParams"] == \
        f"--zstd {DEFAULT_ZSTD_LEVEL}"
    assert by["positions"].shape == [105, 3] and by["positions"].dtype == "float64"
    assert by["metrics"].shape == [] and by["metrics"].dtype == "dict" and by["metrics"].format == "json"
    assert json.loads((d / "metrics.json").read_text()) == {"n": 3, "rmse": {"leaking": 0.5, "mask": 0.0125}}
    # the texture really is a 3D volume with x = width
    _, info = decode_ktx2((d / "states.ktx2").read_bytes())
    assert (info["pixel_width"], info["pixel_height"], info["pixel_depth"]) == (7, 5, 3)
    assert sorted(p.name for p in d.iterdir()) == sorted([i.file for i in infos] + [MANIFEST_NAME])


def _check_loaded(manifest, loaded, arrays, infos):
    assert manifest == _manifest(infos)
    assert set(loaded) == {"sh_l1", "masks", "states", "depth.atlas", "positions", "metrics"}
    for name, a in arrays.items():
        b = loaded[name]
        assert b.shape == a.shape and b.dtype == a.dtype, name
        assert np.array_equal(b.view(np.uint8), a.view(np.uint8)), name  # bit-identical
    assert loaded["metrics"] == {"n": 3, "rmse": {"leaking": 0.5, "mask": 0.0125}}


def test_open_bundle_dir(bundle, arrays):
    d, infos = bundle
    manifest, loaded = open_bundle(d)
    _check_loaded(manifest, loaded, arrays, infos)
    assert read_manifest(d) == manifest
    assert manifest.format_version == FORMAT_VERSION
    assert manifest.grid["counts"] == [7, 5, 3]


def test_open_bundle_zip_and_determinism(bundle, arrays, tmp_path):
    d, infos = bundle
    (d / "stray.txt").write_text("not listed")  # not in the manifest: left out of the zip
    z1 = zip_bundle(d, tmp_path / "out" / "b1.zip")
    for p in d.iterdir():  # new mtimes must not change the zip
        os.utime(p, (1_700_000_000, 1_700_000_000))
    z2 = zip_bundle(d, tmp_path / "b2.zip")
    assert z1.read_bytes() == z2.read_bytes()
    with zipfile.ZipFile(z1) as zf:
        names = zf.namelist()
        assert names == sorted([i.file for i in infos] + [MANIFEST_NAME])
        assert all(zi.date_time == (1980, 1, 1, 0, 0, 0) for zi in zf.infolist())
        assert all((zi.external_attr >> 16) & 0o777 == 0o644 for zi in zf.infolist())
        assert zf.read("sh_l1.ktx2") == (d / "sh_l1.ktx2").read_bytes()
    manifest, loaded = open_bundle(z1)
    _check_loaded(manifest, loaded, arrays, infos)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["b1.zip"]  # no temp left


def test_zip_with_top_folder_opens(bundle, arrays, tmp_path):
    d, infos = bundle
    z = tmp_path / "nested.zip"
    with zipfile.ZipFile(z, "w") as zf:
        for p in sorted(d.iterdir()):
            zf.write(p, f"mybake/{p.name}")
    manifest, loaded = open_bundle(z)
    _check_loaded(manifest, loaded, arrays, infos)


def test_sha256_mismatch_raises(bundle, tmp_path):
    d, infos = bundle
    p = d / "masks.ktx2"
    data = bytearray(p.read_bytes())
    data[-1] ^= 1  # same size, one bit of texel data changed
    p.write_bytes(bytes(data))
    with pytest.raises(BundleError, match="masks.*sha256"):
        open_bundle(d)
    # the same tampering inside a zip
    z = tmp_path / "t.zip"
    with zipfile.ZipFile(z, "w") as zf:
        for q in sorted(d.iterdir()):
            zf.write(q, q.name)
    with pytest.raises(BundleError, match="sha256"):
        open_bundle(z)


def test_zip_bundle_refuses_tampered_folder(bundle, tmp_path):
    d, _ = bundle
    (d / "positions.npy").write_bytes((d / "positions.npy").read_bytes()[:-8])
    with pytest.raises(BundleError, match="positions.npy"):
        zip_bundle(d, tmp_path / "x.zip")
    assert not (tmp_path / "x.zip").exists()


def test_size_mismatch_and_missing_file_raise(bundle):
    d, _ = bundle
    (d / "metrics.json").write_bytes((d / "metrics.json").read_bytes() + b" ")
    with pytest.raises(BundleError, match="bytes, manifest says"):
        open_bundle(d)
    (d / "metrics.json").unlink()
    with pytest.raises(BundleError, match="missing file metrics.json"):
        open_bundle(d)


def test_bad_manifests_raise(bundle, tmp_path):
    d, infos = bundle
    m = json.loads((d / MANIFEST_NAME).read_text())
    bad = dict(m, artifacts=[dict(m["artifacts"][0], file="../evil.ktx2")])
    (d / MANIFEST_NAME).write_text(json.dumps(bad))
    with pytest.raises(BundleError, match="bad file name"):
        open_bundle(d)
    (d / MANIFEST_NAME).write_text(json.dumps(dict(m, format_version=FORMAT_VERSION + 1)))
    with pytest.raises(BundleError, match="newer"):
        open_bundle(d)
    (d / MANIFEST_NAME).write_text(json.dumps(dict(m, artifacts=m["artifacts"] * 2)))
    with pytest.raises(BundleError, match="twice"):
        open_bundle(d)
    (d / MANIFEST_NAME).write_text("{not json")
    with pytest.raises(BundleError, match="not valid JSON"):
        open_bundle(d)
    (d / MANIFEST_NAME).write_text(json.dumps({"kiln_version": "x"}))
    with pytest.raises(BundleError, match="schema"):
        open_bundle(d)
    with pytest.raises(BundleError, match="no such bundle"):
        open_bundle(tmp_path / "nope")
    (tmp_path / "junk.zip").write_bytes(b"PK not really")
    with pytest.raises(BundleError, match="not a bundle"):
        open_bundle(tmp_path / "junk.zip")
    with pytest.raises(ValueError, match="twice"):
        write_manifest(d, _manifest(infos + infos[:1]))


@pytest.mark.parametrize("name", ["", "A", "has space", "a/b", "../x", "x" * 65, ".hidden", "sh:l1", "é"])
def test_bad_artifact_names_rejected(tmp_path, name):
    with pytest.raises(ValueError, match="artifact name"):
        write_artifact(tmp_path, name, np.zeros((2, 2), np.float32), "light")
    assert list(tmp_path.iterdir()) == []


def test_good_names_and_reserved_manifest_name(tmp_path):
    assert artifact_file_name("x" * 64, "ktx2") == "x" * 64 + ".ktx2"
    assert artifact_file_name("mask-atlas_0.v2", "npy") == "mask-atlas_0.v2.npy"
    with pytest.raises(ValueError, match="overwrite manifest.json"):
        write_artifact(tmp_path, "manifest", {"a": 1}, "evaluate", format="json")
    with pytest.raises(ValueError, match="format"):
        artifact_file_name("a", "exr")


def test_artifact_value_errors(tmp_path):
    with pytest.raises(ValueError, match="non-finite"):
        write_artifact(tmp_path, "m", {"x": float("nan")}, "evaluate", format="json")
    with pytest.raises(ValueError, match="must be a dict"):
        write_artifact(tmp_path, "m", [1, 2], "evaluate", format="json")
    with pytest.raises(ValueError, match="object arrays"):
        write_artifact(tmp_path, "o", np.array([{}, 1], dtype=object), "x", format="npy")
    with pytest.raises(ValueError, match="ktx2 artifacts only"):
        write_artifact(tmp_path, "o", np.zeros(3), "x", format="npy", zstd_level=3)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("array, fmt", [
    (np.arange(7 * 3 * 2, dtype=np.float32).reshape(7, 3, 2) / 7, "R32_SFLOAT"),  # prt_lm_uv-like (T, 3, 2)
    (np.arange(-3, 9, dtype=np.int32), "R32_SINT"),                                # prt_point_offsets-like (M+1,)
    (np.arange(2 * 2 * 2 * 9 * 3, dtype=np.float32).reshape(2, 2, 2, 9, 3), "R32_SFLOAT"),  # probe_sh-like
    (np.array([[1, 2], [3, 4]], np.uint32), "R32_UINT"),
], ids=["rows-of-pairs", "int-1d", "probe-sh-5d", "uint"])
def test_tables_round_trip_as_one_channel_2d_ktx2(tmp_path, array, fmt):
    info = write_artifact(tmp_path, "t", array, "x", table=True)
    assert info.format == "ktx2" and info.shape == list(array.shape) and info.meta["ktx2"]["table"] is True
    assert info.meta["ktx2"]["format"] == fmt and info.meta["ktx2"]["supercompression"] == "zstd"
    tex, k = decode_ktx2((tmp_path / "t.ktx2").read_bytes())   # (rows, values per row, 1), 2D, level order = C order
    assert k["pixel_depth"] == 0 and tex.shape == (array.shape[0], int(np.prod(array.shape[1:])), 1)
    assert np.array_equal(tex.reshape(-1), array.reshape(-1))
    back = load_artifact(tmp_path / "t.ktx2", info)
    assert back.shape == array.shape and back.dtype == array.dtype and np.array_equal(back, array)
    # a manifest shape with another number of values is refused; without `table` a reshape is refused
    with pytest.raises(BundleError, match="does not fit manifest shape"):
        load_artifact(tmp_path / "t.ktx2", info.model_copy(update={"shape": [array.size + 1]}))
    plain = info.model_copy(update={"meta": {"ktx2": {k: v for k, v in info.meta["ktx2"].items() if k != "table"}}})
    if array.ndim != 2:
        with pytest.raises(BundleError, match="does not fit manifest shape"):
            load_artifact(tmp_path / "t.ktx2", plain)


def test_table_refuses_float64_and_npy_options(tmp_path):
    with pytest.raises(ValueError, match="no table format"):
        write_artifact(tmp_path, "t", np.zeros(3), "x", table=True)
    with pytest.raises(ValueError, match="ktx2 artifacts only"):
        write_artifact(tmp_path, "t", np.zeros(3, np.float32), "x", format="npy", table=True)
    assert list(tmp_path.iterdir()) == []


def test_load_artifact_from_path_and_bytes(bundle, arrays):
    d, infos = bundle
    info = next(i for i in infos if i.name == "states")
    for src in (d / info.file, str(d / info.file), (d / info.file).read_bytes()):
        a = load_artifact(src, info)
        assert a.shape == (3, 5, 7) and np.array_equal(a, arrays["states"])
    wrong = info.model_copy(update={"shape": [5, 3, 7]})
    with pytest.raises(BundleError, match="does not fit manifest shape"):
        load_artifact(d / info.file, wrong)
    wrong = info.model_copy(update={"dtype": "int8"})
    with pytest.raises(BundleError, match="dtype"):
        load_artifact(d / info.file, wrong)
    other = next(i for i in infos if i.name == "masks")
    with pytest.raises(BundleError, match="sha256|bytes"):
        load_artifact(d / info.file, other)


def test_rewrite_replaces_and_with_artifact(bundle, arrays):
    d, infos = bundle
    m = _manifest(infos)
    new = write_artifact(d, "masks", arrays["masks"][::-1].copy(), "masks", zstd_level=3)
    m2 = with_artifact(m, new)
    assert [a.name for a in m2.artifacts] == [a.name for a in m.artifacts]
    assert m2.artifact("masks").sha256 == new.sha256 != m.artifact("masks").sha256
    extra = write_artifact(d, "extra", np.arange(4, dtype=np.int32), "x", format="npy")
    m3 = with_artifact(m2, extra)
    assert [a.name for a in m3.artifacts][-1] == "extra" and len(m.artifacts) == 6
    write_manifest(d, m3)
    manifest, loaded = open_bundle(d)
    assert np.array_equal(loaded["masks"], arrays["masks"][::-1]) and loaded["extra"].tolist() == [0, 1, 2, 3]
    assert not [p for p in d.iterdir() if p.name.startswith(".")]  # no temp files left


def test_png_artifact_loads_as_bytes(tmp_path):
    png = b"\x89PNG\r\n\x1a\n" + b"\0" * 8
    (tmp_path / "preview.png").write_bytes(png)
    info = ArtifactInfo(name="preview", file="preview.png", format="png", shape=[1, 1, 3], dtype="uint8",
                        bytes=len(png), sha256=hashlib.sha256(png).hexdigest(), stage="evaluate")
    write_manifest(tmp_path, _manifest([info]))
    _, loaded = open_bundle(tmp_path)
    assert loaded["preview"].tobytes() == png


def test_manifest_json_is_stable(bundle):
    d, infos = bundle
    text = (d / MANIFEST_NAME).read_text()
    assert text.endswith("\n") and json.loads(text)["artifacts"][0]["file"] == "sh_l1.ktx2"
    write_manifest(d, _manifest(infos))
    assert (d / MANIFEST_NAME).read_text() == text
