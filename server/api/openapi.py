"""The OpenAPI document as the service really behaves, and API docs that work offline.

FastAPI's generated document is adjusted once, on first use (``install`` replaces ``app.openapi``):

- the 422 that FastAPI adds to every route with parameters, its ``HTTPValidationError`` (``{"detail": [...]}``),
  is not what Kiln answers (server/api/errors.py shapes every error ``{"error": {"code", "message"}}``): each
  route declares its own 4xx with :class:`~server.api.schemas.ErrorResponse` (``schemas.error_responses``), and
  FastAPI's leftovers are removed — from routes that cannot answer 422 at all (only ``str`` path parameters);
- the API-key scheme (``Authorization: Bearer <key>``) is declared, and every operation the key check covers
  (``server.api.guard.needs_key``) says so: the docs' "Authorize" button then sends the key;
- the Server-Sent Events' data (:class:`~server.api.schemas.BakeSnapshot`) is added to the components (the
  events route's event schema, ``bakes.SSE_EVENT``, names it).

``/docs`` (Swagger UI) and ``/redoc`` load their scripts and styles from Kiln itself (the ``fastapi-offline``
package ships them; ``server/main.py`` builds the app with it), never from a CDN; Swagger UI's online
validator badge is off (``validatorUrl: null``) and ReDoc's CDN logo is hidden and refused by a
Content-Security-Policy: the docs render with no other host reachable (tests/web/test_docs_offline.py).
"""
from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.openapi.docs import get_redoc_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse

from server.api.guard import needs_key
from server.api.schemas import BakeSnapshot

SWAGGER_UI_PARAMETERS = {"validatorUrl": None, "persistAuthorization": True}
"""Swagger UI options (``FastAPI(swagger_ui_parameters=...)``): no request to the online validator."""

SECURITY_SCHEME = "apiKey"
_FASTAPI_VALIDATION = "#/components/schemas/HTTPValidationError"


def build(app: FastAPI) -> dict[str, Any]:
    """The app's OpenAPI document (module doc)."""
    doc = get_openapi(title=app.title, version=app.version, openapi_version=app.openapi_version,
                      summary=app.summary, description=app.description, routes=app.routes, tags=app.openapi_tags,
                      servers=app.servers, separate_input_output_schemas=app.separate_input_output_schemas)
    components = doc.setdefault("components", {})
    schemas = components.setdefault("schemas", {})
    for path, item in doc.get("paths", {}).items():
        for method, op in item.items():
            responses = op.get("responses", {})
            v = responses.get("422", {}).get("content", {}).get("application/json", {}).get("schema", {})
            if v.get("$ref") == _FASTAPI_VALIDATION:
                del responses["422"]
            if needs_key(path):
                op["security"] = [{SECURITY_SCHEME: []}]
    for name in ("HTTPValidationError", "ValidationError"):
        schemas.pop(name, None)
    snap = BakeSnapshot.model_json_schema(ref_template="#/components/schemas/{model}")
    for name, s in snap.pop("$defs", {}).items():
        schemas.setdefault(name, s)
    schemas[BakeSnapshot.__name__] = snap
    components.setdefault("securitySchemes", {})[SECURITY_SCHEME] = {
        "type": "http", "scheme": "bearer",
        "description": "With API keys configured (KILN_API_KEYS=\"team:key,...\"): 'Authorization: Bearer <key>'; "
                       "each team sees only its own scenes and bakes. A server without keys is open (loopback only)."}
    return doc


REDOC_CSP = ("default-src 'self'; script-src 'self' blob:; worker-src 'self' blob:; style-src 'self' 'unsafe-inline'; "
             "img-src 'self' data:; font-src 'self' data:; connect-src 'self'")
"""``/redoc``'s Content-Security-Policy: ReDoc's bundle shows a "powered by" logo from its CDN in the sidebar; the
page hides that link and the policy keeps the browser from fetching anything from another host."""
_REDOC_HIDE = "a[href*='redocly.com'], a[href*='redoc.ly'] { display: none !important; }"


def install(app: FastAPI, static_url: str = "/static-offline-docs") -> None:
    """The adjusted document at ``app.openapi_url``, and ``/redoc`` from Kiln's own assets (build the app with
    ``FastAPIOffline(..., redoc_url=None)``: its /docs, this /redoc)."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = build(app)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    @app.get("/redoc", include_in_schema=False)
    async def redoc(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        page = get_redoc_html(openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - ReDoc",
                              redoc_js_url=f"{root}{static_url}/redoc.standalone.js", with_google_fonts=False,
                              redoc_favicon_url=f"{root}{static_url}/favicon.png")
        html = page.body.decode().replace("</style>", f"  {_REDOC_HIDE}\n    </style>", 1)
        return HTMLResponse(html, headers={"Content-Security-Policy": REDOC_CSP})
