"""Hostile input through the real app (issue 15, the input half): non-finite numbers and coerced types refused
with 422 naming the field, stored non-finite data that can never make a response 500, bad scenes refused at
upload with a code, bounded list pagination, valid input that used to be refused, error messages without temp
paths or object addresses, and the JSON error shape for malformed requests.

The app runs on an embedded Redis with its real ingest process pool; no RQ worker is needed (bakes stay
queued), so one service serves the whole module.
"""
from __future__ import annotations

import io
import json
import unicodedata
import urllib.parse
import zipfile

import numpy as np
import pytest

from tests.conftest import Service
from tests.workers.gltf.builders import QUAD, Gltf, glb_bytes, minimal, png_bytes, write_glb

JSON = {"Content-Type": "application/json"}
LFS_POINTER = (b"version https://git-lfs.github.com/spec/v1\n"
               b"oid sha256:4d7a214614ab2935c943f9e0ff69d22eadbb8f32b1258daaa5e2ca24d17e2393\nsize 12345\n")


@pytest.fixture(scope="module")
def svc(tmp_path_factory):
    s = Service(tmp_path_factory.mktemp("hostile") / "data")
    try:
        s.start_app()
        yield s
    finally:
        s.close()


@pytest.fixture(scope="module")
def scene_id(svc, tmp_path_factory):
    glb = write_glb(tmp_path_factory.mktemp("scene") / "quad.glb", minimal()).read_bytes()
    r = svc.client.post("/v1/scenes", content=glb, headers={"X-Filename": "quad.glb"})
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


def _error(r, status: int, code: str, *fields: str) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/json"), r.headers
    err = r.json()["error"]
    assert err["code"] == code, err
    for f in fields:
        assert f in err["message"], err
    return err


def _glb(g: Gltf) -> bytes:
    import copy

    g = copy.deepcopy(g)
    for png in g.images:
        g.doc.setdefault("images", []).append({"bufferView": g.view(png), "mimeType": "image/png"})
    g.doc["buffers"] = [{"byteLength": len(g.bin)}]
    return glb_bytes(g.doc, g.bin)


def _zip(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


def _gltf_doc(g: Gltf, uri: str) -> bytes:
    doc = json.loads(json.dumps(g.doc))
    doc["buffers"] = [{"byteLength": len(g.bin), "uri": urllib.parse.quote(uri)}]
    return json.dumps(doc, ensure_ascii=False).encode()


# ---------------------------------------------------------------------------------------------- item 1


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_non_finite_literals_in_the_bake_config_are_422(svc, scene_id, literal):
    body = ('{"scene_id": "%s", "config": {"scene": {"lights": [{"type": "point", "position": [0, 1, 0], '
            '"range": %s}]}}}' % (scene_id, literal))
    _error(svc.client.post("/v1/bakes", content=body, headers=JSON), 422, "invalid_config",
           "config.scene.lights.0.range", "JSON has no NaN or Infinity")
    assert svc.client.get("/v1/bakes", params={"scene_id": scene_id, "status": "queued"}).json()["total"] == 0


def test_non_finite_literals_in_the_relight_body_are_422(svc):
    body = '{"lights": [{"type": "point", "position": [0, NaN, 0]}]}'
    _error(svc.client.post("/v1/bakes/nope/relight", content=body, headers=JSON), 422, "invalid_request",
           "lights.0.position.1", "JSON has no NaN or Infinity")
    body = '{"lights": [], "lightmap": Infinity}'
    _error(svc.client.post("/v1/bakes/nope/relight", content=body, headers=JSON), 422, "invalid_request",
           "lightmap", "JSON has no NaN or Infinity")
    # the models refuse them too, whatever the JSON parser let through (proto.models._Strict)
    from pydantic import ValidationError

    from proto.models import LightConfig

    with pytest.raises(ValidationError, match="finite number"):
        LightConfig.model_validate({"type": "point", "position": [0, float("nan"), 0]})


@pytest.mark.parametrize("config, field", [
    ({"seed": "4"}, "config.seed"),
    ({"seed": True}, "config.seed"),
    ({"trace": {"rays_per_probe": "256"}}, "config.trace.rays_per_probe"),
    ({"place": {"counts": [4, True, 4]}}, "config.place.counts.1"),
    ({"place": {"spacing": "0.5"}}, "config.place.spacing"),
    ({"light": {"sh_order": True}}, "config.light.sh_order"),
    ({"prt": {"enabled": 1}}, "config.prt.enabled"),
    ({"scene": {"use_scene_lights": "false"}}, "config.scene.use_scene_lights"),
    ({"masks": {"sweeps": 10.5}}, "config.masks.sweeps"),
])
def test_strict_number_and_boolean_types(svc, scene_id, config, field):
    _error(svc.client.post("/v1/bakes", json={"scene_id": scene_id, "config": config}), 422, "invalid_config",
           field)


def test_relight_lightmap_must_be_a_boolean(svc):
    _error(svc.client.post("/v1/bakes/nope/relight", json={"lights": [], "lightmap": "yes"}), 422,
           "invalid_request", "lightmap")


def test_integers_written_as_floats_are_accepted_in_the_config(svc, scene_id):
    c = svc.client
    r = c.post("/v1/bakes", json={"scene_id": scene_id,
                                  "config": {"seed": 7.0, "place": {"counts": [4.0, 3, 2.0]},
                                             "trace": {"rays_per_probe": 64.0, "max_offset": 0}}})
    assert r.status_code == 202, r.text
    bid = r.json()["id"]
    cfg = c.get(f"/v1/bakes/{bid}").json()["config"]
    assert cfg["seed"] == 7 and cfg["place"]["counts"] == [4, 3, 2] and cfg["trace"]["rays_per_probe"] == 64
    assert cfg["trace"]["max_offset"] == 0.0
    assert c.delete(f"/v1/bakes/{bid}").status_code == 204


@pytest.mark.parametrize("light, field", [
    ({"type": "point", "position": [0, 1, 0], "intensity": 1e39}, "config.scene.lights.0.intensity"),
    ({"type": "point", "position": [0, 1, 0], "color": [1e308, 1, 1]}, "config.scene.lights.0.color"),
    ({"type": "point", "position": [1e300, 1, 0]}, "config.scene.lights.0"),
    ({"type": "directional", "direction": [0, -1e300, 0]}, "config.scene.lights.0"),
])
def test_absurd_config_magnitudes_are_refused_at_post(svc, scene_id, light, field):
    _error(svc.client.post("/v1/bakes", json={"scene_id": scene_id, "config": {"scene": {"lights": [light]}}}),
           422, "invalid_config", field)


def test_absurd_prt_and_camera_magnitudes(svc, scene_id):
    c = svc.client
    _error(c.post("/v1/bakes", json={"scene_id": scene_id,
                                    "config": {"prt": {"scenario": {"color_max": [1e308, 1, 1]}}}}),
           422, "invalid_config", "config.prt.scenario.color_max")
    _error(c.post("/v1/bakes", json={"scene_id": scene_id, "config": {"place": {"box": {
        "min": [-1e30, 0, 0], "max": [1, 1, 1]}}}}), 422, "invalid_config", "config.place.box")


def test_stored_non_finite_data_never_makes_a_500(svc, scene_id):
    """A bake and a scene stored before these checks, holding NaN/inf: every route still answers."""
    c = svc.client
    cat = c.app.state.catalog
    nan, inf = float("nan"), float("inf")
    config = {"scene": {"lights": [{"type": "point", "position": [0, nan, 0], "range": inf}]}}
    bid = cat.create_bake("default", scene_id, config, [("ingest", "1" * 64), ("place", "2" * 64)])
    cat.update_stage(bid, "ingest", status="succeeded", progress=1.0, seconds=0.1,
                     stats={"lights": [{"intensity": inf}], "residual": nan})
    cat.set_bake_status(bid, "running", error={"message": "x", "value": -inf})
    for r in (c.get(f"/v1/bakes/{bid}"), c.get("/v1/bakes"), c.get("/v1/bakes", params={"scene_id": scene_id})):
        assert r.status_code == 200, r.text
        json.loads(r.text)  # strict JSON: no NaN/Infinity literals
    b = c.get(f"/v1/bakes/{bid}").json()
    assert b["config"]["scene"]["lights"][0]["range"] is None
    assert b["stages"][0]["stats"]["lights"][0]["intensity"] is None
    r = c.post(f"/v1/bakes/{bid}/cancel")
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    with c.stream("GET", f"/v1/bakes/{bid}/events") as r:
        assert r.status_code == 200
        data = [json.loads(line[5:]) for line in r.iter_lines() if line.startswith("data:")]
    assert data[-1]["status"] == "cancelled" and data[-1]["error"]["value"] is None
    # a scene summary holding NaN
    summary = {"id": "e" * 64, "triangles": 2, "bounds": [[0, 0, nan], [1, 1, inf]], "lights": 0,
               "materials": 1, "warnings": []}
    cat.add_scene("default", "e" * 64, summary, "old.glb")
    for r in (c.get(f"/v1/scenes/{'e' * 64}"), c.get("/v1/scenes")):
        assert r.status_code == 200, r.text
        json.loads(r.text)
    assert c.get(f"/v1/scenes/{'e' * 64}").json()["bounds"][0][2] is None
    assert c.delete(f"/v1/bakes/{bid}").status_code == 204
    assert c.delete(f"/v1/scenes/{'e' * 64}").status_code == 204


# ---------------------------------------------------------------------------------------------- item 6


def _scaled() -> bytes:
    g = Gltf()
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3]), scale=[1e20, 1e20, 1e20])
    return _glb(g)


def _emissive(factor, strength) -> bytes:
    g = Gltf()
    g.doc["materials"] = [{"emissiveFactor": factor,
                           "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}}]
    g.node(mesh=g.mesh(QUAD, [0, 1, 2, 0, 2, 3], material=0))
    return _glb(g)


def _light(light) -> bytes:
    g = minimal()
    g.doc["extensions"] = {"KHR_lights_punctual": {"lights": [light]}}
    g.node(translation=[0, 2, 0], extensions={"KHR_lights_punctual": {"light": 0}})
    return _glb(g)


def _point() -> bytes:
    g = Gltf()
    g.node(mesh=g.mesh(np.ones((4, 3), np.float32), [0, 1, 2, 0, 2, 3]))
    return _glb(g)


def _line() -> bytes:
    g = Gltf()
    g.node(mesh=g.mesh(np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], np.float32), [0, 1, 2, 1, 2, 3]))
    return _glb(g)


def _lfs_buffer() -> bytes:
    g = minimal()
    return _zip({"m/scene.gltf": _gltf_doc(g, "scene.bin"), "m/scene.bin": LFS_POINTER})


@pytest.mark.parametrize("make, code", [
    (_scaled, "absurd_magnitude"),
    (lambda: _emissive([1, 1, 1], 1e60), "absurd_magnitude"),
    (lambda: _emissive([-1, 0, 0], 1.0), "negative_emissive"),
    (lambda: _light({"type": "point", "intensity": 1e39}), "absurd_magnitude"),
    (lambda: _light({"type": "point", "color": [1e308, 1, 1]}), "absurd_magnitude"),
    (lambda: _light({"type": "point", "color": [-1, 1, 1]}), "negative_light"),
    (_point, "zero_extent"),
    (_line, "degenerate_triangles"),
    (_lfs_buffer, "text_buffer"),
], ids=["scale", "emissive", "negative_emissive", "intensity", "color", "negative_color", "zero_extent",
        "degenerate", "lfs_pointer"])
def test_bad_scenes_refused_at_upload(svc, make, code):
    before = svc.client.get("/v1/scenes").json()["total"]
    err = _error(svc.client.post("/v1/scenes", content=make(), headers={"X-Filename": "bad.glb"}), 422, code)
    assert len(err["message"]) > 10
    assert svc.client.get("/v1/scenes").json()["total"] == before


# ---------------------------------------------------------------------------------------------- item 10


@pytest.mark.parametrize("path", ["/v1/scenes", "/v1/bakes"])
def test_list_pagination_is_bounded(svc, path):
    c = svc.client
    for params in ({"offset": "9223372036854775808"}, {"offset": str(2**70)}, {"offset": "-1"},
                   {"limit": "0"}, {"limit": "-5"}, {"limit": "ten"}, {"offset": "1.5"}):
        err = _error(c.get(path, params=params), 422, "invalid_request")
        assert next(iter(params)) in err["message"], (params, err)
    r = c.get(path, params={"limit": str(10**30)})
    assert r.status_code == 200 and r.json()["limit"] == 500, r.text
    r = c.get(path, params={"limit": "100000", "offset": "1000000000"})
    assert r.status_code == 200 and r.json()["items"] == [] and r.json()["limit"] == 500


# ---------------------------------------------------------------------------------------------- item 11


def test_valid_input_that_was_refused_is_accepted(svc):
    c = svc.client
    g = minimal()
    # '..' that stays inside the zip, in a URI and in a member name
    r = c.post("/v1/scenes", content=_zip({"m/scene.gltf": _gltf_doc(g, "textures/../data/scene.bin"),
                                           "m/data/scene.bin": bytes(g.bin)}), headers={"X-Filename": "a.zip"})
    assert r.status_code in (200, 201), r.text
    sid = r.json()["id"]
    r = c.post("/v1/scenes", content=_zip({"m/scene.gltf": _gltf_doc(g, "scene.bin"),
                                           "m/x/../scene.bin": bytes(g.bin)}), headers={"X-Filename": "b.zip"})
    assert r.status_code == 200 and r.json()["id"] == sid, r.text
    # a URI in NFC, the member stored NFD (macOS), and the other way round
    name = "Kühl naïve.bin"
    for uri_form, member_form in (("NFC", "NFD"), ("NFD", "NFC")):
        files = {"scene.gltf": _gltf_doc(g, unicodedata.normalize(uri_form, name)),
                 unicodedata.normalize(member_form, name): bytes(g.bin)}
        r = c.post("/v1/scenes", content=_zip(files), headers={"X-Filename": "c.zip"})
        assert r.status_code == 200 and r.json()["id"] == sid, r.text
    # integers written as floats (JSON Schema integers), in a .glb's JSON chunk
    doc = json.loads(json.dumps(g.doc))
    doc["buffers"] = [{"byteLength": float(len(g.bin))}]
    for acc in doc["accessors"]:
        acc["count"], acc["componentType"] = float(acc["count"]), float(acc["componentType"])
    doc["nodes"][0]["mesh"] = 0.0
    r = c.post("/v1/scenes", content=glb_bytes(doc, g.bin), headers={"X-Filename": "d.glb"})
    assert r.status_code == 200 and r.json()["id"] == sid, r.text
    r = c.post("/v1/scenes", content=_zip({"m/scene.gltf": _gltf_doc(g, "../../scene.bin"),
                                           "scene.bin": bytes(g.bin)}))
    _error(r, 422, "path_traversal")  # above the zip's root: still refused


# ---------------------------------------------------------------------------------------------- item 9 (input)


def _bad_png_glb() -> bytes:
    g = minimal()
    tex = g.image(b"\x89PNG but not really an image" * 4)
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}}]
    g.doc["meshes"][0]["primitives"][0]["material"] = 0
    return _glb(g)


def _bad_png_zip(payload: bytes) -> bytes:
    g = minimal()
    doc = json.loads(_gltf_doc(g, "scene.bin"))
    doc["images"] = [{"uri": "tex/a.png"}]
    doc["textures"] = [{"source": 0}]
    doc["materials"] = [{"emissiveTexture": {"index": 0}}]
    doc["meshes"][0]["primitives"][0]["material"] = 0
    return _zip({"m/scene.gltf": json.dumps(doc).encode(), "m/scene.bin": bytes(g.bin), "m/tex/a.png": payload})


@pytest.mark.parametrize("make", [
    _bad_png_glb,
    lambda: _bad_png_zip(b"GIF89a, not a png" * 8),
    lambda: _bad_png_zip(LFS_POINTER),
    lambda: _bad_png_zip(png_bytes()[:40]),
    lambda: b"glTF\x02\x00\x00\x00\xff\xff\xff\x7f" + b"\x00" * 16,
    lambda: _zip({"a.gltf": b"{", "b.gltf": b"{"}),
    lambda: _zip({"m/scene.gltf": b'{"asset": {"version": "2.0"}, "buffers": [{"uri": "x.bin", "byteLength": 4}]}'}),
    lambda: b"PK\x03\x04" + b"\x00" * 64,
    lambda: LFS_POINTER,
], ids=["png_in_glb", "gif_in_zip", "lfs_image", "truncated_png", "truncated_glb", "two_models", "missing",
        "broken_zip", "lfs_model"])
def test_bad_upload_messages_carry_no_temp_paths_or_addresses(svc, make):
    r = svc.client.post("/v1/scenes", content=make(), headers={"X-Filename": "bad.zip"})
    assert 400 <= r.status_code < 500, r.text
    msg = r.json()["error"]["message"]
    assert "/tmp" not in msg and " at 0x" not in msg and str(svc.data) not in msg, msg


def test_malformed_requests_get_the_json_error_shape(svc, scene_id):
    c = svc.client
    err = _error(c.post("/v1/bakes", content=b'{"scene_id": ', headers=JSON), 422, "invalid_request")
    assert "not valid JSON" in err["message"]
    _error(c.post("/v1/bakes", content=b"\xff\xfe garbage", headers=JSON), 422, "invalid_request")
    _error(c.post("/v1/bakes", content=b"[" * 100_000 + b"]" * 100_000, headers=JSON), 422, "invalid_request")
    _error(c.post("/v1/bakes", content=json.dumps({"scene_id": scene_id}).encode(),
                  headers={"Content-Type": "text/plain"}), 422, "invalid_request")
    _error(c.post("/v1/bakes", content=b'"just a string"', headers=JSON), 422, "invalid_request")
    _error(c.get("/v1/nothing-here"), 404, "not_found")
    _error(c.put("/v1/bakes"), 405, "method_not_allowed")
    _error(c.get("/v1/bakes", params={"status": "bogus"}), 422, "invalid_request", "status")


def test_every_route_with_a_body_refuses_non_finite_json(svc):
    """Every JSON body goes through server.api.jsonbody.FiniteJSONRoute (new routers must use it)."""
    from fastapi.routing import APIRoute

    from server.api.jsonbody import FiniteJSONRoute

    def api_routes(routes):
        for r in routes:
            if isinstance(r, APIRoute):
                yield r
            if getattr(r, "original_router", None) is not None:  # FastAPI's lazily included routers
                yield from api_routes(r.original_router.routes)

    with_body = [r for r in api_routes(svc.client.app.router.routes) if r.body_field is not None]
    assert {"/v1/bakes", "/v1/bakes/{bake_id}/relight"} <= {r.path for r in with_body}
    assert [r.path for r in with_body if not isinstance(r, FiniteJSONRoute)] == []
