"""A scene's quality thresholds through the API (GET/PUT /v1/scenes/{id}/thresholds, server/api/routes/thresholds.py):
stored with the scene, validated with the gates grammar (server/gates.py), checked per bake with the same code,
another team's scene unseen. A real service (embedded Redis, real workers) and one tiny evaluated bake."""
from __future__ import annotations

from server import gates

RED = {"Authorization": "Bearer red-key-123"}
BLUE = {"Authorization": "Bearer blue-key-456"}
CFG = {"place": {"counts": [3, 2, 2]}, "trace": {"rays_per_probe": 16, "relocate_iterations": 1},
       "light": {"bounces": 1}, "visibility": {"samples_per_cell": 2, "slabs": 1},
       "masks": {"clusters": 2, "sweeps": 5},
       "evaluate": {"enabled": True, "cameras": 1, "width": 32, "height": 24, "spp": 2, "repeats": 1,
                    "previews": 0, "flip": False, "surface_points": 32, "modes": ["direct", "leaking"]}}


def test_thresholds_round_trip_refusals_teams_and_per_bake_results(service, scene_files):
    service.start_workers()
    c = service.start_app(api_keys="red:red-key-123,blue:blue-key-456")
    r = service.upload(scene_files["two-rooms"], headers=RED)
    assert r.status_code in (200, 201), r.text
    sid = r.json()["id"]
    url = f"/v1/scenes/{sid}/thresholds"

    empty = c.get(url, headers=RED)
    assert empty.status_code == 200, empty.text
    assert empty.json() == {"scene_id": sid, "thresholds": [], "gates": [], "bakes": []}

    # a bad expression: 422 in the error shape, naming the bad one; nothing stored
    bad = c.put(url, headers=RED, json={"thresholds": ["leaking.leak > 0.5", "leaking.rmse >> 0.1"]})
    assert bad.status_code == 422, bad.text
    err = bad.json()["error"]
    assert err["code"] == "invalid_threshold" and "thresholds[1]" in err["message"]
    assert "leaking.rmse >> 0.1" in err["message"] and "leaking.leak > 0.5" not in err["message"]
    assert c.put(url, headers=RED, json={"thresholds": ["x < 1e999"]}).status_code == 422   # non-finite
    assert c.put(url, headers=RED, json={"thresholds": "leaking.leak > 0.5"}).json()["error"]["code"]
    assert c.get(url, headers=RED).json()["thresholds"] == []

    # round trip (texts stripped), and the scene record shows them
    texts = ["leaking.leak > 0.999", " *.rmse >= 0 ", "nope.metric < 1"]
    put = c.put(url, headers=RED, json={"thresholds": texts})
    assert put.status_code == 200, put.text
    doc = put.json()
    assert doc["thresholds"] == ["leaking.leak > 0.999", "*.rmse >= 0", "nope.metric < 1"]
    assert doc["gates"][0] == {"text": "leaking.leak > 0.999", "metric": "leaking.leak", "op": ">", "value": 0.999}
    assert c.get(url, headers=RED).json() == doc
    assert c.get(f"/v1/scenes/{sid}", headers=RED).json()["thresholds"] == doc["thresholds"]

    # another team: 404 for both, and its own copy of the same file has no thresholds
    assert c.get(url, headers=BLUE).status_code == 404
    other = c.put(url, headers=BLUE, json={"thresholds": ["a > 1"]})
    assert other.status_code == 404 and other.json()["error"]["code"] == "scene_not_found"
    assert c.get(url, headers=RED).json()["thresholds"] == doc["thresholds"]
    assert c.get("/v1/scenes/nope/thresholds", headers=RED).status_code == 404

    # a bake: each threshold checked against its metrics with the gates code
    bid = c.post("/v1/bakes", headers=RED, json={"scene_id": sid, "config": CFG}).json()["id"]
    b = service.wait_bake(bid, timeout=180, headers=RED)
    assert b["status"] == "succeeded", b["error"]
    doc = c.get(url, headers=RED).json()
    assert [x["bake_id"] for x in doc["bakes"]] == [bid]
    res = {x["text"]: x for x in doc["bakes"][0]["results"]}
    assert res["leaking.leak > 0.999"]["passed"] and set(res["leaking.leak > 0.999"]["matched"]) == {"leaking.leak"}
    rmse = res["*.rmse >= 0"]       # every mode's rmse is >= 0: the gate fails on each
    assert not rmse["passed"] and {"direct.rmse", "leaking.rmse"} <= set(rmse["failing"])
    assert not res["nope.metric < 1"]["passed"] and res["nope.metric < 1"]["matched"] == {}
    assert "no metric" in res["nope.metric < 1"]["message"]
    assert doc["bakes"][0]["passed"] is False
    # the same answer as the CLI's code on the bake's manifest
    gs = gates.parse_gates(doc["thresholds"])
    failed = gates.check(gs, gates.manifest_metrics(_manifest(service, bid)))
    assert {g.text for g in failed} == {t for t, x in res.items() if not x["passed"]}

    # only passing thresholds: the bake passes; an empty list removes them
    ok = c.put(url, headers=RED, json={"thresholds": ["leaking.leak > 0.999"]}).json()
    assert ok["bakes"][0]["passed"] is True
    assert c.put(url, headers=RED, json={"thresholds": []}).json()["thresholds"] == []
    assert c.get(f"/v1/scenes/{sid}", headers=RED).json().get("thresholds") is None


def _manifest(service, bake_id: str) -> dict:
    from persist.catalog import Catalog

    return Catalog(service.data / "kiln.db").get_bake(bake_id)["manifest"]
