"""JSON at the HTTP boundary: no non-finite number gets in, and none can break a response on the way out.

- :class:`FiniteJSONRoute`, the route class of every router in ``server/api/routes`` (``APIRouter(...,
  route_class=FiniteJSONRoute)``; a test checks every route with a body uses it): a JSON body holding
  ``NaN``, ``Infinity`` or ``-Infinity`` (Python's ``json`` reads them; JSON does not allow them), or a number
  too large for a double (``1e999`` reads as infinity), is refused before validation with 422 and the error
  shape ``{"error": {"code", "message"}}``, the message naming the field (``config.scene.lights.0.range``).
  The models refuse non-finite floats too (``proto.models._Strict``: ``allow_inf_nan=False``); this catches
  them in any body, whatever its model.
- :class:`FiniteJSONResponse`, the app's default response class: a non-finite float in stored data (a bake
  record from before these checks, a stage's stats) is written as ``null`` instead of failing the response
  with a 500 (``json.dumps(allow_nan=False)`` raises on it).
"""
from __future__ import annotations

import json
import math
from typing import Any, Callable, Coroutine

from fastapi import Request, Response
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.exceptions import HTTPException


class BodyError(HTTPException):
    """A request body refused before validation; ``code`` is the error code of the JSON error shape."""

    def __init__(self, status_code: int, code: str, message: str):
        super().__init__(status_code=status_code, detail=message)
        self.code = code


def first_non_finite(obj: Any, path: tuple = ()) -> tuple | None:
    """The path (keys and indices) of the first non-finite float in parsed JSON, or None (no recursion)."""
    stack = [(obj, path)]
    while stack:
        v, p = stack.pop()
        if isinstance(v, float):
            if not math.isfinite(v):
                return p
        elif isinstance(v, dict):
            stack.extend((x, (*p, k)) for k, x in reversed(list(v.items())))
        elif isinstance(v, list):
            stack.extend((x, (*p, i)) for i, x in reversed(list(enumerate(v))))
    return None


def finite_or_none(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (JSON has no NaN or infinity)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    return obj


def dumps(obj: Any, **kw) -> str:
    """``json.dumps`` that never writes NaN/Infinity (they become null) and never raises for them."""
    kw.setdefault("separators", (",", ":"))
    try:
        return json.dumps(obj, allow_nan=False, **kw)
    except ValueError:
        return json.dumps(finite_or_none(obj), allow_nan=False, **kw)


class FiniteJSONResponse(JSONResponse):
    """A JSONResponse whose non-finite floats become ``null`` rather than a 500."""

    def render(self, content: Any) -> bytes:
        return dumps(content, ensure_ascii=False).encode("utf-8")


def _code_for(path: tuple) -> str:
    return "invalid_config" if path[:1] == ("config",) else "invalid_request"


class _FiniteJSONRequest(Request):
    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            body = await self.body()
            try:
                doc = json.loads(body)
            except json.JSONDecodeError:
                raise  # FastAPI answers 422 json_invalid (server.api.errors shapes it)
            except RecursionError:
                raise BodyError(422, "invalid_request", "the JSON body is nested too deeply") from None
            except ValueError as e:  # bad UTF-8, an integer of more than 4300 digits
                raise BodyError(422, "invalid_request", f"the body is not valid JSON ({e})") from None
            bad = first_non_finite(doc)
            if bad is not None:
                where = ".".join(str(p) for p in bad) or "body"
                raise BodyError(422, _code_for(bad),
                                f"{where}: not a finite number (JSON has no NaN or Infinity, and a number must "
                                "fit a double)")
            self._json = doc
        return self._json


class FiniteJSONRoute(APIRoute):
    """An APIRoute whose JSON body may hold no NaN/Infinity (see the module docstring)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def finite_json_handler(request: Request) -> Response:
            return await handler(_FiniteJSONRequest(request.scope, request.receive, request._send))

        return finite_json_handler
