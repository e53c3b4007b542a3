"""The ingest stage's warnings: ``unlit_scene`` (nothing lights the scene) and ``light_outside_scene``."""
from __future__ import annotations

import pytest

from proto.models import BakeConfig
from workers.gltf import ingest_file
from workers.stages.base import StageContext
from workers.stages.lighting import run_lighting


@pytest.fixture(scope="module")
def scenes(scene_files):
    return {name: ingest_file(path) for name, path in scene_files.items()}


def _warnings(scene, config: dict) -> list[dict]:
    ctx = StageContext(config=BakeConfig.model_validate(config), scene_loader=lambda: scene, inputs={},
                       report=lambda f: None)
    return run_lighting(ctx).stats.get("warnings", [])


@pytest.mark.parametrize("name", ["cornell", "two-rooms", "sealed-box"])
def test_lit_scenes_have_no_warnings(scenes, name):
    assert _warnings(scenes[name], {}) == []


def test_unlit_scene(scenes):
    w = _warnings(scenes["two-rooms"], {"scene": {"use_scene_lights": False}})
    assert [x["code"] for x in w] == ["unlit_scene"]
    msg = w[0]["message"]
    assert "nothing lights the scene" in msg and "use_scene_lights = false" in msg and "black" in msg
    # a sky, a config light or an emitter lights it
    assert _warnings(scenes["two-rooms"], {"scene": {"use_scene_lights": False, "sky": [0.1, 0.1, 0.1]}}) == []
    assert _warnings(scenes["two-rooms"], {"scene": {"use_scene_lights": False, "lights": [
        {"type": "directional", "direction": [0, -1, 0]}]}}) == []
    assert _warnings(scenes["cornell"], {"scene": {"use_scene_lights": False}}) == []  # its ceiling emitter
    assert [x["code"] for x in _warnings(scenes["furnace"], {})] == ["unlit_scene"]


def test_light_outside_scene(scenes):
    # two-rooms: bounds (-0.05 .. 8.1, 3.05, 4.05), diagonal ~9.6 m, so the margin is ~0.96 m
    near = {"type": "point", "position": [8.8, 1.0, 2.0]}
    far = {"type": "spot", "position": [1.0, 12.0, 2.0], "direction": [0, -1, 0]}
    w = _warnings(scenes["two-rooms"], {"scene": {"lights": [near, far]}})
    assert [x["code"] for x in w] == ["light_outside_scene"]
    assert "spot light 2" in w[0]["message"] and "(1, 12, 2)" in w[0]["message"]
    # directional lights have no position: never outside
    assert _warnings(scenes["two-rooms"], {"scene": {"lights": [{"type": "directional", "direction": [0, -1, 0]}]}}) == []
