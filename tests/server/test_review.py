"""Review cameras through the API (GET/PUT /v1/scenes/{id}/cameras), stored cameras in bakes, the check_points
field of GET /v1/bakes/{id}. A real service; tiny bakes (explicit small probe grids, a few paths per point)."""
from __future__ import annotations

import numpy as np

from tests.gltf_build import GltfBuilder, box_inward

EV = {"enabled": True, "surface_points": 64, "spp": 4, "previews": 0, "modes": ["direct", "leaking"],
      "points": {"points": [[2.0, 1.2, 2.0]], "regions": {"a": [0]}}}
CFG = {"place": {"counts": [3, 2, 2]}, "trace": {"rays_per_probe": 32, "relocate_iterations": 1},
       "light": {"bounces": 1}, "visibility": {"samples_per_cell": 2, "slabs": 1},
       "masks": {"clusters": 2, "sweeps": 10}, "evaluate": EV}
CAMS = [{"position": [1.0, 1.5, 2.0], "target": [3.0, 1.2, 2.0], "name": "room-a"},
        {"position": [7.0, 1.5, 2.0], "target": [5.0, 1.2, 2.0], "fov_y": 70.0}]


def _stage(bake, name):
    return next(s for s in bake["stages"] if s["name"] == name)


def test_review_cameras_get_put_and_bakes_use_them(running, scene_files):
    c = running.client
    sid = running.upload(scene_files["two-rooms"]).json()["id"]
    r = c.get(f"/v1/scenes/{sid}/cameras")
    assert r.status_code == 200 and r.json() == {"scene_id": sid, "source": "auto", "cameras": [], "from_bake": None}
    assert c.get("/v1/scenes/nope/cameras").status_code == 404
    assert c.put("/v1/scenes/nope/cameras", json={"cameras": CAMS}).status_code == 404
    bad = c.put(f"/v1/scenes/{sid}/cameras", json={"cameras": [{"position": [0, 0, 0]}]})
    assert bad.status_code == 422 and bad.json()["error"]["code"]
    assert c.put(f"/v1/scenes/{sid}/cameras", json={"cameras": CAMS * 9}).status_code == 422   # > 16

    r = c.put(f"/v1/scenes/{sid}/cameras", json={"cameras": CAMS})
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["source"] == "stored" and [x["name"] for x in doc["cameras"]] == ["room-a", "review-1"]
    assert doc["cameras"][1]["fov_y"] == 70.0 and c.get(f"/v1/scenes/{sid}/cameras").json() == doc

    # a bake uses the stored cameras (recorded in its config and manifest) and shows its check points
    bid = c.post("/v1/bakes", json={"scene_id": sid, "config": CFG}).json()["id"]
    b = running.wait_bake(bid, timeout=180)
    assert b["status"] == "succeeded", b["error"]
    ev = _stage(b, "evaluate")["stats"]
    assert [x["position"] for x in ev["cameras"]] == [x["position"] for x in CAMS] and ev["camera_source"] == "config"
    assert ev["cameras"][1]["fov"] == 70.0 and b["config"]["evaluate"]["cameras"][0]["name"] == "room-a"
    cp = b["check_points"]
    assert cp["points"] == [[2.0, 1.2, 2.0]] and np.shape(cp["reference_indirect"]) == (1, 6, 3)
    assert np.shape(cp["reference_stderr"]) == (1, 6, 3) and set(cp["modes"]) == {"direct", "leaking"}
    assert np.shape(cp["modes"]["leaking"]) == (1, 6, 3) and np.asarray(cp["reference_indirect"]).sum() > 0
    assert "leaking.region.a.mean_ratio" in b["metrics"]
    art = c.get(f"/v1/bakes/{bid}/artifacts/check_points").json()
    assert art["reference_indirect"] == cp["reference_indirect"]

    # other cameras: a new reference; the same cameras again with another probe grid: the cached one
    c.put(f"/v1/scenes/{sid}/cameras", json={"cameras": CAMS[:1]})
    b2 = running.wait_bake(c.post("/v1/bakes", json={"scene_id": sid, "config": CFG}).json()["id"], timeout=180)
    assert b2["status"] == "succeeded" and not _stage(b2, "reference")["cached"]
    assert len(_stage(b2, "evaluate")["stats"]["cameras"]) == 1
    cfg3 = {**CFG, "place": {"counts": [4, 2, 3]}}
    b3 = running.wait_bake(c.post("/v1/bakes", json={"scene_id": sid, "config": cfg3}).json()["id"], timeout=180)
    assert b3["status"] == "succeeded" and _stage(b3, "reference")["cached"] and not _stage(b3, "place")["cached"]
    assert _stage(b3, "evaluate")["stats"]["cameras"] == _stage(b2, "evaluate")["stats"]["cameras"]

    # removed: automatic again, showing what the latest evaluated bake used
    doc = c.put(f"/v1/scenes/{sid}/cameras", json={"cameras": []}).json()
    assert doc["source"] == "auto" and doc["from_bake"] == b3["id"] and len(doc["cameras"]) == 1


def test_gltf_cameras_are_the_review_cameras(running, tmp_path):
    g = GltfBuilder()
    pos, nrm, idx = box_inward([-2, 0, -2], [2, 2.5, 2])
    g.mesh(pos, idx, normals=nrm, material=g.material(pbrMetallicRoughness={"metallicFactor": 0.0}))
    g.point_light([0, 2, 0], 10.0)
    g.doc["cameras"] = [{"type": "perspective", "name": "Main View", "perspective": {"yfov": 0.8, "znear": 0.1}},
                        {"type": "orthographic", "orthographic": {"xmag": 1, "ymag": 1, "znear": 0, "zfar": 9}}]
    g.doc["nodes"] += [{"camera": 0, "translation": [0.0, 1.2, 1.5]}, {"camera": 1}]
    g.doc["scenes"][0]["nodes"] += [len(g.doc["nodes"]) - 2, len(g.doc["nodes"]) - 1]
    path = tmp_path / "room.glb"
    path.write_bytes(g.glb())
    sid = running.upload(path).json()["id"]
    doc = running.client.get(f"/v1/scenes/{sid}/cameras").json()
    assert doc["source"] == "gltf" and len(doc["cameras"]) == 1         # the orthographic one is skipped
    cam = doc["cameras"][0]
    assert cam["name"] == "main-view" and np.allclose(cam["position"], [0, 1.2, 1.5])
    assert np.allclose(cam["target"], [0, 1.2, 0.5]) and abs(cam["fov_y"] - np.degrees(0.8)) < 1e-6
