"""``/v1/scenes``: upload (raw body or multipart, streamed to disk), list, get, delete."""
from __future__ import annotations

import asyncio
import os
import tempfile
from pathlib import Path

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse

from proto.catalog import Catalog
from proto.store import Store
from server.api import deps
from server.api.errors import ApiError
from server.config import Settings

router = APIRouter(prefix="/v1/scenes", tags=["scenes"])

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
        form = await request.form(max_files=1, max_fields=8)
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


@router.post("", status_code=201, summary="Upload a scene (.glb, .gltf with data URIs, or .zip)")
async def upload_scene(request: Request, team: str = Depends(deps.team)):
    settings: Settings = request.app.state.settings
    catalog: Catalog = request.app.state.catalog
    store: Store = request.app.state.store
    updir = settings.data / "uploads"
    updir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=updir, suffix=".upload")
    os.close(fd)
    try:
        filename = await _save_body(request, Path(tmp), settings.max_upload_bytes)
        limits = {"max_bytes": settings.max_upload_bytes, "max_triangles": settings.max_triangles}
        result = await request.app.state.ingest_pool.run(tmp, filename or "upload", str(store.root), limits)
    finally:
        Path(tmp).unlink(missing_ok=True)
    if "error" in result:
        e = result["error"]
        raise ApiError(e["status"], e["code"], e["message"])
    summary = result["summary"]
    created = await asyncio.to_thread(catalog.add_scene, team, result["scene_id"], summary, filename)
    body = await asyncio.to_thread(catalog.get_scene, team, result["scene_id"])
    return JSONResponse(body, status_code=201 if created else 200)


@router.get("", summary="List the team's scenes")
def list_scenes(team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                limit: int = Query(50, ge=1, le=500), offset: int = Query(0, ge=0)):
    items, total = catalog.list_scenes(team, limit, offset)
    return {"items": items, "total": total, "limit": limit, "offset": offset}


@router.get("/{scene_id}", summary="One scene")
def get_scene(scene_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog)):
    s = catalog.get_scene(team, scene_id)
    if s is None:
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    return s


@router.delete("/{scene_id}", status_code=204, summary="Delete a scene (409 while bakes use it)")
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
