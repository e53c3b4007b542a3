"""The API docs work offline: ``/docs`` (Swagger UI) and ``/redoc`` of a real ``kiln serve``, in Chromium with
every request to another host aborted, render the operations of the OpenAPI document (server/api/openapi.py).

Each page records what it tried to load elsewhere (a CDN script, a font, the online validator badge): none may
be tried, and the page must show the API — the operations, their paths, the error model — not merely load.
"""
from __future__ import annotations

from urllib.parse import urlsplit

import pytest


@pytest.fixture
def offline_page(browser, kiln_server):
    ours = urlsplit(kiln_server.url).netloc
    ctx = browser.new_context(viewport={"width": 1280, "height": 900}, base_url=kiln_server.url)
    elsewhere: list[str] = []

    def route(r):
        url = r.request.url
        if urlsplit(url).netloc == ours or url.startswith(("data:", "blob:")):
            return r.continue_()
        elsewhere.append(url)
        return r.abort("internetdisconnected")

    ctx.route("**/*", route)
    pg = ctx.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.elsewhere, pg.script_errors = elsewhere, errors
    try:
        yield pg
    finally:
        ctx.close()


def _operations(kiln_server) -> list[tuple[str, str]]:
    doc = kiln_server.api("/openapi.json")
    return [(m.upper(), p) for p, item in doc["paths"].items() for m in item]


def test_swagger_ui_renders_every_operation_offline(offline_page, kiln_server):
    pg = offline_page
    pg.goto("/docs")
    pg.wait_for_selector(".opblock .opblock-summary-path", timeout=30_000)
    ops = _operations(kiln_server)
    shown = pg.eval_on_selector_all(
        ".opblock", "els => els.map(e => [e.querySelector('.opblock-summary-method').textContent.trim(), "
                    "e.querySelector('.opblock-summary-path').getAttribute('data-path')])")
    assert sorted(map(tuple, shown)) == sorted(ops)
    assert "Kiln" in pg.locator(".info .title").inner_text()
    # the upload's request body and the real error model are in the rendered document
    pg.locator("#operations-scenes-upload_scene_v1_scenes_post .opblock-summary").click()
    body = pg.locator("#operations-scenes-upload_scene_v1_scenes_post .opblock-section-request-body")
    body.wait_for(timeout=10_000)
    assert "model/gltf-binary" in body.inner_text()
    models = pg.eval_on_selector_all("section.models article[data-json-schema-level='0'] > div > button "
                                     ".json-schema-2020-12__title", "els => els.map(e => e.textContent.trim())")
    assert {"ErrorResponse", "ScenePublic", "BakePublic", "BakeSnapshot"} <= set(models), models
    assert "HTTPValidationError" not in models
    assert pg.locator(".btn.authorize").count() == 1          # the API-key scheme
    assert pg.elsewhere == [], f"/docs tried other hosts: {pg.elsewhere}"
    assert pg.script_errors == []


def test_redoc_renders_offline(offline_page, kiln_server):
    pg = offline_page
    pg.goto("/redoc")
    pg.wait_for_selector("[data-section-id^='tag/']", timeout=60_000)
    text = pg.locator("body").inner_text()
    for summary in ("Upload a scene", "Start a bake of a scene", "Relight a PRT bake", "Metric deltas of two bakes"):
        assert summary in text
    assert pg.locator("[data-section-id^='operation/']").count() == len(_operations(kiln_server))
    assert pg.elsewhere == [], f"/redoc tried other hosts: {pg.elsewhere}"
    assert pg.script_errors == []
