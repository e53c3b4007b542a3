"""``/v1/scenes/{id}/cameras``: a scene's review cameras, and what a bake's record shows of its check points.

Every bake of a scene is scored from the same review cameras (the evaluate stage's previews and, with
``evaluate.sampling = "cameras"``, its surface points: workers/stages/reference.py). They are, in order:

1. ``stored``: cameras saved with ``PUT /v1/scenes/{id}/cameras`` (kept with the scene in the catalog,
   ``summary.review_cameras``);
2. ``gltf``: the glTF's own perspective cameras (read at upload, :mod:`workers.gltf.cameras`);
3. ``auto``: placed by the bake in free space looking at geometry (``evaluate.cameras`` of them); GET shows the
   ones the scene's latest evaluated bake recorded (``from_bake``), or none before the first.

A bake created while the scene has stored cameras and whose config leaves ``evaluate.cameras`` a count gets the
stored list in its ``evaluate.cameras`` (:func:`with_review_cameras`, called by ``POST /v1/bakes``): the bake's
config records which cameras it used, and a PUT changes the reference stage's cache key (a new reference for the
new views), while bakes with the same cameras keep sharing one.

``GET`` answers ``{"scene_id", "source", "cameras": [{"name", "position", "target", "fov_y"}], "from_bake"}``;
``PUT`` takes ``{"cameras": [{"position", "target", "fov_y"?, "name"?}, ...]}`` (at most 16, world space,
metres, degrees; an empty list removes the stored cameras) and answers like GET.
"""
from __future__ import annotations

import io
import json
import re

from fastapi import APIRouter, Depends

from persist.catalog import Catalog
from persist.store import Store
from proto.models import BakeConfig
from server.api import deps
from server.api.errors import ApiError
from server.api.jsonbody import FiniteJSONResponse, FiniteJSONRoute
from server.api.schemas import CamerasBody, SceneCameras, error_responses

router = APIRouter(prefix="/v1/scenes", tags=["scenes"], route_class=FiniteJSONRoute)


def _named(cameras: list[dict]) -> list[dict]:
    """Cameras with unique names safe for artifact names (``review-<i>`` where none is given)."""
    out, taken = [], set()
    for i, c in enumerate(cameras):
        name = c.get("name") or f"review-{i}"
        name = re.sub(r"[^a-z0-9_-]+", "-", str(name).lower())[:32] or f"review-{i}"
        while name in taken:
            name = f"{name[:26]}-{i}"
        taken.add(name)
        d = {"name": name, "position": [float(x) for x in c["position"]], "target": [float(x) for x in c["target"]]}
        if c.get("fov_y") is not None:
            d["fov_y"] = float(c["fov_y"])
        out.append(d)
    return out


def gltf_cameras(store: Store, scene_id: str) -> list[dict]:
    """The glTF's own cameras of a stored scene (its normalized scene's metadata only; [] when unreadable)."""
    import numpy as np

    try:
        with np.load(io.BytesIO(store.read_bytes(scene_id)), allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
    except Exception:
        return []
    return [{k: c[k] for k in ("name", "position", "target", "fov_y") if k in c} for c in meta.get("cameras") or []]


def _last_bake_cameras(catalog: Catalog, team: str, scene_id: str) -> tuple[list[dict], str | None]:
    items, _ = catalog.list_bakes(team, scene_id, "succeeded", 20, 0)
    for b in items:
        for st in (b.get("manifest") or {}).get("stages", []):
            cams = (st.get("stats") or {}).get("cameras") if st.get("name") == "evaluate" else None
            if isinstance(cams, list) and cams:
                return [{"name": c.get("name"), "position": c.get("position"), "target": c.get("target"),
                         "fov_y": c.get("fov")} for c in cams], b["id"]
    return [], None


def cameras_doc(catalog: Catalog, store: Store, team: str, scene: dict) -> dict:
    """What GET answers for a scene (module doc)."""
    sid = scene["id"]
    stored = scene.get("review_cameras")
    if stored:
        return {"scene_id": sid, "source": "stored", "cameras": stored, "from_bake": None}
    own = gltf_cameras(store, sid)
    if own:
        return {"scene_id": sid, "source": "gltf", "cameras": own, "from_bake": None}
    cams, bake_id = _last_bake_cameras(catalog, team, sid)
    return {"scene_id": sid, "source": "auto", "cameras": cams, "from_bake": bake_id}


def with_review_cameras(config: BakeConfig, scene: dict | None) -> BakeConfig:
    """The config a bake of ``scene`` runs with: the scene's stored review cameras in ``evaluate.cameras`` when it
    has some, evaluate is on and the config gives a camera count rather than a list (module doc)."""
    stored = (scene or {}).get("review_cameras")
    ev = config.evaluate
    if not stored or not ev.enabled or isinstance(ev.cameras, list):
        return config
    data = config.model_dump(mode="json")
    data["evaluate"]["cameras"] = stored
    return BakeConfig.model_validate(data)


def check_points_of(store: Store, bake: dict) -> dict | None:
    """The ``check_points`` artifact of a bake (evaluate with ``evaluate.points``), or None: the ``check_points``
    field of ``GET /v1/bakes/{id}``."""
    from proto import bundle
    from proto.models import ArtifactInfo

    infos = (bake.get("manifest") or {}).get("artifacts")
    if infos is None:            # not finished: the evaluate stage's record, once it succeeded
        infos = []
        for s in bake.get("stages", []):
            if s.get("name") == "evaluate" and s.get("status") == "succeeded":
                rec = store.get_stage(s["cache_key"])
                infos = (rec or {}).get("artifacts", [])
    info = next((a for a in infos if a.get("name") == "check_points"), None)
    if info is None:
        return None
    try:
        return bundle.load_artifact(store.blob_path(info["sha256"]), ArtifactInfo(**info))
    except Exception:
        return None


def _scene(catalog: Catalog, team: str, scene_id: str) -> dict:
    s = catalog.get_scene(team, scene_id)
    if s is None:
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    return s


_NO_SCENE = {404: "no such scene for this team"}


@router.get("/{scene_id}/cameras", summary="The scene's review cameras (stored, the glTF's own, or automatic)",
            response_model=SceneCameras, responses=error_responses(401, _NO_SCENE))
def get_cameras(scene_id: str, team: str = Depends(deps.team), catalog: Catalog = Depends(deps.catalog),
                store: Store = Depends(deps.store)):
    return FiniteJSONResponse(cameras_doc(catalog, store, team, _scene(catalog, team, scene_id)))


@router.put("/{scene_id}/cameras", summary="Set the scene's review cameras (an empty list removes them)",
            response_model=SceneCameras,
            responses=error_responses(401, _NO_SCENE, 413, {422: "a camera refused (the message names the field)"}))
def put_cameras(scene_id: str, body: CamerasBody, team: str = Depends(deps.team),
                catalog: Catalog = Depends(deps.catalog), store: Store = Depends(deps.store)):
    _scene(catalog, team, scene_id)
    cams = _named([c.model_dump() for c in body.cameras]) if body.cameras else None
    if not catalog.set_scene_cameras(team, scene_id, cams):
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    return FiniteJSONResponse(cameras_doc(catalog, store, team, _scene(catalog, team, scene_id)))
