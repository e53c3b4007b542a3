"""Compressed glTF geometry through workers.gltf: KHR_draco_mesh_compression and
EXT_meshopt_compression / KHR_meshopt_compression (decoders in workers.gltf.compression).

Every compressed file is made here from an uncompressed one with the libraries' own encoders
(DracoPy.encode per primitive; meshopt's encode_gltf_buffer per bufferView, with a fallback buffer that
holds no data), then ingested and compared triangle by triangle with the uncompressed original: exactly
for meshopt, within the quantization error for Draco (which reorders points and faces, so triangles are
matched by centroid and facing). A gltfpack-style KHR_mesh_quantization variant (int16 normalized
positions under a dequantizing node scale, octahedral-filtered int8 normals, uint16 UVs) is compared
exactly with the same quantized file uncompressed. Corrupt data must give IngestError invalid_gltf.
"""

from __future__ import annotations

import base64
import copy
import json
import math
import struct
from pathlib import Path

import DracoPy
import meshopt
import numpy as np
import pytest
from scipy.spatial import cKDTree

from workers.gltf import ERROR_CODES, IngestError, IngestLimits, ingest_file
from workers.gltf import compression as gc
from workers.procedural import make_scene

DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
COMPONENT = {np.dtype(v): k for k, v in DTYPES.items()}
NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
TYPE = {v: k for k, v in NCOMP.items()}
DRACO_SEMANTIC = {0: "POSITION", 1: "NORMAL", 2: "COLOR_0", 3: "TEXCOORD_0"}  # draco attribute type -> glTF
DRACO_BITS = 14


# ---------------------------------------------------------------------------------------------- GLB


def parse_glb(data: bytes) -> tuple[dict, bytes]:
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + jlen])
    bin_ = b""
    if len(data) > 20 + jlen:
        blen = struct.unpack_from("<I", data, 20 + jlen)[0]
        bin_ = data[28 + jlen : 28 + jlen + blen]
    return doc, bin_


def glb(doc: dict, bin_: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    bin_ = bytes(bin_) + b"\0" * (-len(bin_) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    if bin_:
        body += struct.pack("<II", len(bin_), 0x004E4942) + bin_
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def read_accessor(doc: dict, bin_: bytes, i: int) -> np.ndarray:
    """(count, n) values of a plain (non-sparse) accessor."""
    acc = doc["accessors"][i]
    view = doc["bufferViews"][acc["bufferView"]]
    dt = np.dtype(DTYPES[acc["componentType"]])
    n = NCOMP[acc["type"]]
    stride = view.get("byteStride", dt.itemsize * n)
    off = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.ndarray((acc["count"], n), dt, buffer=bin_, offset=off, strides=(stride, dt.itemsize)).copy()


class Blob:
    """A growing binary buffer with its bufferViews and accessors."""

    def __init__(self, doc: dict):
        self.doc = doc
        self.data = bytearray()
        doc["bufferViews"], doc["accessors"] = [], []

    def view(self, raw: bytes, **kw) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw), **kw})
        self.data += raw
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, arr: np.ndarray | None, *, count=None, component=None, type_=None, stride=None, **kw) -> int:
        """An accessor of ``arr`` ((n, k)); ``arr`` None: no bufferView (Draco); ``stride`` pads rows."""
        if arr is not None:
            arr = np.ascontiguousarray(arr)
            arr = arr.reshape(len(arr), -1)
            component = COMPONENT[arr.dtype] if component is None else component
            type_ = TYPE[arr.shape[1]] if type_ is None else type_
            count = len(arr)
            rows = arr
            view_kw = {}
            if stride is not None:
                rows = np.zeros((len(arr), stride), np.uint8)
                rows[:, : arr.itemsize * arr.shape[1]] = arr.view(np.uint8).reshape(len(arr), -1)
                view_kw["byteStride"] = stride
            kw["bufferView"] = self.view(rows.tobytes(), **view_kw)
        self.doc["accessors"].append({"componentType": component, "count": int(count), "type": type_, **kw})
        return len(self.doc["accessors"]) - 1

    def finish(self) -> bytes:
        self.doc["buffers"] = [{"byteLength": len(self.data)}]
        return glb(self.doc, bytes(self.data))


# ---------------------------------------------------------------------------------------------- scenes


def _cube():
    pos, nrm, uv = [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = np.roll(np.eye(3), 1, 0)[axis], np.roll(np.eye(3), 2, 0)[axis]
            if sign < 0:
                u = -u
            c = 0.5 * n
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                pos.append(c + 0.5 * du * u + 0.5 * dv * v)
                nrm.append(n)
                uv.append([(du + 1) / 2, (dv + 1) / 2])
    idx = np.concatenate([[4 * f, 4 * f + 1, 4 * f + 2, 4 * f, 4 * f + 2, 4 * f + 3] for f in range(6)])
    return np.array(pos, np.float32), np.array(nrm, np.float32), np.array(uv, np.float32), idx.astype(np.uint16)


def _grid(n=8):
    x, y = np.meshgrid(np.linspace(0, 4, n + 1), np.linspace(0, 4, n + 1), indexing="xy")
    z = 0.1 * np.sin(x) * np.cos(y)
    pos = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    g = np.stack([-0.1 * np.cos(x) * np.cos(y), 0.1 * np.sin(x) * np.sin(y), np.ones_like(x)], -1).reshape(-1, 3)
    nrm = (g / np.linalg.norm(g, axis=1, keepdims=True)).astype(np.float32)
    uv = (pos[:, :2] / 4).astype(np.float32)
    idx = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            idx += [a, a + 1, a + n + 2, a, a + n + 2, a + n + 1]
    return pos, nrm, uv, np.array(idx, np.uint16)


def _colors(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, 4)).astype(np.uint8)


def handmade_glb() -> bytes:
    """Two meshes (a cube + a quad with another material; a wavy grid), three nodes (one mesh used twice),
    with NORMAL, TEXCOORD_0, COLOR_0 (normalized ubyte) and ushort indices."""
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "materials": [
            {"name": "white", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1], "metallicFactor": 0}},
            {"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.1, 0.1, 1], "metallicFactor": 0}},
        ],
    }
    blob = Blob(doc)
    quad = (
        np.array([[0, 0, 0.7], [2, 0, 0.7], [2, 1, 0.7], [0, 1, 0.7]], np.float32),
        np.tile(np.float32([0, 0, 1]), (4, 1)),
        np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32),
        np.array([0, 1, 2, 0, 2, 3], np.uint16),
    )
    parts = [[(_cube(), 0), (quad, 1)], [(_grid(), 0)]]
    meshes = []
    for mesh_parts in parts:
        prims = []
        for k, ((pos, nrm, uv, idx), mat) in enumerate(mesh_parts):
            attrs = {
                "POSITION": blob.accessor(pos, min=pos.min(0).tolist(), max=pos.max(0).tolist()),
                "NORMAL": blob.accessor(nrm),
                "TEXCOORD_0": blob.accessor(uv),
                "COLOR_0": blob.accessor(_colors(len(pos), k + 10 * len(meshes)), normalized=True),
            }
            prims.append({"attributes": attrs, "indices": blob.accessor(idx), "material": mat})
        meshes.append({"primitives": prims})
    doc["meshes"] = meshes
    half = math.radians(30) / 2
    doc["nodes"] = [
        {"mesh": 0, "translation": [1, 2, 3], "rotation": [0, math.sin(half), 0, math.cos(half)]},
        {"mesh": 1, "translation": [-3, 0, 0], "scale": [0.5, 0.5, 0.5]},
        {"mesh": 0, "translation": [5, 0, 0], "scale": [2, 2, 2]},
    ]
    return blob.finish()


def two_rooms_glb() -> bytes:
    return make_scene("two-rooms")


SCENES = {"handmade": handmade_glb, "two-rooms": two_rooms_glb}


def _primitives(doc: dict):
    for mesh in doc["meshes"]:
        yield from mesh["primitives"]


def _require(doc: dict, *names: str) -> None:
    for key in ("extensionsUsed", "extensionsRequired"):
        doc[key] = sorted(set(doc.get(key, [])) | set(names))


# ---------------------------------------------------------------------------------------------- Draco


def draco_glb(data: bytes, *, fallback: bool = False) -> bytes:
    """Every primitive Draco-compressed (DracoPy.encode, 14-bit positions, lossless normals/UVs/colours).

    The accessors are written from the decoded Draco data, as the spec asks of generators; with
    ``fallback`` they also get uncompressed data, deliberately wrong (positions moved by 1000 m) so a
    test can tell which one was read.
    """
    doc, bin_ = parse_glb(data)
    src = copy.deepcopy(doc)
    blob = Blob(doc)
    for prim, src_prim in zip(_primitives(doc), _primitives(src), strict=True):
        a = src_prim["attributes"]
        pos = read_accessor(src, bin_, a["POSITION"])
        faces = read_accessor(src, bin_, src_prim["indices"]).reshape(-1, 3).astype(np.uint32)
        extra = {}
        if "NORMAL" in a:
            extra["normals"] = read_accessor(src, bin_, a["NORMAL"]).astype(np.float64)  # DracoPy wants float64
        if "TEXCOORD_0" in a:
            extra["tex_coord"] = read_accessor(src, bin_, a["TEXCOORD_0"]).astype(np.float64)  # DracoPy wants float64
        if "COLOR_0" in a:
            extra["colors"] = read_accessor(src, bin_, a["COLOR_0"])
        encoded = DracoPy.encode(pos, faces, quantization_bits=DRACO_BITS, compression_level=7, **extra)
        decoded = DracoPy.decode(encoded)
        ids, attrs = {}, {}
        for att in decoded.attributes:
            sem = DRACO_SEMANTIC[att["attribute_type"]]
            values = np.asarray(att["data"]).reshape(len(att["data"]), -1)
            ids[sem] = att["unique_id"]
            kw = {"normalized": True} if sem == "COLOR_0" else {}
            if sem == "POSITION":
                kw.update(min=values.min(0).tolist(), max=values.max(0).tolist())
            if fallback:
                values = values + 1000 if sem == "POSITION" else values
                attrs[sem] = blob.accessor(values.astype(values.dtype), **kw)
            else:
                attrs[sem] = blob.accessor(
                    None, count=len(values), component=COMPONENT[values.dtype], type_=TYPE[values.shape[1]], **kw
                )
        dfaces = np.asarray(decoded.faces, np.uint32).reshape(-1)
        if fallback:
            indices = blob.accessor(dfaces)
        else:
            indices = blob.accessor(None, count=dfaces.size, component=5125, type_="SCALAR")
        prim["attributes"] = attrs
        prim["indices"] = indices
        prim["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": blob.view(encoded), "attributes": ids}}
    if fallback:
        doc["extensionsUsed"] = sorted(set(doc.get("extensionsUsed", [])) | {"KHR_draco_mesh_compression"})
    else:
        _require(doc, "KHR_draco_mesh_compression")
    return blob.finish()


# ---------------------------------------------------------------------------------------------- meshopt


def quantized_glb(data: bytes) -> tuple[bytes, dict[int, bytes]]:
    """gltfpack-style KHR_mesh_quantization, uncompressed: POSITION int16 normalized (rows of 8 bytes)
    dequantized by a child node's translation + uniform scale, NORMAL int8 normalized through
    meshoptimizer's octahedral filter (rows of 4), TEXCOORD_0 uint16 normalized, COLOR_0 and indices kept.

    Returns the GLB and, for the normal views, the filter-encoded rows meshopt must compress (the GLB
    holds what decoding them gives, as the spec recommends for fallback data).
    """
    doc, bin_ = parse_glb(data)
    src = copy.deepcopy(doc)
    blob = Blob(doc)
    octahedral: dict[int, bytes] = {}
    dequant = []
    for mesh, src_mesh in zip(doc["meshes"], src["meshes"], strict=True):
        allpos = np.concatenate([read_accessor(src, bin_, p["attributes"]["POSITION"]) for p in src_mesh["primitives"]])
        lo, hi = allpos.min(0).astype(np.float64), allpos.max(0).astype(np.float64)
        center, scale = (lo + hi) / 2, float((hi - lo).max() / 2)
        dequant.append((center, scale))
        for prim, sp in zip(mesh["primitives"], src_mesh["primitives"], strict=True):
            a, out = sp["attributes"], {}
            pos = read_accessor(src, bin_, a["POSITION"]).astype(np.float64)
            q = np.rint((pos - center) / scale * 32767).astype(np.int16)
            out["POSITION"] = blob.accessor(q, stride=8, normalized=True, min=q.min(0).tolist(), max=q.max(0).tolist())
            if "NORMAL" in a:
                n = read_accessor(src, bin_, a["NORMAL"])
                rows = meshopt.encode_filter_oct(np.c_[n, np.zeros(len(n))], 4, 8)
                dec = meshopt.decode_vertex_buffer(meshopt.encode_vertex_buffer(rows), len(n), 4, "OCTAHEDRAL")
                out["NORMAL"] = blob.accessor(dec.view(np.int8)[:, :3], stride=4, normalized=True)
                octahedral[doc["accessors"][out["NORMAL"]]["bufferView"]] = rows.tobytes()
            if "TEXCOORD_0" in a:
                uv = read_accessor(src, bin_, a["TEXCOORD_0"])
                assert uv.min() >= 0 and uv.max() <= 1
                out["TEXCOORD_0"] = blob.accessor(np.rint(uv * 65535).astype(np.uint16), normalized=True)
            if "COLOR_0" in a:
                out["COLOR_0"] = blob.accessor(read_accessor(src, bin_, a["COLOR_0"]), normalized=True)
            prim["attributes"] = out
            prim["indices"] = blob.accessor(read_accessor(src, bin_, sp["indices"]))
    for node in list(doc["nodes"]):  # the mesh moves to a child node holding its dequantization
        if "mesh" in node:
            center, scale = dequant[node["mesh"]]
            doc["nodes"].append({"mesh": node.pop("mesh"), "translation": center.tolist(), "scale": [scale] * 3})
            node.setdefault("children", []).append(len(doc["nodes"]) - 1)
    _require(doc, "KHR_mesh_quantization")
    return blob.finish(), octahedral


def meshopt_glb(data: bytes, *, name: str = "EXT_meshopt_compression", filtered: dict[int, bytes] | None = None,
                fallback_uri: str | None = None) -> bytes:
    """Every bufferView meshopt-compressed into buffer 0 (the BIN chunk); the views point at buffer 1, a
    fallback placeholder without data (``{"fallback": true}``; ``fallback_uri`` gives it a URI that is
    not in the upload). Index views use mode TRIANGLES, the rest ATTRIBUTES (``filtered`` views: the
    given filter-encoded rows, OCTAHEDRAL)."""
    doc, bin_ = parse_glb(data)
    filtered = filtered or {}
    index_views = {doc["accessors"][p["indices"]]["bufferView"] for p in _primitives(doc) if "indices" in p}
    users = {}
    for acc in doc["accessors"]:
        users.setdefault(acc["bufferView"], acc)
    out = bytearray()
    fallback_size = 0
    for vi, view in enumerate(doc["bufferViews"]):
        acc = users[vi]
        raw = bin_[view.get("byteOffset", 0) : view.get("byteOffset", 0) + view["byteLength"]]
        elem = np.dtype(DTYPES[acc["componentType"]]).itemsize * NCOMP[acc["type"]]
        stride = view.get("byteStride", elem)
        count = acc["count"]
        ext = {"byteStride": stride, "count": count}
        if vi in index_views:
            ext["mode"] = "TRIANGLES"
            encoded = meshopt.encode_gltf_buffer(np.frombuffer(raw, DTYPES[acc["componentType"]]), "TRIANGLES")
        else:
            ext["mode"] = "ATTRIBUTES"
            rows = np.frombuffer(filtered.get(vi, raw), np.uint8).reshape(count, stride)
            if vi in filtered:
                ext["filter"] = "OCTAHEDRAL"
            encoded = meshopt.encode_gltf_buffer(rows, "ATTRIBUTES")
            view["byteStride"] = stride
        while len(out) % 4:
            out.append(0)
        ext.update(buffer=0, byteOffset=len(out), byteLength=len(encoded))
        out += encoded
        fallback_size += -fallback_size % 4
        view.update(buffer=1, byteOffset=fallback_size, byteLength=count * stride, extensions={name: ext})
        fallback_size += count * stride
    placeholder = {"byteLength": fallback_size, "extensions": {name: {"fallback": True}}}
    if fallback_uri:
        placeholder["uri"] = fallback_uri
    doc["buffers"] = [{"byteLength": len(out)}, placeholder]
    _require(doc, name)
    return glb(doc, bytes(out))


# ---------------------------------------------------------------------------------------------- comparison


def ingest_bytes(tmp_path: Path, name: str, data: bytes, limits: IngestLimits | None = None):
    path = tmp_path / name
    path.write_bytes(data)
    return ingest_file(path, limits)


def match(a, b, tol: float, *, same_order: bool = False):
    """Pair scene b's triangles with scene a's: by centroid and facing, then the corner rotation that fits
    best (windings must agree). Returns (index into b, rotation) per triangle of a, after checking that
    every corner of a is within ``tol`` of its partner (exactly equal when tol is 0)."""
    ta, tb = a.triangles.astype(np.float64), b.triangles.astype(np.float64)
    assert ta.shape == tb.shape

    def key(t):
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return np.hstack([t.mean(1), 0.05 * n])

    if same_order:
        pair = np.arange(len(ta))
    else:
        dist, pair = cKDTree(key(tb)).query(key(ta))
        assert np.unique(pair).size == len(ta), "triangles do not pair up one to one"
    err = np.stack([np.abs(ta - np.roll(tb[pair], -r, axis=1)).max(axis=(1, 2)) for r in range(3)], axis=1)
    rot = err.argmin(axis=1)
    worst = err[np.arange(len(ta)), rot].max()
    assert worst <= tol, f"a corner is {worst} away from its partner (tolerance {tol})"
    return pair, rot


def paired(arr: np.ndarray, pair: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Per-corner data of scene b reordered to scene a's triangles and corners."""
    out = arr[pair].copy()
    for r in (1, 2):
        out[rot == r] = np.roll(out[rot == r], -r, axis=1)
    return out


def extent(scene) -> float:
    t = scene.triangles.reshape(-1, 3)
    return float((t.max(0) - t.min(0)).max())


def expect_invalid(tmp_path: Path, data: bytes, code: str = "invalid_gltf", **kw) -> IngestError:
    with pytest.raises(IngestError) as info:
        ingest_bytes(tmp_path, "bad.glb", data, **kw)
    assert info.value.code == code, info.value.message
    assert info.value.status == ERROR_CODES[code]
    return info.value


# ---------------------------------------------------------------------------------------------- Draco tests


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_draco_scene_matches_the_uncompressed_one(tmp_path, scene):
    data = SCENES[scene]()
    ref = ingest_bytes(tmp_path, "ref.glb", data)
    comp = draco_glb(data)
    assert len(comp) < len(data)
    got = ingest_bytes(tmp_path, "draco.glb", comp)
    assert got.n_triangles == ref.n_triangles
    assert not any("extensions ignored" in w for w in got.warnings)
    # 14-bit positions: half a step of the primitive's largest range per axis, in world units <= the scene's
    tol = extent(ref) / (2**DRACO_BITS - 1)
    pair, rot = match(ref, got, tol)
    assert np.array_equal(got.material[pair], ref.material)
    np.testing.assert_allclose(paired(got.normals, pair, rot), ref.normals, atol=1e-4)
    np.testing.assert_allclose(paired(got.uv0, pair, rot), ref.uv0, atol=1e-6)
    if ref.colors is not None:
        np.testing.assert_array_equal(paired(got.colors, pair, rot), ref.colors)


def test_draco_is_preferred_over_the_uncompressed_fallback(tmp_path):
    data = handmade_glb()
    ref = ingest_bytes(tmp_path, "ref.glb", data)
    comp = draco_glb(data, fallback=True)
    doc, _ = parse_glb(comp)
    assert "KHR_draco_mesh_compression" not in doc.get("extensionsRequired", [])
    assert all("bufferView" in acc for acc in doc["accessors"])
    got = ingest_bytes(tmp_path, "draco.glb", comp)  # the fallback is 1000 m away: Draco was read
    match(ref, got, extent(ref) / (2**DRACO_BITS - 1))


def test_draco_limits(tmp_path):
    data = draco_glb(handmade_glb())
    n = ingest_bytes(tmp_path, "ok.glb", data).n_triangles
    expect_invalid(tmp_path, data, "too_many_triangles", limits=IngestLimits(max_triangles=n - 1))
    err = expect_invalid(tmp_path, data, "decoded_too_large", limits=IngestLimits(max_decoded_bytes=2000))
    assert "2000" in err.message
    # an indices accessor declaring fewer indices than the Draco data decodes: over the planned budget
    doc, bin_ = parse_glb(data)
    doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]["count"] -= 3
    expect_invalid(tmp_path, glb(doc, bin_))


def test_corrupt_draco_is_invalid_gltf(tmp_path):
    doc, bin_ = parse_glb(draco_glb(handmade_glb()))
    draco = doc["meshes"][1]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]
    view = doc["bufferViews"][draco["bufferView"]]
    start, length = view["byteOffset"], view["byteLength"]
    zeroed = bin_[:start] + bytes(length) + bin_[start + length :]
    assert "Draco" in expect_invalid(tmp_path, glb(doc, zeroed)).message
    garbage = bytes(np.random.default_rng(1).integers(0, 256, length).astype(np.uint8))
    expect_invalid(tmp_path, glb(doc, bin_[:start] + garbage + bin_[start + length :]))
    short = copy.deepcopy(doc)
    short["bufferViews"][doc["bufferViews"].index(view)]["byteLength"] = 12  # truncated bitstream
    expect_invalid(tmp_path, glb(short, bin_))
    bad = copy.deepcopy(doc)
    ext = bad["meshes"][1]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]
    ext["attributes"]["POSITION"] = 99  # no such Draco attribute
    expect_invalid(tmp_path, glb(bad, bin_))
    bad = copy.deepcopy(doc)
    bad["meshes"][1]["primitives"][0]["mode"] = 1  # lines cannot be Draco-compressed
    expect_invalid(tmp_path, glb(bad, bin_))


def test_draco_module_api():
    pos, nrm, uv, idx = _grid(2)
    geom = gc.decode_draco(DracoPy.encode(pos, idx.reshape(-1, 3).astype(np.uint32), quantization_bits=16,
                                          normals=nrm.astype(np.float64), tex_coord=uv.astype(np.float64)))
    assert geom.faces.shape == (8, 3) and geom.faces.dtype == np.uint32
    assert all(v.shape[0] == geom.n_points for v in geom.attributes.values())
    positions = next(v for u, v in geom.attributes.items() if geom.kinds[u] == 0)
    assert positions.dtype == np.float32  # dequantized by the decoder
    q16 = gc.draco_attribute_as(positions / 4, np.int16, 3, True)
    assert q16.dtype == np.int16 and not q16.flags.writeable
    with pytest.raises(gc.CompressionError):
        gc.draco_attribute_as(positions, np.float32, 2, False)
    with pytest.raises(gc.CompressionError):
        gc.decode_draco(b"DRACO" + bytes(40))


# ---------------------------------------------------------------------------------------------- meshopt tests


@pytest.mark.parametrize("name", ["EXT_meshopt_compression", "KHR_meshopt_compression"])
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_meshopt_scene_is_exactly_the_uncompressed_one(tmp_path, scene, name):
    data = SCENES[scene]()
    ref = ingest_bytes(tmp_path, "ref.glb", data)
    comp = meshopt_glb(data, name=name)
    doc, _ = parse_glb(comp)
    assert "uri" not in doc["buffers"][1] and doc["buffers"][1]["byteLength"] > len(parse_glb(comp)[1])
    got = ingest_bytes(tmp_path, "meshopt.glb", comp)
    assert not any("extensions ignored" in w for w in got.warnings)
    # the TRIANGLES codec keeps triangle order and winding but may rotate a triangle's corners
    pair, rot = match(ref, got, 0.0, same_order=True)
    for field in ("normals", "uv0", "colors"):
        if getattr(ref, field) is not None:
            assert np.array_equal(paired(getattr(got, field), pair, rot), getattr(ref, field)), field
    assert np.array_equal(got.material, ref.material)


def test_meshopt_with_mesh_quantization_like_gltfpack(tmp_path):
    data = handmade_glb()
    ref = ingest_bytes(tmp_path, "ref.glb", data)
    quant, octahedral = quantized_glb(data)
    qref = ingest_bytes(tmp_path, "quantized.glb", quant)
    got = ingest_bytes(tmp_path, "meshopt.glb", meshopt_glb(quant, filtered=octahedral))
    # compressed == the same quantized file uncompressed, exactly
    pair, rot = match(qref, got, 0.0, same_order=True)
    for field in ("normals", "uv0", "colors"):
        assert np.array_equal(paired(getattr(got, field), pair, rot), getattr(qref, field)), field
    # and the quantized file is the original within int16 / 8-bit octahedral precision
    match(ref, qref, extent(ref) / 32767 * 1.5, same_order=True)
    assert (np.sum(qref.normals * ref.normals, axis=-1) > 0.995).all()
    np.testing.assert_allclose(qref.uv0, ref.uv0, atol=1 / 65535)


def test_meshopt_fallback_buffer_with_a_missing_uri_is_not_read(tmp_path):
    data = meshopt_glb(handmade_glb(), fallback_uri="fallback.bin")
    doc, bin_ = parse_glb(data)
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bin_).decode()
    (tmp_path / "a.gltf").write_text(json.dumps(doc))
    got = ingest_file(tmp_path / "a.gltf")
    assert got.n_triangles == ingest_bytes(tmp_path, "ref.glb", handmade_glb()).n_triangles


def test_meshopt_limits_and_fallback_misuse(tmp_path):
    data = meshopt_glb(handmade_glb())
    expect_invalid(tmp_path, data, "decoded_too_large", limits=IngestLimits(max_decoded_bytes=1000))
    # a bufferView without the extension that reads the data-less fallback buffer
    doc, bin_ = parse_glb(data)
    del doc["bufferViews"][0]["extensions"]
    assert "fallback" in expect_invalid(tmp_path, glb(doc, bin_)).message


def test_corrupt_meshopt_is_invalid_gltf(tmp_path):
    doc, bin_ = parse_glb(meshopt_glb(handmade_glb()))
    name = "EXT_meshopt_compression"
    for vi, view in enumerate(doc["bufferViews"]):
        ext = view["extensions"][name]
        start, length = ext["byteOffset"], ext["byteLength"]
        zeroed = glb(doc, bin_[:start] + bytes(length) + bin_[start + length :])
        assert "meshopt" in expect_invalid(tmp_path, zeroed).message, ext["mode"]
        short = copy.deepcopy(doc)
        short["bufferViews"][vi]["extensions"][name]["byteLength"] = length // 2
        expect_invalid(tmp_path, glb(short, bin_))
        if vi >= 2:
            break
    for change in ({"mode": "STRIPS"}, {"filter": "COLOR"}, {"byteStride": 6}, {"count": 0},
                   {"byteOffset": len(bin_)}, {"buffer": 7}):
        bad = copy.deepcopy(doc)
        bad["bufferViews"][0]["extensions"][name].update(change)
        expect_invalid(tmp_path, glb(bad, bin_))


# ---------------------------------------------------------------------------------------------- HTTP


def test_draco_glb_uploads_through_the_api(running, tmp_path):
    data = two_rooms_glb()
    n = ingest_bytes(tmp_path, "ref.glb", data).n_triangles
    r = running.client.post("/v1/scenes", content=draco_glb(data), headers={"X-Filename": "two-rooms-draco.glb"})
    assert r.status_code == 201, r.text
    assert r.json()["triangles"] == n
    r = running.client.post("/v1/scenes", content=meshopt_glb(data), headers={"X-Filename": "two-rooms-meshopt.glb"})
    assert r.status_code == 201, r.text
    assert r.json()["triangles"] == n
