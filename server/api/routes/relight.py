"""``POST /v1/bakes/{id}/relight``: a PRT bake's reconstructed indirect for new lights (DESIGN stage 6).

Body: ``{"lights": [LightConfig, ...], "lightmap": true}`` (``proto.models.LightConfig``: point, spot or
directional, KHR_lights_punctual units; at most 64; an empty list gives zeros). A bad light is a 422
naming the field (``lights.0.position: ...``).

Response — a **bundle** (proto/bundle.md) holding the relit arrays, in one of two encodings:

- ``?format=zip`` (default): ``application/zip``, exactly a bundle zip (``proto.bundle.zip_bundle``:
  ``manifest.json`` + files, deterministic), readable with ``proto.bundle.open_bundle``;
- ``?format=json``: ``{"format": "kiln-relight/1", "manifest": {...}, "files": {file name: base64}}``, the
  same manifest and file bytes, for a browser that would rather not unzip.

The manifest is the bake's (scene summary, config, grid) with one stage, ``relight``, and the light stage's
artifact names and layouts (``probe_sh``, ``sh_l1_r/g/b``, ``lightmap``, ``prt_direct``, ``relight``): see
:mod:`workers.relight`, which does the work (loads the PRT model, traces the shadow rays, writes the bundle).
This route checks the request, reads the catalog and encodes the answer; the caches (unpacked models, ray
casters) belong to the app (``app.state.relight_cache``, taken through ``server.api.deps.relight_cache``).

The relit values are the indirect light of the given lights only: the scene's emission, its own lights
and the sky are not part of the transfer (see workers/stages/prt.py). Errors: 404 ``bake_not_found``
(unknown, or another team's); 409 ``no_prt`` when the bake has no PRT transfer (made with
``prt.enabled = false``, or its prt stage has not finished).
"""
from __future__ import annotations

import base64
import json
import tempfile
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Depends, Query
from fastapi.responses import Response

from persist.catalog import Catalog
from persist.export import bake_artifacts
from persist.store import Store
from proto import bundle
from server.api import deps
from server.api.errors import ApiError
from server.api.jsonbody import FiniteJSONResponse, FiniteJSONRoute
from server.api.schemas import RelightJSON, RelightRequest, error_responses
from workers.relight import RelightCache, write_relit_bundle

router = APIRouter(prefix="/v1/bakes", tags=["relight"], route_class=FiniteJSONRoute)


@router.post("/{bake_id}/relight", summary="Relight a PRT bake: new lights -> probe SH volume and lightmap",
             response_model=RelightJSON,
             responses={200: {"content": {"application/zip": {"schema": {"type": "string", "format": "binary"}},
                                          "application/json": {}},
                              "description": "a bundle of the relit arrays: a zip (format=zip, the default), or "
                                             "JSON with the manifest and base64 files (format=json)"},
                        **error_responses(401, {404: "no such bake for this team",
                                                409: "the bake has no PRT transfer (no_prt)"}, 413,
                                          {422: "a light refused (the message names the field), or format"})})
def relight_bake(bake_id: str, body: RelightRequest,
                 format: Literal["zip", "json"] = Query("zip", description="zip (a bundle) or json (base64 files)"),
                 team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                 store: Store = Depends(deps.store), cache: RelightCache = Depends(deps.relight_cache)):
    bake = catalog.get_bake(bake_id, team)
    if bake is None:
        raise ApiError(404, "bake_not_found", f"no bake {bake_id}")
    infos = {a["name"]: a for a in bake_artifacts(store, bake)}
    if "prt" not in infos:
        if not (bake.get("config") or {}).get("prt", {}).get("enabled", False):
            raise ApiError(409, "no_prt", f"bake {bake_id} has no PRT transfer: it was made with prt.enabled = false")
        raise ApiError(409, "no_prt", f"bake {bake_id} has no PRT transfer yet (the bake is {bake['status']})")
    scene = catalog.get_scene(team, bake["scene_id"]) or {}
    lights = [light.model_dump(mode="json") for light in body.lights]
    with tempfile.TemporaryDirectory(dir=store.root / "tmp") as tmp:
        folder = Path(tmp) / "relit"
        manifest = write_relit_bundle(store, bake, scene, infos, lights, folder, lightmap=body.lightmap, cache=cache)
        if format == "json":
            files = {"manifest.json": (folder / "manifest.json").read_bytes()}
            files |= {a.file: (folder / a.file).read_bytes() for a in manifest.artifacts}
            return FiniteJSONResponse({"format": "kiln-relight/1", "manifest": json.loads(files["manifest.json"]),
                                       "files": {n: base64.b64encode(b).decode() for n, b in files.items()}})
        zpath = bundle.zip_bundle(folder, Path(tmp) / "relit.zip")
        data = zpath.read_bytes()
    return Response(content=data, media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="kiln-relight-{bake_id}.zip"',
                             "Cache-Control": "no-store"})
