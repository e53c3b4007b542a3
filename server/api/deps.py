"""Request dependencies: settings, catalog, store, Redis, and the caller's team (API-key auth)."""
from __future__ import annotations

import hmac

from fastapi import Request

from proto.catalog import Catalog
from proto.store import Store
from server.api.errors import ApiError
from server.config import OPEN_TEAM, Settings


def settings(request: Request) -> Settings:
    return request.app.state.settings


def catalog(request: Request) -> Catalog:
    return request.app.state.catalog


def store(request: Request) -> Store:
    return request.app.state.store


def redis_conn(request: Request):
    return request.app.state.redis


def team(request: Request) -> str:
    """The team of the caller's API key (``Authorization: Bearer <key>``); ``default`` when the server is open."""
    s: Settings = request.app.state.settings
    keys = s.keys
    if not keys:
        return OPEN_TEAM
    auth = request.headers.get("authorization", "")
    scheme, _, token = auth.partition(" ")
    if scheme.lower() != "bearer" or not token:
        raise ApiError(401, "unauthorized", "send an API key as 'Authorization: Bearer <key>'",
                       headers={"WWW-Authenticate": "Bearer"})
    for key, t in keys.items():
        if hmac.compare_digest(key.encode(), token.strip().encode()):
            return t
    raise ApiError(401, "unauthorized", "unknown API key", headers={"WWW-Authenticate": "Bearer"})
