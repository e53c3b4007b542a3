"""Tests for workers.gltf.lights: KHR_lights_punctual lights placed by their nodes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tests.workers.gltf.builders import Gltf, write_glb, QUAD
from workers.gltf import IngestError, ingest_file


def test_lights_follow_node_world_transforms(tmp_path):
    g = Gltf()
    g.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    g.doc["extensions"] = {
        "KHR_lights_punctual": {
            "lights": [
                {"type": "spot", "name": "spot", "intensity": 20, "range": 5, "spot": {"outerConeAngle": 0.5}},
                {"type": "directional", "color": [1, 0.9, 0.8]},
                {"type": "point"},
            ]
        }
    }
    g.node(mesh=g.mesh(QUAD[:3]))
    # parent: translate (1, 2, 3) and scale 2; child spot: +90 degrees about X, offset (0, 0, 1) locally
    q = [math.sin(math.pi / 4), 0, 0, math.cos(math.pi / 4)]
    spot = g.node(root=False, translation=[0, 0, 1], rotation=q, extensions={"KHR_lights_punctual": {"light": 0}})
    g.node(translation=[1, 2, 3], scale=[2, 2, 2], children=[spot])
    # directional light yawed 90 degrees about Y: local -Z turns to -X
    qy = [0, math.sin(math.pi / 4), 0, math.cos(math.pi / 4)]
    g.node(rotation=qy, translation=[5, 5, 5], extensions={"KHR_lights_punctual": {"light": 1}})
    g.node(matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 7, 8, 9, 1], extensions={"KHR_lights_punctual": {"light": 2}})
    s = ingest_file(write_glb(tmp_path / "l.glb", g))
    spot_l, sun, point = s.lights
    assert spot_l["type"] == "spot" and spot_l["name"] == "spot"
    np.testing.assert_allclose(spot_l["position"], [1, 2, 5], atol=1e-9)  # (1,2,3) + 2 * (0,0,1)
    np.testing.assert_allclose(spot_l["direction"], [0, 1, 0], atol=1e-9)  # R_x(90) (0,0,-1) = (0,1,0)
    assert spot_l["inner_cone_angle"] == 0.0 and spot_l["outer_cone_angle"] == 0.5
    assert spot_l["intensity"] == 20 and spot_l["range"] == 5 and spot_l["color"] == [1, 1, 1]
    assert sun["type"] == "directional" and sun["position"] is None
    np.testing.assert_allclose(sun["direction"], [-1, 0, 0], atol=1e-9)
    assert sun["color"] == [1, 0.9, 0.8] and sun["intensity"] == 1.0 and sun["range"] is None
    assert point["position"] == [7, 8, 9] and point["direction"] is None
    assert point["inner_cone_angle"] is None and point["outer_cone_angle"] is None
    json.dumps(s.lights)  # plain JSON


def test_spot_light_defaults(tmp_path):
    g = Gltf()
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "spot"}]}}
    g.node(mesh=g.mesh(QUAD[:3]))
    g.node(extensions={"KHR_lights_punctual": {"light": 0}})
    (light,) = ingest_file(write_glb(tmp_path / "l.glb", g)).lights
    assert light["inner_cone_angle"] == 0 and light["outer_cone_angle"] == pytest.approx(math.pi / 4)
    assert light["direction"] == [0, 0, -1] and light["position"] == [0, 0, 0] and light["intensity"] == 1


# ---------------------------------------------------------------------------------------------- unit: KHR_lights_punctual


def test_build_lights_parses_definitions_and_places_them():
    from workers.gltf.document import Document
    from workers.gltf.lights import build_lights

    doc = Document({"asset": {}, "extensions": {"KHR_lights_punctual": {"lights": [
        {"type": "directional", "intensity": 5.0, "name": "sun"},
        {"type": "spot", "color": [1, 0, 0], "range": 4.0, "spot": {"outerConeAngle": 0.5}},
    ]}}, "nodes": [{"extensions": {"KHR_lights_punctual": {"light": 0}}},
                   {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": 1}}}, {}]})
    world = [np.eye(4) for _ in range(3)]
    world[1][:3, 3] = [1, 2, 3]
    world[1][:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # local -Z -> world +Y
    sun, spot = build_lights(doc, [0, 1, 2], world)
    assert sun == {"name": "sun", "type": "directional", "color": [1.0, 1.0, 1.0], "intensity": 5.0, "range": None,
                   "position": None, "direction": [0.0, 0.0, -1.0], "inner_cone_angle": None, "outer_cone_angle": None}
    assert spot["name"] == "lamp" and spot["position"] == [1.0, 2.0, 3.0] and np.allclose(spot["direction"], [0, 1, 0])
    assert spot["inner_cone_angle"] == 0.0 and spot["outer_cone_angle"] == 0.5 and spot["range"] == 4.0
    assert build_lights(doc, [2], world) == []  # only the nodes listed are read
    bad = Document({"asset": {}, "nodes": [{"extensions": {"KHR_lights_punctual": {"light": 3}}}]})
    with pytest.raises(IngestError) as info:
        build_lights(bad, [0], [np.eye(4)])
    assert info.value.code == "invalid_gltf" and "does not exist" in info.value.message
