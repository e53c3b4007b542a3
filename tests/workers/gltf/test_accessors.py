"""Tests for workers.gltf.accessors: buffers, views, accessors (sparse, normalized, strided)."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from tests.workers.gltf.builders import Gltf, write_glb, expect_error
from workers.gltf import IngestError, IngestLimits


def test_primitive_restart_value_is_invalid(tmp_path):
    g = Gltf()
    pos = np.zeros((256, 3), np.float32)
    pos[1], pos[255] = [1, 0, 0], [0, 1, 0]
    g.node(mesh=g.mesh(pos))
    g.doc["meshes"][0]["primitives"][0]["indices"] = g.accessor(np.array([0, 1, 255], np.uint8))
    expect_error("invalid_gltf", write_glb(tmp_path / "a.glb", g), contains="restart")


# ---------------------------------------------------------------------------------------------- unit: accessors


def _accessors(doc: dict, data: bytes):
    from workers.gltf.accessors import Accessors
    from workers.gltf.container import NoFiles
    from workers.gltf.document import Document

    doc = {"asset": {"version": "2.0"}, **doc,
           "buffers": [{"byteLength": len(data),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]}
    return Accessors(Document(doc), None, NoFiles(), IngestLimits(), "t.gltf")


def test_strided_normalized_and_sparse_accessors():
    # interleaved: (u8 x 2, pad 2) per element, 3 elements; then sparse indices (u8) and values (u8 x 2)
    inter = bytes([0, 255, 9, 9, 128, 64, 9, 9, 255, 0, 9, 9])
    sparse_i, sparse_v = bytes([2, 0, 0, 0]), bytes([10, 20, 0, 0])
    data = inter + sparse_i + sparse_v
    acc = _accessors({
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 12, "byteStride": 4},
                        {"buffer": 0, "byteOffset": 12, "byteLength": 4}, {"buffer": 0, "byteOffset": 16, "byteLength": 4}],
        "accessors": [
            {"bufferView": 0, "componentType": 5121, "count": 3, "type": "VEC2", "normalized": True},
            {"bufferView": 0, "componentType": 5121, "count": 3, "type": "VEC2",
             "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5121}, "values": {"bufferView": 2}}},
            {"componentType": 5126, "count": 2, "type": "VEC3"},
        ]}, data)
    assert acc.accessor(0, "t").tolist() == [[0, 255], [128, 64], [255, 0]]
    assert np.allclose(acc.accessor_float(0, "t"), np.array([[0, 255], [128, 64], [255, 0]]) / 255)
    assert acc.accessor(1, "t").tolist() == [[0, 255], [128, 64], [10, 20]]
    assert acc.accessor_float(2, "t").tolist() == [[0, 0, 0], [0, 0, 0]]  # no bufferView: zeros
    assert not acc.accessor(0, "t").flags.writeable and acc.accessor(0, "t") is acc.accessor(0, "t")
    with pytest.raises(IngestError) as info:
        acc.accessor_float(0, "POSITION", (3,))
    assert "expected 3 components" in info.value.message


def test_signed_normalized_clamps_at_minus_one_and_view_ranges_are_checked():
    data = np.array([-128, -127, 0, 127], np.int8).tobytes()
    acc = _accessors({"bufferViews": [{"buffer": 0, "byteLength": 4}, {"buffer": 0, "byteOffset": 2, "byteLength": 4}],
                      "accessors": [{"bufferView": 0, "componentType": 5120, "count": 4, "type": "SCALAR",
                                     "normalized": True},
                                    {"bufferView": 1, "componentType": 5120, "count": 1, "type": "SCALAR"}]}, data)
    assert acc.accessor_float(0, "t")[:, 0].tolist() == [-1.0, -1.0, 0.0, 1.0]
    with pytest.raises(IngestError) as info:
        acc.accessor(1, "t")
    assert "runs past the end of buffer 0" in info.value.message
