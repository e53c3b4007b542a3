"""tests/bench/bench_fidelity.py's rotated scenes (``--rotate``): the same scene in another frame, lights included,
so that the Cycles references made in the original frame still hold."""
from __future__ import annotations

import math

import numpy as np

from tests.bench.bench_fidelity import rotated_config, rotated_glb, rotation_y
from workers.gltf import ingest_file
from workers.procedural import make_scene


def _ingest(tmp_path, data: bytes, name: str):
    p = tmp_path / f"{name}.glb"
    p.write_bytes(data)
    return ingest_file(p)


def test_rotated_glb_turns_meshes_and_lights_by_the_same_rotation(tmp_path):
    base = _ingest(tmp_path, make_scene("two-rooms"), "a")
    for deg in (90.0, 30.0):
        rot = rotation_y(deg)
        turned = _ingest(tmp_path, rotated_glb(make_scene("two-rooms"), deg), f"b{deg:g}")
        a = np.asarray(base.triangles, np.float64).reshape(-1, 3)
        b = np.asarray(turned.triangles, np.float64).reshape(-1, 3)
        np.testing.assert_allclose(b, a @ rot.T, atol=1e-5)          # every vertex, in order
        la, lb = base.lights[0], turned.lights[0]
        np.testing.assert_allclose(lb["position"], rot @ np.asarray(la["position"]), atol=1e-5)
    np.testing.assert_allclose(rotation_y(90.0) @ [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], atol=1e-12)
    assert abs(np.linalg.det(rotation_y(30.0)) - 1.0) < 1e-12


def test_rotated_config_turns_added_lights_not_the_sky():
    cfg = {"scene": {"sky": [0.3, 0.35, 0.4], "lights": [{"type": "directional", "direction": [1.0, -1.0, 0.0]},
                                                          {"type": "point", "position": [0.0, 2.0, 3.0]}]}}
    out = rotated_config(cfg, rotation_y(90.0))
    assert out["scene"]["sky"] == [0.3, 0.35, 0.4] and cfg["scene"]["lights"][0]["direction"] == [1.0, -1.0, 0.0]
    np.testing.assert_allclose(out["scene"]["lights"][0]["direction"], [0.0, -1.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(out["scene"]["lights"][1]["position"], [3.0, 2.0, 0.0], atol=1e-12)
    assert math.isclose(np.linalg.norm(out["scene"]["lights"][0]["direction"]), math.sqrt(2))


def test_a_real_scene_turns_as_one_glb_with_its_files(tmp_path):
    """bench_fidelity --rotate on a real scene: its files embedded in one GLB, then turned like a procedural one."""
    from tests.conftest import shared_path
    from workers.gltf.pack import embed_glb

    src = shared_path("scenes", "cornell-box-mcguire-khr-lights", "CornellBox-Original.gltf")
    flat = embed_glb(src)
    base, turned = _ingest(tmp_path, flat, "flat"), _ingest(tmp_path, rotated_glb(flat, 30.0), "turned")
    a = np.asarray(base.triangles, np.float64).reshape(-1, 3)
    b = np.asarray(turned.triangles, np.float64).reshape(-1, 3)
    np.testing.assert_allclose(b, a @ rotation_y(30.0).T, atol=1e-4)
    assert len(turned.lights) == len(base.lights) > 0
