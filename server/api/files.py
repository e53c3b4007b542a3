"""Files from the store as responses (an artifact, a bundle zip): Starlette's ``FileResponse`` (ETag, Range),
with its refusals in Kiln's error shape.

Starlette answers a malformed ``Range`` with a plain-text 400 and one past the end of the file with an empty
text/plain 416; every other error of the API is JSON ``{"error": {"code", "message"}}`` (server/api/errors.py),
and the OpenAPI document says so. :class:`BlobResponse` checks the Range exactly as ``FileResponse`` will
(same conditions, same parser) and answers those two cases itself, as JSON; everything else is FileResponse's.
"""
from __future__ import annotations

import os

import anyio
from starlette.datastructures import Headers
from starlette.responses import FileResponse, JSONResponse, MalformedRangeHeader, RangeNotSatisfiable
from starlette.types import Receive, Scope, Send

from server.api.errors import error_body


class BlobResponse(FileResponse):
    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and self.status_code == 200 and scope["method"].upper() in ("GET", "HEAD"):
            headers = Headers(scope=scope)
            http_range, if_range = headers.get("range"), headers.get("if-range")
            if http_range is not None:
                if self.stat_result is None:
                    try:
                        self.stat_result = await anyio.to_thread.run_sync(os.stat, self.path)
                    except FileNotFoundError:
                        raise RuntimeError(f"File at path {self.path} does not exist.") from None
                    self.set_stat_headers(self.stat_result)
                if if_range is None or self._should_use_range(if_range):
                    refusal = None
                    try:
                        self._parse_range_header(http_range, self.stat_result.st_size)
                    except MalformedRangeHeader as e:
                        refusal = JSONResponse(error_body("bad_range", f"the Range header is refused: {e.content}"),
                                               status_code=400)
                    except RangeNotSatisfiable as e:
                        refusal = JSONResponse(
                            error_body("range_not_satisfiable", f"the Range starts past the end of the file "
                                                                f"({e.max_size} bytes)"),
                            status_code=416, headers={"Content-Range": f"bytes */{e.max_size}"})
                    if refusal is not None:
                        return await refusal(scope, receive, send)
        return await super().__call__(scope, receive, send)
