"""``/v1/scenes``: upload (raw body or multipart, streamed to disk), list, get, delete."""
from __future__ import annotations

import asyncio
import os
import tempfile
from pathlib import Path

from fastapi import APIRouter, Depends, Request, Response

from persist.catalog import Catalog
from persist.store import Store
from server.api import deps
from server.api.errors import ApiError
from server.api.jsonbody import FiniteJSONResponse, FiniteJSONRoute
from server.api.paging import Page, page
from server.api.schemas import ScenePublic, ScenesPublic, error_responses
from server.config import Settings
from server.ingest_pool import IngestPool, UploadsBusy

router = APIRouter(prefix="/v1/scenes", tags=["scenes"], route_class=FiniteJSONRoute)

_MULTIPART_SLACK = 64 * 1024
"""Bytes of multipart framing allowed beyond the upload limit in Content-Length."""


async def _save_body(request: Request, dest: Path, limit: int) -> str | None:
    """Stream the upload to ``dest``; returns the client's file name if it sent one. 413 past ``limit``."""
    ctype = request.headers.get("content-type", "")
    cl = request.headers.get("content-length")
    if cl is not None:
        try:
            n = int(cl)
        except ValueError:
            raise ApiError(400, "bad_request", "Content-Length is not a number")
        if n > limit + (_MULTIPART_SLACK if ctype.startswith("multipart/") else 0):
            raise ApiError(413, "too_large", f"the upload is {n} bytes; the limit is {limit} bytes")
    written = 0
    if ctype.startswith("multipart/form-data"):
        # the multipart parser spools the file itself: count what it receives, so a chunked body is cut off
        # at the limit too (not only one with a Content-Length)
        received = 0

        async def bounded_receive():
            nonlocal received
            msg = await request.receive()
            if msg["type"] == "http.request":
                received += len(msg.get("body", b""))
                if received > limit + _MULTIPART_SLACK:
                    raise ApiError(413, "too_large", f"the upload exceeds the limit of {limit} bytes")
            return msg

        form = await Request(request.scope, bounded_receive).form(max_files=1, max_fields=8)
        try:
            files = [v for _, v in form.multi_items() if hasattr(v, "read")]
            if not files:
                raise ApiError(400, "no_file", "the multipart body has no file part")
            up = files[0]
            with open(dest, "wb") as f:
                while chunk := await up.read(1 << 20):
                    written += len(chunk)
                    if written > limit:
                        raise ApiError(413, "too_large", f"the upload exceeds the limit of {limit} bytes")
                    f.write(chunk)
            name = up.filename
        finally:
            await form.close()
    else:
        with open(dest, "wb") as f:
            async for chunk in request.stream():
                written += len(chunk)
                if written > limit:
                    raise ApiError(413, "too_large", f"the upload exceeds the limit of {limit} bytes")
                f.write(chunk)
        name = request.headers.get("x-filename") or request.query_params.get("filename")
    if written == 0:
        raise ApiError(400, "empty_upload", "the upload is empty")
    return name


UPLOAD_RETRY_AFTER_S = 5
"""``Retry-After`` of a 429 for too many concurrent uploads of one team (a small upload takes about a second)."""
QUOTA_RETRY_AFTER_S = 60
"""``Retry-After`` of a 429 for a storage or scene-count quota: nothing frees itself; the team must delete."""


def stored_bytes(catalog: Catalog, store: Store, team: str, usage: dict | None = None) -> int:
    """What a team stores, for ``KILN_QUOTA_STORED_MB``: its scenes' normalized bytes (a scene stored before
    sizes were recorded: its blob's size) and the bundles of its succeeded bakes."""
    usage = usage or catalog.team_usage(team)
    extra = 0
    for sid in usage["unsized"]:
        try:
            extra += store.blob_path(sid).stat().st_size
        except (OSError, ValueError):
            pass
    return usage["scene_bytes"] + extra + usage["artifact_bytes"]


def quota_error(what: str, used: int | str, limit: int | str, hint: str) -> ApiError:
    return ApiError(429, "quota_exceeded", f"the team's {what} quota is used: {used} of {limit}; {hint}",
                    headers={"Retry-After": str(QUOTA_RETRY_AFTER_S)})


def _check_upload_quota(settings: Settings, catalog: Catalog, store: Store, team: str, adding: int = 0,
                        new_scene: bool = True) -> None:
    usage = catalog.team_usage(team)
    if new_scene and usage["scenes"] >= settings.quota_scenes:
        raise quota_error("scenes", usage["scenes"], settings.quota_scenes, "delete scenes first (KILN_QUOTA_SCENES)")
    used = stored_bytes(catalog, store, team, usage)
    limit = settings.quota_stored_mb * 2**20
    if used + adding > limit or (adding == 0 and used >= limit):
        raise quota_error("stored bytes", used + adding, limit,
                          "delete scenes or bakes first (KILN_QUOTA_STORED_MB)")


_BINARY = {"schema": {"type": "string", "format": "binary"}}
UPLOAD_BODY = {
    "required": True,
    "description": "The scene file: a raw body (any content type but multipart: the bytes decide the format; name "
                   "it with `X-Filename` or `?filename=`), or multipart/form-data with one file part (its file "
                   "name is kept). At most KILN_MAX_UPLOAD_MB.",
    "content": {
        "model/gltf-binary": _BINARY,
        "model/gltf+json": {"schema": {"type": "object", "description": "a glTF 2.0 document (buffers and "
                                                                        "images as data URIs)"}},
        "application/zip": _BINARY,
        "application/octet-stream": _BINARY,
        "multipart/form-data": {"schema": {"type": "object", "required": ["file"], "properties": {
            "file": {"type": "string", "format": "binary", "description": "the .glb, .gltf or .zip"}}}},
    },
}
"""``POST /v1/scenes``'s request body in the OpenAPI document: the route streams the body itself (no FastAPI body
parameter, so that nothing reads it into memory), so it is declared here."""
UPLOAD_PARAMETERS = [
    {"name": "X-Filename", "in": "header", "required": False, "schema": {"type": "string"},
     "description": "the file name of a raw body (shown in the scene's `filename`, named in messages)"},
    {"name": "filename", "in": "query", "required": False, "schema": {"type": "string"},
     "description": "the same as X-Filename"},
]


@router.post("", status_code=201, summary="Upload a scene (.glb, .gltf with data URIs, or .zip)",
             response_model=ScenePublic,
             openapi_extra={"requestBody": UPLOAD_BODY, "parameters": UPLOAD_PARAMETERS},
             responses={200: {"model": ScenePublic, "description": "the team already has this scene (same id)"},
                        201: {"description": "a new scene"},
                        **error_responses({400: "an empty upload, or a multipart body without a file part"}, 401,
                                          408, {413: "over KILN_MAX_UPLOAD_MB, or it expands past "
                                                     "KILN_MAX_SCENE_MB / the triangle limit"},
                                          415, {422: "not a valid scene (the code names why: workers/gltf/errors.py "
                                                     "ERROR_CODES)"}, 429)})
async def upload_scene(request: Request, team: str = Depends(deps.team), settings: Settings = Depends(deps.settings),
                       catalog: Catalog = Depends(deps.catalog), store: Store = Depends(deps.store),
                       pool: IngestPool = Depends(deps.ingest_pool)):
    """Admission first, before any body byte is read: the team's concurrent uploads (429 with Retry-After,
    ``KILN_MAX_UPLOADS_PER_TEAM``) and its quotas (429 ``quota_exceeded``). The body streams to disk within
    ``KILN_MAX_UPLOAD_MB`` and ``KILN_INGEST_TIMEOUT_S``; a parser child reads it (killed past the timeout or when
    the client goes away); the normalized scene must stay within ``KILN_MAX_SCENE_MB`` and the quota."""
    await asyncio.to_thread(_check_upload_quota, settings, catalog, store, team)
    try:
        admitted = pool.admit(team)
        admitted.__enter__()
    except UploadsBusy as e:
        raise ApiError(429, "too_many_uploads", f"the team has {e.limit} uploads in progress, the most it may "
                                                "(KILN_MAX_UPLOADS_PER_TEAM); retry when one is done",
                       headers={"Retry-After": str(UPLOAD_RETRY_AFTER_S)}) from None
    try:
        result, filename = await _receive_and_parse(request, settings, store, pool, team)
    finally:
        admitted.__exit__(None, None, None)
    if "error" in result:
        e = result["error"]
        raise ApiError(e["status"], e["code"], e["message"])
    summary = result["summary"]
    if await asyncio.to_thread(catalog.get_scene, team, result["scene_id"]) is None:
        try:
            await asyncio.to_thread(_check_upload_quota, settings, catalog, store, team, int(summary.get("bytes") or 0))
        except ApiError:
            if not await asyncio.to_thread(catalog.scene_referenced, result["scene_id"]):
                store.blob_path(result["scene_id"]).unlink(missing_ok=True)
            raise
    created = await asyncio.to_thread(catalog.add_scene, team, result["scene_id"], summary, filename)
    body = await asyncio.to_thread(catalog.get_scene, team, result["scene_id"])
    return FiniteJSONResponse(body, status_code=201 if created else 200)


async def _receive_and_parse(request: Request, settings: Settings, store: Store, pool, team: str
                             ) -> tuple[dict, str | None]:
    updir = settings.data / "uploads"
    updir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=updir, suffix=".upload")
    os.close(fd)
    try:
        try:
            filename = await asyncio.wait_for(_save_body(request, Path(tmp), settings.max_upload_bytes),
                                              settings.ingest_timeout_s)
        except asyncio.TimeoutError:
            raise ApiError(408, "upload_timeout", f"the upload did not arrive within {settings.ingest_timeout_s:g} s "
                                                  "(KILN_INGEST_TIMEOUT_S)") from None
        limits = {"max_bytes": settings.max_upload_bytes, "max_triangles": settings.max_triangles,
                  "max_scene_bytes": settings.max_scene_bytes}
        limits.update(_expanded_limits(settings))
        result = await pool.run(tmp, filename or "upload", str(store.root), limits, team=team,
                                disconnected=request.is_disconnected)
    finally:
        Path(tmp).unlink(missing_ok=True)
    return result, filename


def _expanded_limits(settings: Settings) -> dict:
    """IngestLimits fields bounding the decoded size of an upload (not only its file): the images' total pixels,
    so four 8192² PNGs in a small file are refused before they are decoded (4 bytes a pixel, RGBA)."""
    return {"max_total_image_pixels": settings.max_scene_bytes // 4}


@router.get("", summary="List the team's scenes", response_model=ScenesPublic,
            responses=error_responses(401, {422: "limit or offset out of range"}))
def list_scenes(team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                pg: Page = Depends(page)):
    limit, offset = pg
    items, total = catalog.list_scenes(team, limit, offset)
    return FiniteJSONResponse({"items": items, "total": total, "limit": limit, "offset": offset})


@router.get("/{scene_id}", summary="One scene", response_model=ScenePublic,
            responses=error_responses(401, {404: "no such scene for this team"}))
def get_scene(scene_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog)):
    s = catalog.get_scene(team, scene_id)
    if s is None:
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    return FiniteJSONResponse(s)


@router.delete("/{scene_id}", status_code=204, summary="Delete a scene (409 while bakes use it)",
               response_class=Response,
               responses=error_responses(401, {404: "no such scene for this team",
                                               409: "bakes use the scene (scene_in_use): delete them first"}))
def delete_scene(scene_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                 store: Store = Depends(deps.store)):
    if catalog.get_scene(team, scene_id) is None:
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    _, n = catalog.list_bakes(team, scene_id, None, 1, 0)
    if n:
        raise ApiError(409, "scene_in_use", f"{n} bake(s) use this scene; delete them first")
    catalog.delete_scene(team, scene_id)
    if not catalog.scene_referenced(scene_id):
        store.blob_path(scene_id).unlink(missing_ok=True)
    return Response(status_code=204)
