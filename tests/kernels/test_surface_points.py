"""The reference's choice of surface points (workers/kernels/surface_points.py: surface_point_set)."""
from __future__ import annotations

import numpy as np

from tests.kernels.test_pathtrace import closed_box
from workers.kernels import surface_points as SP
from workers.raycast import RayCaster
from workers.render.cameras import Camera


def test_area_sampling_and_the_fallback_without_cameras():
    box = closed_box(0.5, 0.0, size=2.0)
    caster = RayCaster(box.triangles)
    sp, used, warnings = SP.surface_point_set(box, [], 64, "cameras", seed=1, caster=caster, eps=1e-4)
    assert used == "area" and warnings == [] and 32 <= len(sp["position"]) <= 64
    same, _, _ = SP.surface_point_set(box, [], 64, "area", seed=1, caster=caster, eps=1e-4)
    np.testing.assert_array_equal(sp["position"], same["position"])


def test_camera_sampling_and_its_fallback():
    box = closed_box(0.5, 0.0, size=2.0)
    caster = RayCaster(box.triangles)
    inside = Camera((1.0, 1.0, 1.0), (1.0, 1.0, 0.0), width=32, height=24)
    sp, used, _ = SP.surface_point_set(box, [inside], 64, "cameras", seed=1, caster=caster)
    assert used == "cameras" and len(sp["position"]) > 32
    outside = Camera((1.0, 1.0, 50.0), (1.0, 1.0, 60.0), width=32, height=24)    # looks away: sees nothing
    _, used, _ = SP.surface_point_set(box, [outside], 64, "cameras", seed=1, caster=caster, eps=1e-4)
    assert used == "area"


def test_few_points_warn(monkeypatch):
    monkeypatch.setattr(SP, "area_points", lambda *a, **k: {"position": np.zeros((3, 3))})
    _, used, warnings = SP.surface_point_set(closed_box(0.5, 0.0), [], 64, "area")
    assert used == "area" and [w["code"] for w in warnings] == ["few_surface_points"]
    assert SP.surface_point_set(closed_box(0.5, 0.0), [], 0, "area")[2] == []          # none asked: no warning
