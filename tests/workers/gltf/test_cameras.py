"""Tests for workers.gltf.cameras: the glTF's own perspective cameras (lenient: bad ones are skipped)."""

from __future__ import annotations

import math

import numpy as np

from workers.gltf.cameras import MAX_CAMERAS, build_cameras, safe_camera_name


def test_perspective_cameras_in_world_space_others_skipped():
    gltf = {"cameras": [{"type": "perspective", "name": "Main View!", "perspective": {"yfov": math.radians(60)}},
                        {"type": "orthographic", "orthographic": {}},
                        {"type": "perspective", "perspective": {"yfov": math.radians(200)}}],
            "nodes": [{"camera": 0}, {"camera": 1}, {"camera": 2}, {"camera": 7}, {"name": "plain"}]}
    world = [np.eye(4) for _ in range(5)]
    world[0][:3, 3] = [1, 2, 3]
    cams = build_cameras(gltf, [0, 1, 2, 3, 4], world)
    assert cams == [{"name": "main-view", "position": [1.0, 2.0, 3.0], "target": [1.0, 2.0, 2.0], "fov_y": 60.0}]
    world[0][:3, 3] = [np.nan, 0, 0]
    assert build_cameras(gltf, [0], world) == []
    assert build_cameras({"nodes": []}, [], []) == [] and build_cameras([], [], []) == []


def test_at_most_max_cameras_with_unique_safe_names():
    gltf = {"cameras": [{"type": "perspective", "name": "cam", "perspective": {"yfov": 1.0}}],
            "nodes": [{"camera": 0}] * (MAX_CAMERAS + 3)}
    cams = build_cameras(gltf, list(range(MAX_CAMERAS + 3)), [np.eye(4)] * (MAX_CAMERAS + 3))
    assert len(cams) == MAX_CAMERAS
    assert [c["name"] for c in cams[:3]] == ["cam", "cam-2", "cam-3"]
    taken: set[str] = set()
    assert safe_camera_name("", 4, taken) == "gltf-4"
    assert safe_camera_name("A" * 40, 0, taken) == "a" * 24
