"""Pagination of the list endpoints (``GET /v1/scenes``, ``GET /v1/bakes``): ``limit`` and ``offset``, bounded.

``limit`` must be at least 1; larger than :data:`MAX_LIMIT` it is clamped (the response's ``limit`` says what
was used). ``offset`` must be in ``[0, MAX_OFFSET]``: anything else is a 422 naming the parameter, never
SQLite's ``OverflowError`` (a 500) for an offset past 64 bits.
"""
from __future__ import annotations

from typing import NamedTuple

from fastapi import Query

MAX_LIMIT = 500
"""Most items of one page; a larger ``limit`` is clamped to it."""
MAX_OFFSET = 1_000_000_000
"""Largest ``offset`` accepted (far past any catalog; SQLite takes up to 2**63 - 1)."""


class Page(NamedTuple):
    limit: int
    offset: int


def page(limit: int = Query(50, ge=1, description=f"items per page; above {MAX_LIMIT} it is clamped to {MAX_LIMIT}"),
         offset: int = Query(0, ge=0, le=MAX_OFFSET, description="items to skip")) -> Page:
    return Page(min(limit, MAX_LIMIT), offset)
