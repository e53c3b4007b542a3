"""``/v1/bakes``: create (202, or done at once from cache), list, get, cancel, delete, events (SSE),
artifacts (ETag + Range) and the bundle (one zip)."""
from __future__ import annotations

import asyncio
import json
import logging
import math
import tempfile
import threading
import time
from typing import Literal

import redis
from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse, StreamingResponse

from persist.catalog import TERMINAL, Catalog
from persist.export import bake_artifacts, export_bundle
from persist.store import Store
from proto import bundle, cost
from proto.models import BakeConfig, Manifest
from proto.stages import collect_warnings, finalize_bake
from server import queue
from server.api import deps
from server.api.errors import ApiError
from server.api.routes import review
from server.api.routes.scenes import quota_error, stored_bytes
from server.api.jsonbody import FiniteJSONRoute
from server.api.jsonbody import dumps as finite_dumps
from server.api.files import BlobResponse
from server.api.paging import Page, page
from server.api.schemas import (BakeCreate, BakeCreated, BakeDryRun, BakePublic, BakeRefused, BakeSnapshot, BakesPublic,
                                error_responses)
from server.config import Settings

log = logging.getLogger("kiln.api")
router = APIRouter(prefix="/v1/bakes", tags=["bakes"], route_class=FiniteJSONRoute)

MEDIA = {"ktx2": "image/ktx2", "npy": "application/octet-stream", "json": "application/json", "png": "image/png",
         "glb": "model/gltf-binary"}
SSE_POLL_S = 0.25
SSE_HEARTBEAT_S = 15.0


def json_response(obj) -> Response:
    """``obj`` (plain JSON types, as the catalog returns them) as a JSON response, without FastAPI's
    ``jsonable_encoder``: for a bake's 20 KB document that walk costs 3.3 ms against ``json.dumps``'s 0.4 ms,
    and clients poll these routes. A non-finite float (a stage's stats holding ``inf``) becomes ``null`` rather
    than failing the whole bake's document with a 500 (JSON has no infinities)."""
    try:
        text = json.dumps(obj, separators=(",", ":"), allow_nan=False)
    except ValueError:
        text = json.dumps(_finite_or_none(obj), separators=(",", ":"), allow_nan=False)
    return Response(text, media_type="application/json")


def _finite_or_none(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    return obj


def links(bake_id: str) -> dict:
    base = f"/v1/bakes/{bake_id}"
    return {"self": base, "events": f"{base}/events", "bundle": f"{base}/bundle", "artifacts": f"{base}/artifacts",
            "cancel": f"{base}/cancel"}


def bake_warnings(bake: dict, scene_warnings: list[str] | None = None) -> list[dict]:
    """The bake's warnings (``[{code, message, stage}]``): the manifest's once it succeeded (recomputed from
    its stages for manifests stored before they carried warnings), else the scene's ingest warnings and those
    of the stages finished so far."""
    m = bake.get("manifest")
    if m:
        if "warnings" in m:
            return m["warnings"]
        pairs = [(s["name"], s.get("stats")) for s in m.get("stages", [])]
        found = collect_warnings(pairs, (m.get("scene") or {}).get("warnings"))
    else:
        pairs = [(s["name"], s.get("stats")) for s in bake["stages"] if s["status"] == "succeeded"]
        found = collect_warnings(pairs, scene_warnings)
    return [w.model_dump(mode="json") for w in found]


def _scene_warnings(catalog: Catalog, bake: dict, cache: dict | None = None) -> list[str]:
    """The ingest warnings of the bake's scene (needed only while the bake has no manifest)."""
    if bake.get("manifest"):
        return []
    key = (bake["team"], bake["scene_id"])
    if cache is not None and key in cache:
        return cache[key]
    scene = catalog.get_scene(*key)
    found = list((scene or {}).get("warnings") or [])
    if cache is not None:
        cache[key] = found
    return found


def public(bake: dict, store: Store | None = None, scene_warnings: list[str] | None = None) -> dict:
    out = {k: bake[k] for k in ("id", "scene_id", "status", "config", "created", "started", "finished", "error")}
    out["stages"] = [{k: s[k] for k in ("name", "status", "progress", "seconds", "cached", "stats")}
                     for s in bake["stages"]]
    out["warnings"] = bake_warnings(bake, scene_warnings)
    out["warning_count"] = len(out["warnings"])
    out["metrics"] = bake.get("metrics", {})
    if store is not None:
        out["artifacts"] = [{k: a.get(k) for k in ("name", "file", "format", "shape", "dtype", "bytes", "sha256", "stage",
                                                   "meta")}
                            for a in bake_artifacts(store, bake)]
        out["check_points"] = review.check_points_of(store, bake)     # evaluate.points: the check_points artifact
    out["links"] = links(bake["id"])
    return out


def _get(catalog: Catalog, team: str, bake_id: str) -> dict:
    bake = catalog.get_bake(bake_id, team)
    if bake is None:
        raise ApiError(404, "bake_not_found", f"no bake {bake_id}")
    return bake


BAKE_RETRY_AFTER_MIN_S, BAKE_RETRY_AFTER_MAX_S = 5, 3600
_admission = threading.Lock()
"""Held from a bake's quota check to its record, so two requests of a team cannot both take the last slot."""


def budget_of(settings) -> cost.Budget:
    return cost.Budget(memory_bytes=settings.bake_memory_bytes, seconds=settings.max_bake_seconds,
                       disk_bytes=settings.max_bake_disk_mb * 2**20)


def _limits_json(b: cost.Budget) -> dict:
    return {"peak_memory_bytes": b.memory_bytes, "seconds": b.seconds, "artifact_bytes": b.disk_bytes}


def _bake_retry_after(catalog: Catalog, team: str) -> int:
    """Seconds until the team's soonest active bake should finish, by the cost model (within 5 s .. 1 h)."""
    best = float(BAKE_RETRY_AFTER_MAX_S)
    now = time.time()
    for b in catalog.bakes_with_status(("queued", "running")):
        if b["team"] != team:
            continue
        scene = catalog.get_scene(team, b["scene_id"])
        try:
            est = cost.estimate(scene or {}, BakeConfig.model_validate(b["config"]))
        except Exception:
            continue
        best = min(best, est.seconds - (now - (b["started"] or b["created"])))
    return int(min(BAKE_RETRY_AFTER_MAX_S, max(BAKE_RETRY_AFTER_MIN_S, math.ceil(best))))


_NO_BAKE = {404: "no such bake for this team"}


@router.post("", status_code=202, summary="Start a bake of a scene with a config (or estimate it: dry_run)",
             response_model=BakeCreated,
             responses={200: {"model": BakeDryRun, "description": "dry_run=true: the estimate; nothing started"},
                        **error_responses(401, {404: "no such scene for this team"}, 413,
                                          {429: "a team quota: concurrent bakes or stored bytes (Retry-After)"}),
                        422: {"model": BakeRefused, "description": "the config refused (invalid_config, the "
                              "message names the field) or over the server's budget (over_budget, with the "
                              "estimate and the limits)"}})
def create_bake(body: BakeCreate, team: str = Depends(deps.team),
                catalog: Catalog = Depends(deps.catalog), store: Store = Depends(deps.store),
                settings: Settings = Depends(deps.settings), conn: redis.Redis = Depends(deps.redis_conn),
                dry_run: bool = Query(False, description="only estimate the bake: 200 {estimate, limits, "
                                                         "over_budget}; nothing is recorded or started")):
    """Every bake is estimated first (``proto.cost``: probes, seconds, peak memory, artifact bytes). Over the
    server's budget it is refused, 422 ``over_budget`` with the estimate and the limits; over the team's
    quotas (concurrent bakes, stored bytes) 429 ``quota_exceeded`` with ``Retry-After``. ``dry_run=true``
    answers the estimate without recording or starting anything."""
    scene = catalog.get_scene(team, body.scene_id)
    if scene is None:
        raise ApiError(404, "scene_not_found", f"no scene {body.scene_id}")
    body.config = review.with_review_cameras(body.config, scene)   # the scene's stored review cameras
    est = cost.estimate(scene, body.config)
    budget = budget_of(settings)
    over = cost.over_budget(est, budget)
    if dry_run:
        return json_response({"estimate": est.public(), "limits": _limits_json(budget), "over_budget": over})
    if over:
        what = "; ".join(f"{o['resource']} {o['estimate']} > {o['limit']}" for o in over)
        return JSONResponse({"error": {
            "code": "over_budget",
            "message": f"the bake is estimated over the server's budget ({what}): use fewer probes, rays per probe "
                       "or visibility samples (POST /v1/bakes?dry_run=true estimates a config)",
            "estimate": est.public(), "limits": _limits_json(budget), "over_budget": over}}, status_code=422)
    stages = queue.plan_stages(body.scene_id, body.config, namespace=team)
    records = [store.get_stage(key) for _, key in stages]
    with _admission:
        if not all(records):
            usage = catalog.team_usage(team)
            if usage["active_bakes"] >= settings.quota_concurrent_bakes:
                raise ApiError(429, "quota_exceeded", (
                    f"the team has {usage['active_bakes']} bakes queued or running, the most it may "
                    "(KILN_QUOTA_CONCURRENT_BAKES); retry when one is done"),
                    headers={"Retry-After": str(_bake_retry_after(catalog, team))})
            used = stored_bytes(catalog, store, team, usage)
            limit = settings.quota_stored_mb * 2**20
            if used + est.bundle_bytes > limit:
                raise quota_error("stored bytes", used + est.bundle_bytes, limit,
                                  "delete bakes or scenes first (KILN_QUOTA_STORED_MB)")
        bake_id = catalog.create_bake(team, body.scene_id, body.config.model_dump(mode="json"), stages)
    if all(records):  # every stage is in the store: done at once
        for (name, _), rec in zip(stages, records):
            catalog.update_stage(bake_id, name, status="succeeded", progress=1.0, seconds=rec["seconds"],
                                 cached=True, stats=rec["stats"], started=time.time(), finished=time.time())
        done = finalize_bake(catalog.get_bake(bake_id), scene, store)
        catalog.mark_succeeded(bake_id, done.manifest, done.metrics)
    else:
        try:
            queue.enqueue_bake(conn, catalog.get_bake(bake_id), scene,
                               settings.bake_memory_bytes)
        except (redis.exceptions.ConnectionError, redis.exceptions.TimeoutError) as e:
            # Redis down: the bake is safe in the catalog; recovery enqueues it once Redis is back
            log.warning("could not enqueue bake %s now (%s); recovery will", bake_id, e)
        except Exception as e:
            log.exception("enqueueing bake %s failed", bake_id)
            msg = f"could not enqueue the bake ({type(e).__name__}); it has been logged"  # no reprs or paths
            catalog.set_bake_status(bake_id, "failed", error={"stage": None, "code": "internal", "message": msg})
    bake = catalog.get_bake(bake_id)
    return {"id": bake_id, "status": bake["status"], "links": links(bake_id)}


@router.get("", summary="List bakes (filter by scene and status; paginated)", response_model=BakesPublic,
            responses=error_responses(401, {422: "limit, offset or status out of range"}))
def list_bakes(team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
               scene_id: str | None = None,
               status: Literal["queued", "running", "succeeded", "failed", "cancelled"] | None = None,
               pg: Page = Depends(page)):
    limit, offset = pg
    items, total = catalog.list_bakes(team, scene_id, status, limit, offset)
    full = [catalog.get_bake(b["id"]) for b in items]
    scenes: dict = {}
    return json_response({"items": [public(b, scene_warnings=_scene_warnings(catalog, b, scenes)) for b in full if b],
                          "total": total, "limit": limit, "offset": offset})


@router.get("/{bake_id}", summary="A bake: status, per-stage progress, timings, error, warnings, artifacts",
            response_model=BakePublic, responses=error_responses(401, _NO_BAKE))
def get_bake(bake_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
             store: Store = Depends(deps.store)):
    bake = _get(catalog, team, bake_id)
    return json_response(public(bake, store, _scene_warnings(catalog, bake)))


@router.post("/{bake_id}/cancel", summary="Cancel a queued or running bake", response_model=BakePublic,
             responses=error_responses(401, _NO_BAKE, {409: "the bake has finished (bake_finished)"}, 413))
def cancel_bake(bake_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                store: Store = Depends(deps.store), conn: redis.Redis = Depends(deps.redis_conn)):
    bake = _get(catalog, team, bake_id)
    if bake["status"] in TERMINAL:
        raise ApiError(409, "bake_finished", f"the bake is already {bake['status']}")
    _cancel(conn, catalog, bake)
    bake = catalog.get_bake(bake_id)
    return json_response(public(bake, store, _scene_warnings(catalog, bake)))


def _cancel(conn: redis.Redis, catalog: Catalog, bake: dict) -> None:
    """Cancel in the catalog first (a running stage's progress callback and every later job see it), then stop
    the jobs: queued ones are cancelled, a running one's work-horse is killed by its worker at once."""
    catalog.set_bake_status(bake["id"], "cancelled", only_from=("queued", "running"))
    for s in bake["stages"]:
        if s["status"] in ("pending", "retrying", "running"):
            catalog.update_stage(bake["id"], s["name"], status="cancelled")
    try:
        queue.cancel_jobs(conn, bake)
    except Exception as e:
        log.warning("could not cancel the jobs of bake %s (%s); they will skip it", bake["id"], e)


@router.delete("/{bake_id}", status_code=204, summary="Delete a bake (cancelling it first)",
               response_class=Response, responses=error_responses(401, _NO_BAKE))
def delete_bake(bake_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                settings: Settings = Depends(deps.settings), conn: redis.Redis = Depends(deps.redis_conn)):
    bake = _get(catalog, team, bake_id)
    if bake["status"] not in TERMINAL:
        _cancel(conn, catalog, bake)
    catalog.delete_bake(bake_id)
    zpath = settings.data / "bundles" / f"{bake_id}.zip"
    zpath.unlink(missing_ok=True)
    return Response(status_code=204)


def _snapshot(bake: dict, scene_warnings: list[str] | None = None) -> dict:
    return {"id": bake["id"], "scene_id": bake["scene_id"], "status": bake["status"], "error": bake["error"],
            "stages": [{k: s[k] for k in ("name", "status", "progress", "seconds", "cached")} for s in bake["stages"]],
            "warnings": bake_warnings(bake, scene_warnings)}


SSE_EVENT = {
    "type": "object", "required": ["event", "data"], "description": "one Server-Sent Event",
    "properties": {
        "event": {"type": "string", "enum": ["progress", "status", "deleted"]},
        "data": {"type": "string", "contentMediaType": "application/json", "contentSchema": {"anyOf": [
            {"$ref": f"#/components/schemas/{BakeSnapshot.__name__}"},
            {"type": "object", "required": ["id"], "properties": {"id": {"type": "string"}},
             "additionalProperties": False, "description": "event: deleted"}]}},
    },
}
"""An event of ``GET /v1/bakes/{id}/events`` in the OpenAPI document (3.1: a text/event-stream's ``schema`` is
one event); its ``data`` is a :class:`BakeSnapshot` (server.api.openapi adds it to the components)."""


@router.get("/{bake_id}/events", summary="Server-Sent Events: stage progress, then the final status",
            response_class=StreamingResponse,
            responses={200: {"description": "`event: progress` with a BakeSnapshot as `data` at each change, then "
                                            "one `event: status` (the final snapshot; `event: deleted`, `data: "
                                            "{\"id\"}`, when the bake is deleted meanwhile); `: keep-alive` "
                                            "comments every 15 s",
                             "content": {"text/event-stream": {"schema": SSE_EVENT}}},
                       **error_responses(401, _NO_BAKE)})
async def bake_events(bake_id: str, request: Request, team: str = Depends(deps.team),
                      catalog: Catalog = Depends(deps.catalog)):
    scene_warnings = _scene_warnings(catalog, _get(catalog, team, bake_id))

    async def stream():
        last, last_sent = None, time.monotonic()
        while True:
            bake = await asyncio.to_thread(catalog.get_bake, bake_id, team)
            if bake is None:
                yield f"event: deleted\ndata: {json.dumps({'id': bake_id})}\n\n"
                return
            snap = _snapshot(bake, scene_warnings)
            if snap != last:
                yield f"event: progress\ndata: {finite_dumps(snap)}\n\n"
                last, last_sent = snap, time.monotonic()
            if bake["status"] in TERMINAL:
                yield f"event: status\ndata: {finite_dumps(snap)}\n\n"
                return
            if time.monotonic() - last_sent > SSE_HEARTBEAT_S:
                yield ": keep-alive\n\n"
                last_sent = time.monotonic()
            if await request.is_disconnected():
                return
            await asyncio.sleep(SSE_POLL_S)

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


_FILE = {"schema": {"type": "string", "format": "binary"}}
_RANGE_PARAMETERS = [
    {"name": "Range", "in": "header", "required": False, "schema": {"type": "string"},
     "description": "bytes=START-END (one or more ranges): 206 with those bytes"},
    {"name": "If-Range", "in": "header", "required": False, "schema": {"type": "string"},
     "description": "the ETag: the Range applies only while the file is the same"},
]


@router.get("/{bake_id}/artifacts/{name}", summary="One artifact file (ETag, Range)",
            response_class=BlobResponse,
            openapi_extra={"parameters": [
                {"name": "If-None-Match", "in": "header", "required": False, "schema": {"type": "string"},
                 "description": "the ETag (the artifact's sha256, quoted) the client has: 304 when it matches"},
                *_RANGE_PARAMETERS]},
            responses={200: {"description": "the file (by its format: image/ktx2, application/octet-stream for "
                                            "npy, application/json, image/png, model/gltf-binary)",
                             "content": {m: _FILE for m in dict.fromkeys(MEDIA.values())}},
                       206: {"description": "the requested byte ranges (multipart/byteranges for several)",
                             "content": {**{m: _FILE for m in dict.fromkeys(MEDIA.values())},
                                         "multipart/byteranges": _FILE}},
                       304: {"description": "If-None-Match names this artifact's ETag"},
                       **error_responses({400: "a malformed Range header"}, 401,
                                         {404: "no such bake for this team, or no such artifact (yet)"}, 416)})
def get_artifact(bake_id: str, name: str, request: Request, team: str = Depends(deps.team),
                 catalog: Catalog = Depends(deps.catalog), store: Store = Depends(deps.store)):
    bake = _get(catalog, team, bake_id)
    infos = {a["name"]: a for a in bake_artifacts(store, bake)}
    info = infos.get(name) or next((a for a in infos.values() if a["file"] == name), None)
    if info is None:
        raise ApiError(404, "artifact_not_found", f"bake {bake_id} has no artifact {name!r} (yet)")
    etag = f'"{info["sha256"]}"'
    if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
        return Response(status_code=304, headers={"ETag": etag})
    return BlobResponse(store.blob_path(info["sha256"]), media_type=MEDIA.get(info["format"]),
                        filename=info["file"], content_disposition_type="inline",
                        headers={"ETag": etag, "Cache-Control": "private, max-age=31536000, immutable"})


@router.get("/{bake_id}/bundle", summary="The whole bundle as one zip", response_class=BlobResponse,
            openapi_extra={"parameters": _RANGE_PARAMETERS},
            responses={200: {"description": "the bundle zip (manifest.json + one file per artifact)",
                             "content": {"application/zip": _FILE}},
                       206: {"description": "the requested byte ranges",
                             "content": {"application/zip": _FILE, "multipart/byteranges": _FILE}},
                       **error_responses({400: "a malformed Range header"}, 401, _NO_BAKE,
                                         {409: "the bake has not succeeded (bake_not_finished)"}, 416)})
def get_bundle(bake_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
               store: Store = Depends(deps.store), settings: Settings = Depends(deps.settings)):
    bake = _get(catalog, team, bake_id)
    if bake["status"] != "succeeded":
        raise ApiError(409, "bake_not_finished", f"the bake is {bake['status']}; the bundle exists once it succeeds")
    zdir = settings.data / "bundles"
    zpath = zdir / f"{bake_id}.zip"
    if not zpath.exists():
        with tempfile.TemporaryDirectory(dir=store.root / "tmp") as work:
            export_bundle(store, Manifest.model_validate(bake["manifest"]), work)
            zdir.mkdir(parents=True, exist_ok=True)
            bundle.zip_bundle(work, zpath)
    return BlobResponse(zpath, media_type="application/zip", filename=f"kiln-bake-{bake_id}.zip")
