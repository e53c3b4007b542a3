"""The OpenAPI document says what the service does (server/api/openapi.py, server/api/schemas.py): every operation
has a response schema, declares the 4xx it answers (with Kiln's error shape, never FastAPI's HTTPValidationError),
the upload has a request body, and the docs' assets are Kiln's own. The real responses are checked against this
document by tests/server/test_schemathesis.py."""
from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient

from server.api.guard import needs_key

ERROR_REF = "#/components/schemas/ErrorResponse"


@pytest.fixture(scope="module")
def app_client(tmp_path_factory):
    """The app without its lifespan (no Redis, no data): /openapi.json, /docs and /redoc need neither."""
    from server.config import Settings
    from server.main import create_app

    app = create_app(Settings(data=tmp_path_factory.mktemp("openapi") / "data", redis_url="redis://127.0.0.1:1"))
    return TestClient(app)


@pytest.fixture(scope="module")
def doc(app_client):
    return app_client.get("/openapi.json").json()


def _ops(doc):
    for path, item in doc["paths"].items():
        for method, op in item.items():
            yield method.upper(), path, op


def _resolve(doc, schema):
    while "$ref" in schema:
        schema = doc["components"]["schemas"][schema["$ref"].rsplit("/", 1)[-1]]
    return schema


def test_every_operation_has_a_response_schema(doc):
    ops = list(_ops(doc))
    assert len(ops) >= 19
    for method, path, op in ops:
        ok = {c: r for c, r in op["responses"].items() if c.startswith("2")}
        assert ok, f"{method} {path} declares no 2xx"
        for code, r in ok.items():
            if code == "204":
                assert not r.get("content"), f"{method} {path} 204 has a body"
                continue
            content = r.get("content")
            assert content, f"{method} {path} {code} has no content"
            for media, m in content.items():
                schema = m.get("schema")
                assert schema, f"{method} {path} {code} {media} has no schema"
                # a named model (server/api/schemas.py), not FastAPI's empty default; but the config's JSON
                # Schema (a JSON Schema document) and a json artifact (a file of the bundle, proto/bundle.md)
                if media == "application/json" and path not in ("/v1/config/schema",
                                                                 "/v1/bakes/{bake_id}/artifacts/{name}"):
                    assert "$ref" in schema, f"{method} {path} {code} answers an undocumented JSON shape: {schema}"
                    assert _resolve(doc, schema).get("properties"), f"{method} {path} {code}"


def test_every_operation_declares_its_4xx_with_the_real_error_shape(doc):
    schemas = doc["components"]["schemas"]
    assert "HTTPValidationError" not in schemas and "ValidationError" not in schemas
    err = schemas["ErrorResponse"]
    assert err["required"] == ["error"] and err["additionalProperties"] is False
    detail = _resolve(doc, err["properties"]["error"])
    assert set(detail["required"]) == {"code", "message"}
    assert detail["properties"]["code"]["type"] == "string" and detail["properties"]["message"]["type"] == "string"

    for method, path, op in _ops(doc):
        codes = {int(c) for c in op["responses"] if c.startswith("4")}
        params = {p["name"]: p for p in op.get("parameters", [])}
        in_path = [p for p in params.values() if p["in"] == "path"]
        # what the app does, whatever the route: the key check, the JSON body cap, unknown ids, validation
        if needs_key(path):
            assert 401 in codes, f"{method} {path}: the key check answers 401"
            assert op["security"] == [{"apiKey": []}], f"{method} {path}"
        else:
            assert 401 not in codes and "security" not in op, f"{method} {path} needs no key"
        if method in ("POST", "PUT", "PATCH") and path != "/v1/scenes":
            assert 413 in codes, f"{method} {path}: the JSON body cap answers 413"
        if in_path:
            assert 404 in codes, f"{method} {path}: an unknown id answers 404"
        validated = "requestBody" in op or any(p["in"] == "query" and (p.get("required") or "enum" in str(p)
                                                                       or "minimum" in str(p)) for p in params.values())
        if validated:
            assert 422 in codes, f"{method} {path}: validation answers 422"
        for code in codes:
            content = op["responses"][str(code)]["content"]
            assert list(content) == ["application/json"], f"{method} {path} {code}"
            ref = content["application/json"]["schema"]["$ref"]
            shape = _resolve(doc, {"$ref": ref})
            assert list(shape["properties"]) == ["error"], f"{method} {path} {code}: {ref}"
            assert ref == ERROR_REF or _resolve(doc, shape["properties"]["error"])["required"] == ["code", "message"]


def test_known_refusals_are_declared(doc):
    """The codes the routes raise (grep ApiError in server/api/routes) are in their operations."""
    expect = {
        ("POST", "/v1/scenes"): {400, 401, 408, 413, 415, 422, 429},
        ("DELETE", "/v1/scenes/{scene_id}"): {401, 404, 409},
        ("POST", "/v1/bakes"): {401, 404, 413, 422, 429},
        ("POST", "/v1/bakes/{bake_id}/cancel"): {401, 404, 409, 413},
        ("GET", "/v1/bakes/{bake_id}/bundle"): {400, 401, 404, 409, 416},
        ("GET", "/v1/bakes/{bake_id}/artifacts/{name}"): {400, 401, 404, 416},
        ("POST", "/v1/bakes/{bake_id}/relight"): {401, 404, 409, 413, 422},
        ("GET", "/v1/compare"): {401, 404, 409, 422},
    }
    got = {(m, p): {int(c) for c in op["responses"] if c.startswith("4")} for m, p, op in _ops(doc)}
    for key, codes in expect.items():
        assert got[key] == codes, key
    refused = doc["paths"]["/v1/bakes"]["post"]["responses"]["422"]["content"]["application/json"]["schema"]
    over = _resolve(doc, _resolve(doc, refused)["properties"]["error"])
    assert {"estimate", "limits", "over_budget"} <= set(over["properties"])


def test_the_upload_documents_its_request_body(doc):
    op = doc["paths"]["/v1/scenes"]["post"]
    body = op["requestBody"]
    assert body["required"] is True
    content = body["content"]
    for media in ("model/gltf-binary", "application/zip", "application/octet-stream"):
        assert content[media]["schema"] == {"type": "string", "format": "binary"}
    form = content["multipart/form-data"]["schema"]
    assert form["required"] == ["file"] and form["properties"]["file"]["format"] == "binary"
    names = {(p["in"], p["name"]) for p in op["parameters"]}
    assert {("header", "X-Filename"), ("query", "filename")} <= names
    assert set(op["responses"]) >= {"200", "201"}


def test_the_event_stream_documents_its_events(doc):
    content = doc["paths"]["/v1/bakes/{bake_id}/events"]["get"]["responses"]["200"]["content"]
    assert list(content) == ["text/event-stream"]
    data = content["text/event-stream"]["schema"]["properties"]["data"]
    refs = [s.get("$ref") for s in data["contentSchema"]["anyOf"]]
    assert "#/components/schemas/BakeSnapshot" in refs
    assert "BakeSnapshot" in doc["components"]["schemas"]


def test_docs_load_their_assets_from_kiln(app_client):
    for page in ("/docs", "/redoc"):
        r = app_client.get(page)
        assert r.status_code == 200
        urls = re.findall(r"""(?:src|href)=["']([^"']+)["']""", r.text)
        assert urls, page
        for url in urls:
            assert url.startswith("/"), f"{page} loads {url} from another host"
            assert app_client.get(url).status_code == 200, url
    assert '"validatorUrl": null' in app_client.get("/docs").text
