"""``GET /v1/compare?a=<bake>&b=<bake>``: the metric deltas of two bakes of the caller's team (DESIGN "Service").

A bake's metrics are the catalog's (``catalog.get_bake(...)["metrics"]``: stage seconds, artifact bytes, and
whatever the finisher records) merged with the flat ``metrics`` of its ``evaluate`` stage's stats in the
manifest (``<mode>.rmse``, ``<mode>.flip``, ``<mode>.leak``, ``<mode>.pass_ms``, ``<mode>.texture_bytes``,
``<mode>.gi_fetches_per_pixel``, …; workers/stages/evaluate.py).

Response::

    {"a": {"id", "scene_id", "status", "created"}, "b": {...},
     "metrics": {name: {"a": x, "b": y, "delta": y - x, "ratio": y / x or null}},   # names both bakes have
     "only_a": [names], "only_b": [names]}

Errors: 404 ``bake_not_found`` for an unknown bake or another team's (indistinguishable, as everywhere);
409 ``no_metrics`` when a bake has no evaluate metrics yet (not evaluated, or not finished); 422 when a
parameter is missing.
"""
from __future__ import annotations

import math

from fastapi import APIRouter, Depends, Query

from persist.catalog import Catalog
from server.api.deps import catalog, team
from server.api.errors import ApiError
from server.api.jsonbody import FiniteJSONResponse, FiniteJSONRoute
from server.api.schemas import Comparison, error_responses

router = APIRouter(prefix="/v1", tags=["compare"], route_class=FiniteJSONRoute)


def bake_metrics(bake: dict) -> dict[str, float]:
    """Catalog metrics + the evaluate stage's flat metrics from the manifest (the latter win)."""
    out = {k: float(v) for k, v in (bake.get("metrics") or {}).items() if isinstance(v, (int, float))}
    manifest = bake.get("manifest") or {}
    for st in manifest.get("stages") or []:
        if st.get("name") == "evaluate":
            for k, v in ((st.get("stats") or {}).get("metrics") or {}).items():
                if isinstance(v, (int, float)) and math.isfinite(v):
                    out[k] = float(v)
    return out


def _has_eval(bake: dict, metrics: dict) -> bool:
    manifest = bake.get("manifest") or {}
    if any(s.get("name") == "evaluate" for s in manifest.get("stages") or []):
        return True
    return any(k.endswith((".rmse", ".pass_ms")) for k in metrics)  # a finisher that copies them to the catalog


def _summary(b: dict) -> dict:
    return {k: b.get(k) for k in ("id", "scene_id", "status", "created")}


@router.get("/compare", summary="Metric deltas of two bakes (both evaluated)", response_model=Comparison,
            responses=error_responses(401, {404: "no such bake for this team",
                                            409: "a bake has no evaluate metrics yet (no_metrics)",
                                            422: "a or b missing"}))
def compare(a: str = Query(..., description="the first bake's id"), b: str = Query(..., description="the second"),
            team_: str = Depends(team), cat: Catalog = Depends(catalog)):
    bakes = {}
    for key, bid in (("a", a), ("b", b)):
        bake = cat.get_bake(bid, team_)
        if bake is None:
            raise ApiError(404, "bake_not_found", f"no bake {bid!r}")
        bakes[key] = bake
    ms = {}
    for key, bake in bakes.items():
        m = bake_metrics(bake)
        if not _has_eval(bake, m):
            raise ApiError(409, "no_metrics", f"bake {bake['id']} has no evaluate metrics (status "
                                              f"{bake.get('status')}); it must finish an evaluate stage first")
        ms[key] = m
    common = sorted(set(ms["a"]) & set(ms["b"]))
    out = {}
    for name in common:
        x, y = ms["a"][name], ms["b"][name]
        out[name] = {"a": x, "b": y, "delta": y - x, "ratio": (y / x) if x != 0 else None}
    return FiniteJSONResponse({"a": _summary(bakes["a"]), "b": _summary(bakes["b"]), "metrics": out,
                               "only_a": sorted(set(ms["a"]) - set(ms["b"])),
                               "only_b": sorted(set(ms["b"]) - set(ms["a"]))})
