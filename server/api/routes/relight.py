"""``POST /v1/bakes/{id}/relight``: a PRT bake's reconstructed indirect for new lights (DESIGN stage 6).

Body: ``{"lights": [LightConfig, ...], "lightmap": true}`` (``proto.models.LightConfig``: point, spot or
directional, KHR_lights_punctual units; at most 64; an empty list gives zeros). A bad light is a 422
naming the field (``lights.0.position: ...``).

Response — a **bundle** (proto/bundle.md) holding the relit arrays, in one of two encodings:

- ``?format=zip`` (default): ``application/zip``, exactly a bundle zip (``proto.bundle.zip_bundle``:
  ``manifest.json`` + files, deterministic), readable with ``proto.bundle.open_bundle``;
- ``?format=json``: ``{"format": "kiln-relight/1", "manifest": {...}, "files": {file name: base64}}``, the
  same manifest and file bytes, for a browser that would rather not unzip.

The manifest is the bake's (scene summary, config, grid) with one stage, ``relight`` (its stats: seconds,
light count, direct norm) and these artifacts (the light stage's names and layouts, proto/bundle.md §5.1,
so a viewer swaps them in for the baked ones):

================ ================================== =====================================================
``probe_sh``     npy (nz, ny, nx, K, 3) float32      radiance SH per probe (three.js order, K = 9 or 4)
``sh_l1_r/g/b``  ktx2 (nz, ny, nx, 4) RGBA32F        L0 + L1 of one colour channel per probe
``lightmap``     ktx2 (R, R, 4) RGBA32F              indirect irradiance rgb, a = 1 on covered texels
                                                     (only when the bake has a lightmap and ``lightmap``)
``prt_direct``   npy (M, 3) float32                  the direct vector at the measurement points
``relight``      json                                the request's lights and timings
================ ================================== =====================================================

The relit values are the indirect light of the given lights only: the scene's emission, its own lights
and the sky are not part of the transfer (see workers/stages/prt.py). Errors: 404 ``bake_not_found``
(unknown, or another team's); 409 ``no_prt`` when the bake has no PRT transfer (made with
``prt.enabled = false``, or its prt stage has not finished).

The direct vector needs shadow rays: the API process traces them (Embree), with one ray caster per scene
built on first use and cached (workers.prt_relight.get_caster), and the unpacked PRT model cached per bake
output; a relight then costs well under a millisecond of math plus encoding the response.
"""
from __future__ import annotations

import base64
import hashlib
import json
import tempfile
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Depends, Query
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field, StrictBool

from persist.catalog import Catalog
from persist.store import Store
from proto import bundle
from proto.models import ArtifactInfo, LightConfig, Manifest, SceneSummary, StageInfo
from proto.stages import KILN_VERSION
from server.api import deps
from server.api.errors import ApiError
from server.api.jsonbody import FiniteJSONResponse, FiniteJSONRoute
from server.api.routes.bakes import _artifact_infos
from server.api.schemas import RelightJSON, error_responses

router = APIRouter(prefix="/v1/bakes", tags=["relight"], route_class=FiniteJSONRoute)

MODEL_CACHE_SIZE = 8
"""Unpacked PRT models kept in the API process (a few MB each for a 16x32x16 grid)."""
_models: "OrderedDict[str, object]" = OrderedDict()
_models_lock = threading.Lock()


class RelightRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    lights: list[LightConfig] = Field(..., max_length=64, description="the lights to relight with")
    lightmap: StrictBool = Field(True, description="also reconstruct the lightmap (when the bake has one)")


def _prt_model(store: Store, infos: dict[str, dict]):
    """The bake's unpacked PRT model, cached by the sha256 of its artifacts."""
    from workers.prt_relight import PrtModel

    key = hashlib.sha256("".join(sorted(i["sha256"] for n, i in infos.items() if n.startswith("prt"))).encode()
                         ).hexdigest()
    with _models_lock:
        if key in _models:
            _models.move_to_end(key)
            return _models[key]
    section = bundle.load_artifact(store.blob_path(infos["prt"]["sha256"]), _info(infos["prt"]))
    names = {"prt", section["points"], section["point_offsets"], section["sh"]["transfer"],
             *(n for group in section["sh"]["basis"] for n in group)}
    if section.get("lightmap"):
        lm = section["lightmap"]
        names |= {lm["transfer"], lm["mask"], *lm["basis"]}
    arrays = {n: bundle.load_artifact(store.blob_path(infos[n]["sha256"]), _info(infos[n])) for n in names}
    model = PrtModel.from_arrays(arrays)
    with _models_lock:
        _models[key] = model
        while len(_models) > MODEL_CACHE_SIZE:
            _models.popitem(last=False)
    return model


def _info(d: dict) -> ArtifactInfo:
    return ArtifactInfo(**d)


def _grid(bake: dict) -> dict:
    if bake.get("manifest"):
        return bake["manifest"].get("grid", {})
    for s in bake["stages"]:
        if s["name"] == "place" and s.get("stats"):
            return {k: s["stats"][k] for k in ("counts", "origin", "spacing") if k in s["stats"]}
    return {}


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
                 store: Store = Depends(deps.store)):
    from workers.prt_relight import get_caster, relight
    from workers.scene import NormalizedScene

    bake = catalog.get_bake(bake_id, team)
    if bake is None:
        raise ApiError(404, "bake_not_found", f"no bake {bake_id}")
    infos = {a["name"]: a for a in _artifact_infos(store, bake)}
    if "prt" not in infos:
        if not (bake.get("config") or {}).get("prt", {}).get("enabled", False):
            raise ApiError(409, "no_prt", f"bake {bake_id} has no PRT transfer: it was made with prt.enabled = false")
        raise ApiError(409, "no_prt", f"bake {bake_id} has no PRT transfer yet (the bake is {bake['status']})")
    t0 = time.perf_counter()
    model = _prt_model(store, infos)
    scene_id = bake["scene_id"]
    caster = get_caster(scene_id, lambda: NormalizedScene.from_bytes(store.read_bytes(scene_id)))
    t1 = time.perf_counter()
    lights = [light.model_dump(mode="json") for light in body.lights]
    out = relight(model, lights, caster, lightmap=body.lightmap)
    t2 = time.perf_counter()

    scene = catalog.get_scene(team, scene_id) or {}
    summary = SceneSummary(id=scene_id, triangles=scene.get("triangles", 0), bounds=scene.get("bounds", []),
                           lights=scene.get("lights", 0), materials=scene.get("materials", 0),
                           warnings=scene.get("warnings", []))
    info = {"bake_id": bake_id, "lights": lights, "load_seconds": t1 - t0, "relight_seconds": t2 - t1,
            "direct_norm": [float(v) for v in (out["prt_direct"] ** 2).sum(axis=0) ** 0.5],
            "note": "indirect light of these lights only (no emission, scene lights or sky)"}
    with tempfile.TemporaryDirectory(dir=store.root / "tmp") as tmp:
        folder = Path(tmp) / "relit"
        arts = [bundle.write_artifact(folder, "probe_sh", out["probe_sh"], "relight", format="npy",
                                      description="relit radiance SH per probe (three.js order), linear RGB")]
        for c in "rgb":
            arts.append(bundle.write_artifact(folder, f"sh_l1_{c}", out[f"sh_l1_{c}"], "relight",
                                              description=f"relit L0 + L1 radiance SH of the {c} channel per probe"))
        if "lightmap" in out:
            arts.append(bundle.write_artifact(folder, "lightmap", out["lightmap"], "relight",
                                              description="relit indirect irradiance, a = 1 on covered texels",
                                              meta={"uv": "prt_lm_uv"}))
        arts.append(bundle.write_artifact(folder, "prt_direct", out["prt_direct"], "relight", format="npy",
                                          description="direct vector at the measurement points"))
        arts.append(bundle.write_artifact(folder, "relight", info, "relight", format="json",
                                          description="the request's lights and timings"))
        key = hashlib.sha256(json.dumps(lights, sort_keys=True).encode()).hexdigest()
        manifest = Manifest(kiln_version=KILN_VERSION, bake_id=bake_id, scene=summary,
                            config=bake.get("config") or {}, grid=_grid(bake),
            stages=[StageInfo(name="relight", seconds=t2 - t1, cache_key=key,
                              stats={"lights": len(lights), "direct_norm": info["direct_norm"]})],
            artifacts=arts)
        bundle.write_manifest(folder, manifest)
        if format == "json":
            files = {"manifest.json": (folder / "manifest.json").read_bytes()}
            files |= {a.file: (folder / a.file).read_bytes() for a in arts}
            return FiniteJSONResponse({"format": "kiln-relight/1", "manifest": json.loads(files["manifest.json"]),
                                       "files": {n: base64.b64encode(b).decode() for n, b in files.items()}})
        zpath = bundle.zip_bundle(folder, Path(tmp) / "relit.zip")
        data = zpath.read_bytes()
    return Response(content=data, media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="kiln-relight-{bake_id}.zip"',
                             "Cache-Control": "no-store"})

