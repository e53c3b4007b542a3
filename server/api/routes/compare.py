"""``GET /v1/compare?a=<bake>&b=<bake>``: the metric deltas of two bakes of the caller's team (DESIGN "Service").

A bake's metrics are the catalog's (``catalog.get_bake(...)["metrics"]``: stage seconds, artifact bytes, and
whatever the finisher records) merged with the flat ``metrics`` of its ``evaluate`` stage's stats in the
manifest (``<mode>.rmse``, ``<mode>.flip``, ``<mode>.leak``, ``<mode>.pass_ms``, ``<mode>.texture_bytes``,
``<mode>.gi_fetches_per_pixel``, …; workers/stages/evaluate.py).

Response::

    {"a": {"id", "scene_id", "status", "created"}, "b": {...},
     "metrics": {name: {"a": x, "b": y, "delta": y - x, "ratio": y / x or null,     # names both bakes have
                        "delta_stderr": paired standard error of the delta, or null}},
     "paired": {"paired": bool, "reason": str, "points": int, "check_points": int},
     "only_a": [names], "only_b": [names]}

Paired standard errors (:func:`paired_stderr`): two bakes scored against the SAME cached reference (their
``reference`` stages have one cache key: same scene, lighting and reference settings, whatever the probe config)
share its noise, which then largely cancels in the delta of a metric; the standard errors each bake carries count
it in full, so ``sqrt(seA² + seB²)`` overstates the delta's (two-rooms: 1.7x for rmse; for mean_ratio, whose
reference noise cancels exactly, 2000x in the simulation of tests/kernels/test_point_metrics.py). For each mode both
bakes evaluated, the surface-point metrics get :func:`workers.kernels.point_metrics.paired_delta_stderr` from the
reference's points and both bakes' ``eval_points``; the check-point regions' ``mean_ratio`` get
``|Δ| · se(reference mean) / reference mean`` (their common denominator is the only noise). Other metrics, and
bakes with different references (``paired.paired`` false, ``paired.reason`` says why), get ``delta_stderr`` null:
a client falls back to ``sqrt(seA² + seB²)``.

Errors: 404 ``bake_not_found`` for an unknown bake or another team's (indistinguishable, as everywhere);
409 ``no_metrics`` when a bake has no evaluate metrics yet (not evaluated, or not finished); 422 when a
parameter is missing.
"""
from __future__ import annotations

import math

import numpy as np
from fastapi import APIRouter, Depends, Query

from persist.catalog import Catalog
from persist.store import Store
from server.api.deps import catalog, store, team
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


def _stage_of(bake: dict, name: str) -> dict | None:
    """The bake's succeeded stage ``name`` (``{"name", "cache_key", ...}``), from its manifest or its stage list."""
    for st in ((bake.get("manifest") or {}).get("stages") or []) + (bake.get("stages") or []):
        if st.get("name") == name and st.get("cache_key") and st.get("status", "succeeded") == "succeeded":
            return st
    return None


def _artifact(st: Store, key: str, name: str):
    """``(data, meta)`` of artifact ``name`` of the stored stage record ``key`` (internal ones too), or None."""
    from proto import bundle
    from proto.models import ArtifactInfo

    rec = st.get_stage(key)
    info = next((a for a in (rec or {}).get("artifacts", []) if a.get("name") == name), None)
    if info is None:
        return None
    return bundle.load_artifact(st.blob_path(info["sha256"]), ArtifactInfo(**info)), info.get("meta") or {}


def paired_stderr(st: Store, a: dict, b: dict) -> tuple[dict[str, float], dict]:
    """Paired standard errors of the deltas ``b − a`` (module doc): ``({metric name: stderr}, paired info)``."""
    from workers.kernels import metrics as MT
    from workers.kernels import point_metrics as PM
    from workers.kernels.reference_layout import point_columns

    info = {"paired": False, "reason": "", "points": 0, "check_points": 0}
    ra, rb = _stage_of(a, "reference"), _stage_of(b, "reference")
    ea, eb = _stage_of(a, "evaluate"), _stage_of(b, "evaluate")
    if not (ra and rb and ea and eb):
        info["reason"] = "a bake has no reference or evaluate stage on record"
        return {}, info
    if ra["cache_key"] != rb["cache_key"]:
        info["reason"] = ("the bakes were scored against different references (scene, lighting or reference "
                          "settings differ): their standard errors are independent")
        return {}, info
    out: dict[str, float] = {}
    ref = _artifact(st, ra["cache_key"], "reference_points")
    pa, pb = _artifact(st, ea["cache_key"], "eval_points"), _artifact(st, eb["cache_key"], "eval_points")
    if ref is None or pa is None or pb is None:
        info["reason"] = "a bake's per-point values are not stored (evaluated before they were kept)"
        return {}, info
    pts = point_columns(ref[0])
    modes_a, modes_b = list(pa[1].get("modes") or []), list(pb[1].get("modes") or [])
    cache: dict = {}
    for m in (m for m in modes_a if m in modes_b):
        ia, ib = modes_a.index(m), modes_b.index(m)
        ta = np.asarray(pa[0], np.float64)[:, 3 * ia:3 * ia + 3]
        tb = np.asarray(pb[0], np.float64)[:, 3 * ib:3 * ib + 3]
        se = PM.paired_delta_stderr(ta, tb, pts["e_indirect"], pts["stderr"], pts["e_direct"], pts["albedo"],
                                    pts["emission"], cache=cache)
        out.update({f"{m}.{k}": v for k, v in se.items() if v is not None and math.isfinite(v)})
    info["points"] = int(len(pts["position"]))
    # check-point regions: mean_ratio = mean Y(T) / mean Y(R) over a region; only the common denominator is noisy
    ca, cb = _check_points(st, ea), _check_points(st, eb)
    if ca and cb and ca.get("regions"):
        cref = np.asarray(ca["reference_indirect"], np.float64)
        cerr = np.asarray(ca["reference_stderr"], np.float64)
        info["check_points"] = int(len(ca["points"]))
        for name, idx in ca["regions"].items():
            idx = np.asarray(idx.get("points", []) if isinstance(idx, dict) else idx, np.int64)
            yr = MT.luminance(cref[idx].reshape(-1, 3))
            mr = float(yr.mean()) if yr.size else 0.0
            if mr <= 0:
                continue
            rel = PM.reference_mean_stderr(cerr[idx]) / mr
            for m in (m for m in ca["modes"] if m in cb["modes"]):
                ya = MT.luminance(np.asarray(ca["modes"][m], np.float64)[idx].reshape(-1, 3)).mean()
                yb = MT.luminance(np.asarray(cb["modes"][m], np.float64)[idx].reshape(-1, 3)).mean()
                out[f"{m}.region.{name}.mean_ratio"] = abs(float(yb - ya)) / mr * rel
    info["paired"] = True
    info["reason"] = "both bakes were scored against the same cached reference: its noise is shared"
    return out, info


def _check_points(st: Store, ev: dict) -> dict | None:
    got = _artifact(st, ev["cache_key"], "check_points")
    return got[0] if got is not None and isinstance(got[0], dict) else None


def _summary(b: dict) -> dict:
    return {k: b.get(k) for k in ("id", "scene_id", "status", "created")}


@router.get("/compare", summary="Metric deltas of two bakes (both evaluated)", response_model=Comparison,
            responses=error_responses(401, {404: "no such bake for this team",
                                            409: "a bake has no evaluate metrics yet (no_metrics)",
                                            422: "a or b missing"}))
def compare(a: str = Query(..., description="the first bake's id"), b: str = Query(..., description="the second"),
            team_: str = Depends(team), cat: Catalog = Depends(catalog), st: Store = Depends(store)):
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
    try:
        se, paired = paired_stderr(st, bakes["a"], bakes["b"])
    except (OSError, ValueError, KeyError) as e:       # a stored artifact unreadable: the deltas still stand
        se, paired = {}, {"paired": False, "reason": f"the per-point values could not be read ({type(e).__name__})",
                          "points": 0, "check_points": 0}
    out = {}
    for name in common:
        x, y = ms["a"][name], ms["b"][name]
        out[name] = {"a": x, "b": y, "delta": y - x, "ratio": (y / x) if x != 0 else None,
                     "delta_stderr": se.get(name)}
    return FiniteJSONResponse({"a": _summary(bakes["a"]), "b": _summary(bakes["b"]), "metrics": out,
                               "paired": paired,
                               "only_a": sorted(set(ms["a"]) - set(ms["b"])),
                               "only_b": sorted(set(ms["b"]) - set(ms["a"]))})
