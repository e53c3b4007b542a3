"""``/v1/scenes/{id}/thresholds``: a scene's quality thresholds, the ``kiln bake --fail-on`` gates kept on the server.

The thresholds are gates of :mod:`server.gates` (``mask_normalized.leak > 0.05``, ``*.rmse >= 0.2``: a gate
*fails* a bake when its comparison holds, or when it names no metric of the bake). They are stored with the
scene in the catalog (``summary.thresholds``, beside the review cameras) and checked with the same code the CLI
uses (``gates.manifest_metrics`` + ``gates.check``) against each of the scene's succeeded bakes: the dashboard
shows pass/fail per bake and draws each threshold on the metric's chart.

``GET`` answers ``{"scene_id", "thresholds": [text], "gates": [{"text", "metric", "op", "value"}],
"bakes": [{"bake_id", "created", "passed", "results": [{"text", "passed", "matched", "failing", "message"}]}]}``
(the newest ``limit`` succeeded bakes, newest first). ``PUT`` takes ``{"thresholds": [text, ...]}`` (at most
32; an empty list removes them), refuses the whole list with 422 ``invalid_threshold`` naming the first gate that
does not parse, and answers like GET. Another team's scene reads as 404, as everywhere.
"""
from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from persist.catalog import Catalog
from server import gates
from server.api import deps
from server.api.errors import ApiError
from server.api.jsonbody import FiniteJSONResponse, FiniteJSONRoute
from server.api.schemas import SceneThresholds, ThresholdsBody, error_responses

router = APIRouter(prefix="/v1/scenes", tags=["scenes"], route_class=FiniteJSONRoute)


def _scene(catalog: Catalog, team: str, scene_id: str) -> dict:
    s = catalog.get_scene(team, scene_id)
    if s is None:
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    return s


def thresholds_doc(catalog: Catalog, team: str, scene: dict, limit: int = 100) -> dict:
    """What GET answers for a scene (module doc)."""
    texts = [str(t) for t in scene.get("thresholds") or []]
    parsed = gates.parse_gates(texts)
    items, _ = catalog.list_bakes(team, scene["id"], "succeeded", limit, 0)
    bakes = []
    for b in items:
        metrics = gates.manifest_metrics(b.get("manifest") or {})
        checked = gates.parse_gates(texts)          # fresh Gate objects: check() fills them in
        gates.check(checked, metrics)
        results = [{"text": g.text, "passed": not g.failed, "matched": g.matched, "failing": g.failing,
                    "message": g.describe()} for g in checked]
        bakes.append({"bake_id": b["id"], "created": b["created"], "passed": all(r["passed"] for r in results),
                      "results": results})
    return {"scene_id": scene["id"], "thresholds": [g.text for g in parsed],
            "gates": [{"text": g.text, "metric": g.metric, "op": g.op, "value": g.value} for g in parsed],
            "bakes": bakes}


_NO_SCENE = {404: "no such scene for this team"}
_LIMIT = Query(100, ge=1, le=500, description="how many of the scene's newest succeeded bakes to check")


@router.get("/{scene_id}/thresholds", summary="The scene's quality thresholds and their pass/fail per bake",
            response_model=SceneThresholds, responses=error_responses(401, _NO_SCENE, 422))
def get_thresholds(scene_id: str, limit: int = _LIMIT, team: str = Depends(deps.team),
                   catalog: Catalog = Depends(deps.catalog)):
    return FiniteJSONResponse(thresholds_doc(catalog, team, _scene(catalog, team, scene_id), limit))


@router.put("/{scene_id}/thresholds", summary="Set the scene's quality thresholds (an empty list removes them)",
            response_model=SceneThresholds,
            responses=error_responses(401, _NO_SCENE, 413,
                                      {422: "a threshold that does not parse (invalid_threshold names it)"}))
def put_thresholds(scene_id: str, body: ThresholdsBody, limit: int = _LIMIT, team: str = Depends(deps.team),
                   catalog: Catalog = Depends(deps.catalog)):
    _scene(catalog, team, scene_id)
    texts = []
    for i, t in enumerate(body.thresholds):
        try:
            texts.append(gates.parse_gate(t).text)
        except gates.GateError as e:
            raise ApiError(422, "invalid_threshold", f"thresholds[{i}]: {e}") from None
    if not catalog.set_scene_thresholds(team, scene_id, texts or None):
        raise ApiError(404, "scene_not_found", f"no scene {scene_id}")
    return FiniteJSONResponse(thresholds_doc(catalog, team, _scene(catalog, team, scene_id), limit))
