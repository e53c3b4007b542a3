"""Review cameras (workers/render/cameras.py: review_cameras, camera_record)."""
from __future__ import annotations

import pytest

from proto.models import BakeConfig
from tests.kernels.test_pathtrace import closed_box
from workers.raycast import RayCaster


def _review(evaluate: dict, scene=None):
    from workers.render.cameras import review_cameras

    scene = scene if scene is not None else closed_box(0.5, 0.0, size=4.0)
    return review_cameras(BakeConfig.model_validate({"evaluate": evaluate}), scene, RayCaster(scene.triangles))


def test_config_cameras_keep_their_order_get_unique_names_and_fitted_planes():
    cams, source = _review({"cameras": [{"position": [1, 1, 1], "target": [3, 1, 1], "name": "a"},
                                        {"position": [2, 2, 2], "target": [2, 1, 2], "name": "a"},
                                        {"position": [3, 3, 3], "target": [1, 1, 1], "fov_y": 40}],
                            "width": 32, "height": 24, "fov_y": 70})
    assert source == "config" and [c.name for c in cams] == ["a", "a-1", "cam-2"]
    assert [c.fov_y for c in cams] == [70, 70, 40] and all((c.width, c.height) == (32, 24) for c in cams)
    assert all(c.near is not None and 0 < c.near < c.far for c in cams)


def test_gltf_cameras_then_auto_then_none():
    scene = closed_box(0.5, 0.0, size=4.0)
    scene.cameras = [{"name": "door", "position": [2, 1.5, 3.5], "target": [2, 1.5, 2.5]}]
    cams, source = _review({"cameras": 2}, scene)
    assert source == "gltf" and [c.name for c in cams] == ["door"]
    cams, source = _review({"cameras": 2})
    assert source in ("auto", "default") and 1 <= len(cams) <= 2
    assert _review({"cameras": 0}) == ([], "none")


def test_camera_record():
    from workers.render.cameras import Camera, camera_record

    rec = camera_record(Camera((0, 1, 2), (0, 1, 0), fov_y=50, width=64, height=48, name="x"))
    assert rec == {"name": "x", "position": [0.0, 1.0, 2.0], "target": [0.0, 1.0, 0.0], "fov": 50.0, "width": 64,
                   "height": 48}
    assert all(isinstance(v, float) for v in rec["position"])


@pytest.mark.parametrize("n", [1, 3])
def test_auto_cameras_are_deterministic(n):
    a, b = _review({"cameras": n}), _review({"cameras": n})
    assert [c.to_dict() for c in a[0]] == [c.to_dict() for c in b[0]]
