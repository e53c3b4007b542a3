"""workers.procedural_glb: the grid-solid mesher and the glTF writer on their own."""
from __future__ import annotations

import json
import struct

import numpy as np

from workers.procedural_glb import Light, Material, SceneSpec, encode_glb, grid_solid, quat_from_neg_z, solid_mesh


def test_grid_solid_of_a_box_minus_a_cavity_is_closed_and_outward():
    ops = [(True, ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))), (False, ((0.25, 0.25, 0.25), (0.75, 0.75, 0.75)))]
    faces = grid_solid(ops, lambda c, axis, sign: "m")["m"]
    quads = np.asarray(faces)                                        # (F, 4, 3) counter-clockwise from outside
    n = np.cross(quads[:, 1] - quads[:, 0], quads[:, 2] - quads[:, 0])
    area = np.linalg.norm(n, axis=1)                                  # the quads are rectangles
    assert np.isclose(area.sum(), 6 * 1.0 + 6 * 0.25)                 # outer skin + cavity skin
    # divergence theorem: sum of (centroid . n) * area / 3 over an outward surface is the enclosed volume
    c = quads.mean(axis=1)
    volume = float((np.einsum("ij,ij->i", c, n)).sum() / 3)
    assert np.isclose(volume, 1.0 - 0.125)


def test_encode_glb_is_valid_and_carries_the_bake_box_and_lights():
    spec = SceneSpec("t", [Material("m", (0.5, 0.5, 0.5))],
                     [solid_mesh("box", [(True, ((0, 0, 0), (1, 1, 1)))], lambda c, a, s: "m")],
                     [Light("sun", "directional", 3.0, direction=(0.0, -1.0, 0.0))], bake_box=((0, 0, 0), (1, 1, 1)))
    glb = encode_glb(spec)
    magic, version, total = struct.unpack("<III", glb[:12])
    assert (magic, version, total) == (0x46546C67, 2, len(glb))
    n = struct.unpack("<I", glb[12:16])[0]
    doc = json.loads(glb[20:20 + n])
    assert doc["scenes"][0]["extras"]["kiln_bake_box"] == {"min": [0, 0, 0], "max": [1, 1, 1]}
    assert doc["extensions"]["KHR_lights_punctual"]["lights"][0]["type"] == "directional"
    # the light node's -Z is rotated onto the light's direction
    q = quat_from_neg_z((0.0, -1.0, 0.0))
    x, y, z, w = q
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(r @ [0, 0, -1], [0, -1, 0], atol=1e-12)
