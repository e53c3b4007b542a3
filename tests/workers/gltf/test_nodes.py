"""Tests for workers.gltf.nodes: node transforms, instancing, skins and morph targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.workers.gltf.builders import Gltf, write_glb, QUAD, sample_scene, face_normals
from workers.gltf import IngestError, ingest_file


def test_world_transforms_uvs_and_normals(tmp_path):
    s = ingest_file(write_glb(tmp_path / "s.glb", sample_scene()))
    # node 0: translated to z=-2, vertex normals +Z, UVs carried per corner
    np.testing.assert_allclose(s.triangles[0], [[0, 0, -2], [1, 0, -2], [1, 1, -2]], atol=1e-6)
    np.testing.assert_allclose(s.normals[:2], np.broadcast_to([0, 0, 1], (2, 3, 3)), atol=1e-6)
    np.testing.assert_allclose(s.uv0[0], [[0, 1], [1, 1], [1, 0]])
    # node 1: +90 degrees about X maps the quad's +Y edge to +Z and its normal (+Z) to -Y, then up 3
    np.testing.assert_allclose(s.triangles[2], [[0, 3, 0], [1, 3, 0], [1, 3, 1]], atol=1e-6)
    np.testing.assert_allclose(face_normals(s)[2:4], [[0, -1, 0]] * 2, atol=1e-6)
    np.testing.assert_allclose(s.normals[2:4], np.broadcast_to([0, -1, 0], (2, 3, 3)), atol=1e-6)  # geometric
    # node 2: scaled by 2, no UVs -> zeros
    np.testing.assert_allclose(s.triangles[4], [[0, 0, 0], [2, 0, 0], [2, 2, 0]])
    assert not s.uv0[4].any()
    assert s.uv1 is None
    assert s.triangles.dtype == np.float32 and s.normals.dtype == np.float32 and s.material.dtype == np.int32
    np.testing.assert_allclose(s.bounds, [[0, 0, -2], [2, 3, 1]], atol=1e-6)


def test_sparse_accessor_morph_target_and_gpu_instancing(tmp_path):
    g = Gltf()
    pos = g.accessor(QUAD[:3])
    doc = g.doc
    # sparse: vertex 2 replaced by (0, 2, 0)
    doc["accessors"][pos]["sparse"] = {
        "count": 1,
        "indices": {"bufferView": g.view(np.array([2], np.uint16).tobytes()), "componentType": 5123},
        "values": {"bufferView": g.view(np.array([[0, 2, 0]], np.float32).tobytes())},
    }
    target = g.accessor(np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1]], np.float32))
    doc["meshes"].append(
        {"primitives": [{"attributes": {"POSITION": pos}, "targets": [{"POSITION": target}]}], "weights": [0.5]}
    )
    t = g.accessor(np.array([[0, 0, 0], [10, 0, 0], [20, 0, 0]], np.float32))
    doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    g.node(mesh=0, extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": t}}})
    s = ingest_file(write_glb(tmp_path / "x.glb", g))
    assert s.n_triangles == 3
    for k in range(3):
        np.testing.assert_allclose(
            s.triangles[k], [[10 * k, 0, 0.5], [10 * k + 1, 0, 0.5], [10 * k, 2, 0.5]], atol=1e-6
        )


def test_skin_at_static_pose_ignores_the_mesh_node_transform(tmp_path):
    g = Gltf()
    pos = QUAD[:3]
    mesh = g.mesh(pos, JOINTS_0=np.zeros((3, 4)), WEIGHTS_0=np.tile([1, 0, 0, 0], (3, 1)))
    prim = g.doc["meshes"][mesh]["primitives"][0]["attributes"]
    prim["JOINTS_0"] = g.accessor(np.zeros((3, 4), np.uint8))  # joints must be unsigned ints
    ibm = g.accessor(np.eye(4, dtype=np.float32).reshape(1, 16))  # bind pose at the origin
    joint = g.node(translation=[0, 5, 0])
    g.doc["skins"] = [{"joints": [joint], "inverseBindMatrices": ibm}]
    g.node(mesh=mesh, skin=0, translation=[100, 100, 100])  # must be ignored
    s = ingest_file(write_glb(tmp_path / "skin.glb", g))
    np.testing.assert_allclose(s.triangles[0], pos + [0, 5, 0], atol=1e-6)


# ---------------------------------------------------------------------------------------------- unit: transforms


def test_local_matrix_is_translation_rotation_scale_or_column_major_matrix():
    from workers.gltf.nodes import local_matrix

    m = local_matrix({"translation": [1, 2, 3], "rotation": [0, 0, 0.7071068, 0.7071068], "scale": [2, 1, 1]}, 0)
    # S first (x doubled), then a quarter turn about +Z (x -> y), then T
    assert np.allclose(m @ [1, 0, 0, 1], [1, 4, 3, 1], atol=1e-6)
    cm = list(range(16))
    assert np.array_equal(local_matrix({"matrix": cm}, 0), np.array(cm, float).reshape(4, 4).T)
    with pytest.raises(IngestError):
        local_matrix({"rotation": [0, 0, 0, 0]}, 0)


def test_world_matrices_compose_parent_then_child_and_refuse_cycles():
    from workers.gltf.document import Document
    from workers.gltf.nodes import scene_nodes, world_matrices

    doc = Document({"asset": {}, "nodes": [{"translation": [1, 0, 0], "children": [1]},
                                           {"scale": [2, 2, 2], "children": [2]}, {"translation": [0, 1, 0]}],
                    "scenes": [{"nodes": [0]}]})
    world = world_matrices(doc)
    assert np.allclose(world[2] @ [0, 0, 0, 1], [1, 2, 0, 1])  # T(1,0,0) @ S(2) @ T(0,1,0)
    assert scene_nodes(doc) == [0, 1, 2]
    cyclic = Document({"asset": {}, "nodes": [{"children": [1]}, {"children": [0]}]})
    with pytest.raises(IngestError) as info:
        world_matrices(cyclic)
    assert info.value.code == "invalid_gltf"


def test_cofactor_transforms_normals_like_the_inverse_transpose():
    from workers.gltf.nodes import cofactor, normalize_rows, quat_to_matrix

    rng = np.random.default_rng(0)
    m = rng.normal(size=(5, 3, 3))
    assert np.allclose(cofactor(m), np.linalg.det(m)[:, None, None] * np.linalg.inv(m).transpose(0, 2, 1))
    r = quat_to_matrix([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0])
    unit, ok = normalize_rows(np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))
    assert ok.tolist() == [True, False, False] and np.allclose(unit[0], [0.6, 0.8, 0.0]) and not unit[1:].any()
