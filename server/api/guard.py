"""The first thing every request meets: the API key is checked before any body byte is read, and JSON bodies
are bounded before FastAPI reads them.

A pure ASGI middleware (outside FastAPI's routing, which reads and parses a JSON body before it resolves the
route's dependencies, the key check among them):

- **auth first**: with keys configured, a request to ``/v1/...`` (but the config schema) or ``/metrics``
  without a valid key is answered 401 at once, its body never read — it costs a header parse. The answer
  carries ``Connection: close``, so the client stops sending;
- **bounded JSON**: a request with a body to any route but the upload (``POST /v1/scenes``, streamed to disk
  within ``KILN_MAX_UPLOAD_MB`` by its route) is refused 413 when its ``Content-Length`` passes
  ``KILN_MAX_JSON_KB``; without a length (chunked) it is read here up to that cap (413 past it) and handed on.

The routes still resolve the team themselves (:func:`server.api.deps.team`); this only makes sure that a
request without a key never gets that far.
"""
from __future__ import annotations

import hmac
import json

from server.api.errors import error_body

UPLOAD_PATH = "/v1/scenes"
OPEN_PATHS = ("/v1/config/schema",)


def needs_key(path: str) -> bool:
    return (path.startswith("/v1/") and path not in OPEN_PATHS) or path == "/metrics"


def key_team(keys: dict[str, str], authorization: str | None) -> str | None:
    """The team of ``Authorization: Bearer <key>``, or None (constant-time over every key)."""
    scheme, _, token = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        return None
    token_b = token.strip().encode()
    found = None
    for key, team in keys.items():
        if hmac.compare_digest(key.encode(), token_b):
            found = team
    return found


async def _answer(send, status: int, code: str, message: str, headers: list | None = None) -> None:
    body = json.dumps(error_body(code, message)).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *(headers or [])]})
    await send({"type": "http.response.body", "body": body})


class Guard:
    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        state = getattr(scope.get("app"), "state", None)
        settings = getattr(state, "settings", None)
        if settings is None:          # before the lifespan ran (never in service)
            return await self.app(scope, receive, send)
        path, method = scope["path"], scope["method"]
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        keys = settings.keys
        if keys and needs_key(path):
            if key_team(keys, headers.get("authorization")) is None:
                message = ("unknown API key" if headers.get("authorization", "").lower().startswith("bearer ")
                           else "send an API key as 'Authorization: Bearer <key>'")
                return await _answer(send, 401, "unauthorized", message, [(b"www-authenticate", b"Bearer")])
        if method in ("GET", "HEAD", "DELETE", "OPTIONS") or (method == "POST" and path == UPLOAD_PATH):
            return await self.app(scope, receive, send)
        cap = settings.max_json_bytes
        cl = headers.get("content-length")
        if cl is not None:
            try:
                n = int(cl)
            except ValueError:
                return await _answer(send, 400, "bad_request", "Content-Length is not a number")
            if n > cap:
                return await _answer(send, 413, "too_large", f"the request body is {n} bytes; the limit is {cap} "
                                                             "bytes (KILN_MAX_JSON_KB)")
        chunks, total = [], 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            body = message.get("body", b"")
            total += len(body)
            if total > cap:
                return await _answer(send, 413, "too_large", f"the request body exceeds the limit of {cap} bytes "
                                                             "(KILN_MAX_JSON_KB)")
            chunks.append(body)
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay():
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": b"".join(chunks), "more_body": False}
            return await receive()

        return await self.app(scope, replay, send)
