"""REST API v1 against a real service: embedded Redis, real RQ worker processes, the real app."""
from __future__ import annotations

import base64
import hashlib
import io
import json
import zipfile

import numpy as np
import pytest

from proto import bundle
from proto.models import BakeConfig
from proto.stages import expand
from tests.conftest import SMALL_EVALUATE, UNLIT, small_bake


def _gltf_from_glb(glb: bytes) -> bytes:
    """The same scene as .gltf with its buffer as a data: URI."""
    import struct

    jlen = struct.unpack_from("<I", glb, 12)[0]
    doc = json.loads(glb[20:20 + jlen])
    blen = struct.unpack_from("<I", glb, 20 + jlen)[0]
    bin_ = glb[28 + jlen:28 + jlen + blen]
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bin_).decode()
    return json.dumps(doc).encode()


def test_upload_formats_dedupe_and_listing(running, scene_files):
    c = running.client
    glb = scene_files["cornell"].read_bytes()
    r = c.post("/v1/scenes", content=glb, headers={"X-Filename": "cornell.glb"})
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["triangles"] > 0 and body["lights"] == 1 and body["materials"] >= 3
    assert np.allclose(body["bounds"], [[0, 0, 0], [1, 1, 1]], atol=1e-5)
    sid = body["id"]
    assert len(sid) == 64

    # the same scene again (raw): 200 with the same body
    r2 = c.post("/v1/scenes", content=glb)
    assert r2.status_code == 200 and r2.json()["id"] == sid
    # multipart
    r3 = c.post("/v1/scenes", files={"file": ("cornell.glb", glb, "model/gltf-binary")})
    assert r3.status_code == 200 and r3.json()["id"] == sid
    # .gltf with a data URI
    r4 = c.post("/v1/scenes", content=_gltf_from_glb(glb), headers={"X-Filename": "cornell.gltf"})
    assert r4.status_code == 200, r4.text
    assert r4.json()["id"] == sid
    # .zip holding the .gltf
    zbuf = io.BytesIO()
    with zipfile.ZipFile(zbuf, "w") as z:
        z.writestr("scene/cornell.gltf", _gltf_from_glb(glb))
    r5 = c.post("/v1/scenes", content=zbuf.getvalue(), headers={"X-Filename": "cornell.zip"})
    assert r5.status_code == 200, r5.text
    assert r5.json()["id"] == sid

    lst = c.get("/v1/scenes").json()
    assert lst["total"] == 1 and lst["items"][0]["id"] == sid
    assert c.get(f"/v1/scenes/{sid}").json()["triangles"] == body["triangles"]
    assert c.get("/v1/scenes/" + "0" * 64).status_code == 404


@pytest.mark.parametrize("payload, status, code", [
    (b"hello, not a model", 415, "not_gltf"),
    (b'{"asset": {"version": "2.0"}, "meshes": [', 422, "broken_json"),
    (b"glTF\x02\x00\x00\x00\xff\xff\xff\x7f" + b"\x00" * 16, 422, "truncated_glb"),
    (b'{"asset": {"version": "2.0"}, "buffers": [{"uri": "http://example.com/a.bin", "byteLength": 4}]}',
     422, "external_uri"),
    (b'{"asset": {"version": "2.0"}, "buffers": [{"uri": "../secret.bin", "byteLength": 4}]}',
     422, "path_traversal"),
    (b'{"asset": {"version": "2.0"}, "extensionsRequired": ["KHR_gaussian_splatting_fake"],'
     b' "extensionsUsed": ["KHR_gaussian_splatting_fake"]}', 422, "unsupported_extension"),
    (b"", 400, "empty_upload"),
])
def test_bad_uploads_get_4xx_with_code(running, payload, status, code):
    r = running.client.post("/v1/scenes", content=payload)
    assert r.status_code == status, r.text
    err = r.json()["error"]
    assert err["code"] == code and len(err["message"]) > 5
    assert running.client.get("/v1/scenes").json()["total"] == 0  # nothing half-written


def test_upload_over_size_limit_is_413(service, scene_files):
    from fastapi.testclient import TestClient

    from server.config import Settings
    from server.main import create_app

    service.start_workers(1)
    s = Settings(data=service.data, redis_url=service.redis.url, max_upload_mb=1)
    with TestClient(create_app(s)) as c:
        r = c.post("/v1/scenes", content=b"glTF" + b"\x00" * (2 * 2**20))
        assert r.status_code == 413 and r.json()["error"]["code"] == "too_large"
        # no Content-Length (a chunked stream) is cut off while streaming
        r = c.post("/v1/scenes", content=iter([b"\x00" * 2**19] * 4))
        assert r.status_code == 413
        assert not any((service.data / "uploads").iterdir())


def test_bake_lifecycle_artifacts_bundle_and_cache(running, scene_files):
    c = running.client
    sid = running.upload(scene_files["two-rooms"]).json()["id"]
    cfg = small_bake(place={"counts": [6, 3, 4]}, evaluate=SMALL_EVALUATE)   # evaluated: the reference is cached
    r = c.post("/v1/bakes", json={"scene_id": sid, "config": cfg})
    assert r.status_code == 202, r.text
    bid = r.json()["id"]
    assert r.json()["links"]["events"] == f"/v1/bakes/{bid}/events"
    b = running.wait_bake(bid)
    assert b["status"] == "succeeded", b
    assert [s["name"] for s in b["stages"]] == [st.name for st in expand(BakeConfig.model_validate(cfg))]
    assert all(s["status"] == "succeeded" and s["progress"] == 1.0 and s["seconds"] >= 0 for s in b["stages"])
    assert b["stages"][1]["stats"]["counts"] == [6, 3, 4]
    assert b["started"] and b["finished"] >= b["started"]

    names = {a["name"] for a in b["artifacts"]}
    assert {"lights", "probe_positions"} <= names
    # artifact with ETag / 304 / Range
    r = c.get(f"/v1/bakes/{bid}/artifacts/probe_positions")
    assert r.status_code == 200 and r.headers["etag"]
    full = r.content
    assert hashlib.sha256(full).hexdigest() == r.headers["etag"].strip('"')
    assert c.get(f"/v1/bakes/{bid}/artifacts/probe_positions",
                 headers={"If-None-Match": r.headers["etag"]}).status_code == 304
    r = c.get(f"/v1/bakes/{bid}/artifacts/probe_positions", headers={"Range": "bytes=10-99"})
    assert r.status_code == 206 and r.content == full[10:100]
    assert c.get(f"/v1/bakes/{bid}/artifacts/nope").status_code == 404
    assert c.get(f"/v1/bakes/{bid}/artifacts/ray_hits").status_code == 404  # internal: not in the bundle

    # the bundle zip opens and holds the grid
    r = c.get(f"/v1/bakes/{bid}/bundle")
    assert r.status_code == 200
    zpath = running.data / "b.zip"
    zpath.write_bytes(r.content)
    manifest, arrays = bundle.open_bundle(zpath)
    pos = arrays["probe_positions"]
    assert pos.shape == (4, 3, 6, 3)
    bounds = np.array(c.get(f"/v1/scenes/{sid}").json()["bounds"])
    assert np.allclose(pos[0, 0, 0], bounds[0], atol=1e-5) and np.allclose(pos[-1, -1, -1], bounds[1], atol=1e-5)
    assert manifest.grid["counts"] == [6, 3, 4]

    # same scene + config: done at once from cache
    r = c.post("/v1/bakes", json={"scene_id": sid, "config": cfg})
    assert r.json()["status"] == "succeeded"
    b2 = c.get(f"/v1/bakes/{r.json()['id']}").json()
    assert all(s["cached"] for s in b2["stages"])
    # only the place section changes: ingest is cached, place re-runs
    r = c.post("/v1/bakes", json={"scene_id": sid, "config": {**cfg, "place": {"spacing": 1.0}}})
    b3 = running.wait_bake(r.json()["id"])
    assert b3["status"] == "succeeded"
    assert b3["stages"][0]["cached"] and not any(s["cached"] for s in b3["stages"][1:] if s["name"] != "reference")
    assert next(s for s in b3["stages"] if s["name"] == "reference")["cached"]   # per scene: reads no probe stage

    # list with filters and pagination
    lst = c.get("/v1/bakes", params={"scene_id": sid, "status": "succeeded", "limit": 2}).json()
    assert lst["total"] == 3 and len(lst["items"]) == 2
    assert c.get("/v1/bakes", params={"status": "bogus"}).status_code == 422

    # a scene with bakes cannot be deleted; a bake can
    assert c.delete(f"/v1/scenes/{sid}").status_code == 409
    assert c.delete(f"/v1/bakes/{bid}").status_code == 204
    assert c.get(f"/v1/bakes/{bid}").status_code == 404


def test_sse_events_end_with_final_status(running, scene_files):
    c = running.client
    sid = running.upload(scene_files["cornell"]).json()["id"]
    bid = c.post("/v1/bakes", json={"scene_id": sid, "config": small_bake(place={"counts": [3, 3, 3]})}).json()["id"]
    events = []
    with c.stream("GET", f"/v1/bakes/{bid}/events") as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        ev = None
        for line in r.iter_lines():
            if line.startswith("event:"):
                ev = line[6:].strip()
            elif line.startswith("data:"):
                events.append((ev, json.loads(line[5:])))
    assert events[-1][0] == "status" and events[-1][1]["status"] == "succeeded"
    assert all(e == "progress" for e, _ in events[:-1]) and len(events) >= 2


def test_config_validation_names_the_field(running, scene_files):
    c = running.client
    sid = running.upload(scene_files["cornell"]).json()["id"]
    for cfg, field in [({"place": {"countz": [4, 4, 4]}}, "config.place.countz"),
                       ({"place": {"counts": [0, 4, 4]}}, "config.place.counts"),
                       ({"scene": {"sky": [1, -1, 0]}}, "config.scene.sky"),
                       ({"scene": {"lights": [{"type": "spot", "position": [0, 1, 0]}]}}, "config.scene.lights"),
                       ({"bogus": 1}, "config.bogus")]:
        r = c.post("/v1/bakes", json={"scene_id": sid, "config": cfg})
        assert r.status_code == 422, (cfg, r.text)
        err = r.json()["error"]
        assert err["code"] == "invalid_config" and field in err["message"], err
    r = c.post("/v1/bakes", json={"scene_id": "f" * 64})
    assert r.status_code == 404 and r.json()["error"]["code"] == "scene_not_found"


def test_cancel_a_running_bake(service, scene_files):
    service.start_workers(1, env={"KILN_FAULT_STAGE_DELAY": "3"})
    c = service.start_app()
    sid = service.upload(scene_files["cornell"]).json()["id"]
    bid = c.post("/v1/bakes", json={"scene_id": sid}).json()["id"]
    service.wait_bake(bid, until=("running",))
    r = c.post(f"/v1/bakes/{bid}/cancel")
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    b = service.wait_bake(bid)
    assert b["status"] == "cancelled"
    assert c.post(f"/v1/bakes/{bid}/cancel").status_code == 409
    import time
    time.sleep(4)  # the running stage notices at its next progress report and stores nothing more
    b = c.get(f"/v1/bakes/{bid}").json()
    assert b["status"] == "cancelled"
    assert b["stages"][-1]["status"] in ("cancelled", "pending")


def test_team_isolation_and_auth(service, scene_files):
    service.start_workers(1)
    c = service.start_app(api_keys="red:red-key-123,blue:blue-key-456")
    red = {"Authorization": "Bearer red-key-123"}
    blue = {"Authorization": "Bearer blue-key-456"}
    assert c.get("/v1/scenes").status_code == 401
    assert c.get("/v1/scenes", headers={"Authorization": "Bearer wrong-key-000"}).status_code == 401
    sid = service.upload(scene_files["cornell"], headers=red).json()["id"]
    bid = c.post("/v1/bakes", json={"scene_id": sid, "config": small_bake()}, headers=red).json()["id"]
    assert service.wait_bake(bid, headers=red)["status"] == "succeeded"
    assert c.get(f"/v1/scenes/{sid}", headers=blue).status_code == 404
    assert c.get(f"/v1/bakes/{bid}", headers=blue).status_code == 404
    assert c.get(f"/v1/bakes/{bid}/artifacts/lights", headers=blue).status_code == 404
    assert c.post("/v1/bakes", json={"scene_id": sid, "config": small_bake()}, headers=blue).status_code == 404
    assert c.get("/v1/bakes", headers=blue).json()["total"] == 0
    assert c.get("/v1/bakes", headers=red).json()["total"] == 1
    # blue uploads the same scene: its own record, same id
    r = service.upload(scene_files["cornell"], headers=blue)
    assert r.status_code == 201 and r.json()["id"] == sid


def test_health_metrics_and_schema(running, scene_files):
    c = running.client
    h = c.get("/healthz").json()
    assert h["status"] == "ok" and h["redis"] and h["catalog"]
    sid = running.upload(scene_files["cornell"]).json()["id"]
    bid = c.post("/v1/bakes", json={"scene_id": sid, "config": small_bake()}).json()["id"]
    running.wait_bake(bid)
    m = c.get("/metrics").text
    assert "kiln_queue_depth" in m
    assert 'kiln_bakes{status="succeeded"} 1.0' in m
    assert 'kiln_stage_duration_seconds_count{stage="place"} 1.0' in m
    schema = c.get("/v1/config/schema").json()
    assert "place" in schema["properties"]
    assert c.get("/docs").status_code == 200
    assert "Kiln" in c.get("/").text


def test_bake_warnings_in_the_api_and_after_a_restart(running, scene_files):
    c = running.client
    sid = running.upload(scene_files["two-rooms"]).json()["id"]
    bid = c.post("/v1/bakes", json={"scene_id": sid, "config": UNLIT}).json()["id"]
    b = running.wait_bake(bid)
    assert b["status"] == "succeeded", b
    unlit = [w for w in b["warnings"] if w["code"] == "unlit_scene"]
    assert len(unlit) == 1 and unlit[0]["stage"] == "ingest", b["warnings"]
    assert "nothing lights the scene" in unlit[0]["message"]
    assert b["warning_count"] == len(b["warnings"])
    assert all(set(w) == {"code", "message", "stage"} for w in b["warnings"])
    # the list carries the count, the bundle's manifest the same warnings
    item = next(i for i in c.get("/v1/bakes").json()["items"] if i["id"] == bid)
    assert item["warning_count"] == len(b["warnings"])
    zpath = running.data / "unlit.zip"
    zpath.write_bytes(c.get(f"/v1/bakes/{bid}/bundle").content)
    manifest, _ = bundle.open_bundle(zpath)
    assert [w.model_dump() for w in manifest.warnings] == b["warnings"]
    # a lit bake of the same scene has none
    lit = running.wait_bake(c.post("/v1/bakes", json={"scene_id": sid, "config": {
        **UNLIT, "scene": {"sky": [0.2, 0.2, 0.2]}}}).json()["id"])
    assert lit["status"] == "succeeded" and not any(w["code"] == "unlit_scene" for w in lit["warnings"])
    # the light stage's own warning: capped at one bounce, it cannot converge
    capped = running.wait_bake(c.post("/v1/bakes", json={"scene_id": sid, "config": {
        **UNLIT, "scene": {"sky": [0.2, 0.2, 0.2]}, "light": {"max_bounces": 1}}}).json()["id"])
    assert capped["status"] == "succeeded"
    assert [w["stage"] for w in capped["warnings"] if w["code"] == "not_converged"] == ["light"], capped["warnings"]
    # the warnings live in the catalog: a restarted server still returns them
    running.stop_app()
    c = running.start_app()
    again = c.get(f"/v1/bakes/{bid}").json()
    assert again["warnings"] == b["warnings"]
    # the same bake again finishes at once from the cache, with the same warnings
    r = c.post("/v1/bakes", json={"scene_id": sid, "config": UNLIT})
    assert r.json()["status"] == "succeeded"
    assert c.get(f"/v1/bakes/{r.json()['id']}").json()["warnings"] == b["warnings"]


def test_running_bake_shows_the_warnings_of_finished_stages(service, scene_files):
    import time

    service.start_workers(1, env={"KILN_FAULT_STAGE_DELAY": "1"})
    c = service.start_app()
    sid = service.upload(scene_files["two-rooms"]).json()["id"]
    bid = c.post("/v1/bakes", json={"scene_id": sid, "config": UNLIT}).json()["id"]
    deadline = time.monotonic() + 60
    while True:
        b = c.get(f"/v1/bakes/{bid}").json()
        if b["stages"][0]["status"] == "succeeded":
            break
        assert b["warnings"] == [] and time.monotonic() < deadline, b
        time.sleep(0.1)
    assert b["status"] == "running"
    assert [w["code"] for w in b["warnings"]] == ["unlit_scene"] and b["warning_count"] == 1
    # the SSE snapshots carry them too
    with c.stream("GET", f"/v1/bakes/{bid}/events") as r:
        for line in r.iter_lines():
            if line.startswith("data:"):
                assert [w["code"] for w in json.loads(line[5:])["warnings"]] == ["unlit_scene"]
                break
    assert c.post(f"/v1/bakes/{bid}/cancel").json()["warnings"] == b["warnings"]
