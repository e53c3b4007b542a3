"""Tests for workers.gltf.primitives: primitive modes, degenerate triangles, winding under mirroring."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from tests.workers.gltf.builders import Gltf, write_glb, QUAD, face_normals
from workers.gltf import ingest_file


@pytest.mark.parametrize(
    "transform",
    [
        {"scale": [-1, 1, 1]},
        {"scale": [1, -1, 1]},
        {"scale": [-1, -1, -1]},
        {"matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]},
    ],
)
def test_negative_scale_keeps_front_faces(tmp_path, transform):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3], NORMAL=np.tile([0, 0, 1], (4, 1))), **transform)
    s = ingest_file(write_glb(tmp_path / "n.glb", g))
    m = np.eye(3)
    if "scale" in transform:
        m = np.diag(transform["scale"])
    else:
        m[0, 0] = -1
    # The mirrored quad's front face keeps its (inverse-transpose transformed) normal, and the winding
    # is flipped so the counter-clockwise rule still gives that same normal.
    expected_normal = np.linalg.inv(m).T @ [0, 0, 1]
    np.testing.assert_allclose(face_normals(s), [expected_normal] * 2, atol=1e-6)
    np.testing.assert_allclose(s.normals, np.broadcast_to(expected_normal, (2, 3, 3)), atol=1e-6)


def test_strip_and_fan_give_the_same_triangles_as_a_list(tmp_path):
    for name, idx, mode in [("list", [0, 1, 2, 0, 2, 3], 4), ("strip", [0, 1, 3, 2], 5), ("fan", [0, 1, 2, 3], 6)]:
        g = Gltf()
        g.node(mesh=g.mesh(QUAD, idx, mode=mode))
        s = ingest_file(write_glb(tmp_path / f"{name}.glb", g))
        assert s.n_triangles == 2
        np.testing.assert_allclose(face_normals(s), [[0, 0, 1]] * 2, atol=1e-6)
        assert 0.5 * np.linalg.norm(
            np.cross(s.triangles[:, 1] - s.triangles[:, 0], s.triangles[:, 2] - s.triangles[:, 0]), axis=1
        ).sum() == pytest.approx(1.0)


def test_points_and_lines_are_dropped_with_a_warning(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, mode=0))
    g.node(mesh=g.mesh(QUAD, mode=1))
    g.node(mesh=g.mesh(QUAD, mode=1))
    g.node(mesh=g.mesh(QUAD[:3]))
    s = ingest_file(write_glb(tmp_path / "p.glb", g))
    assert s.n_triangles == 1
    assert "1 point primitive ignored" in s.warnings and "2 line primitives ignored" in s.warnings


def test_degenerate_index_triangles_are_dropped(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 0, 3, 0, 2, 3]))
    s = ingest_file(write_glb(tmp_path / "d.glb", g))
    assert s.n_triangles == 2
    assert any("degenerate" in w for w in s.warnings)


# ---------------------------------------------------------------------------------------------- unit: modes


def test_triangle_indices_of_each_mode():
    from workers.gltf.primitives import triangle_indices

    class NoAccessors:  # primitives without "indices" read none
        pass

    counts: Counter = Counter()
    tri = triangle_indices(NoAccessors(), {"mode": 5}, 5, "p", counts)
    assert tri.tolist() == [[0, 1, 2], [1, 3, 2], [2, 3, 4]]  # strip: [glTF] 3.7.2.1, odd ones flipped
    assert triangle_indices(NoAccessors(), {"mode": 6}, 4, "p", counts).tolist() == [[1, 2, 0], [2, 3, 0]]
    assert triangle_indices(NoAccessors(), {}, 7, "p", counts).tolist() == [[0, 1, 2], [3, 4, 5]]
    assert triangle_indices(NoAccessors(), {"mode": 1}, 4, "p", counts) is None
    assert counts == {"line primitive(s) ignored": 1,
                      "TRIANGLES primitive(s) whose index count is not a multiple of 3 (extra indices ignored)": 1}
