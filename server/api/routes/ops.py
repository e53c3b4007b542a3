"""``/healthz``, ``/metrics`` (Prometheus text format) and ``/v1/config/schema``."""
from __future__ import annotations

from typing import Any

import redis
from fastapi import APIRouter, Depends, Request, Response
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily, SummaryMetricFamily

from persist.catalog import Catalog
from proto.models import BakeConfig
from server import queue
from server.api import deps
from server.api.jsonbody import FiniteJSONRoute
from server.api.schemas import Health, error_responses
from server.config import Settings

router = APIRouter(tags=["ops"], route_class=FiniteJSONRoute)


@router.get("/healthz", summary="Liveness and dependencies", response_model=Health)
def healthz(settings: Settings = Depends(deps.settings), catalog: Catalog = Depends(deps.catalog),
            conn: redis.Redis = Depends(deps.redis_conn)):
    redis_ok = True
    try:
        conn.ping()
    except Exception:
        redis_ok = False
    try:
        catalog.count_bakes_by_status()
        catalog_ok = True
    except Exception:
        catalog_ok = False
    ok = redis_ok and catalog_ok
    return {"status": "ok" if ok else "degraded", "redis": redis_ok, "catalog": catalog_ok,
            "auth": "open" if settings.open else "api-keys"}


class _Collector:
    """``team``: with API keys, the caller's team — its own bakes and stage times only; the queue depths are
    aggregates over every team (they name no bake). Open (no keys): everything, as team ``default``."""

    def __init__(self, app, team: str | None = None):
        self.app, self.team = app, team

    def collect(self):
        st = self.app.state
        depth = GaugeMetricFamily("kiln_queue_depth", "jobs waiting in the bake queues (all teams)")
        by_queue = GaugeMetricFamily("kiln_queue_jobs", "jobs waiting per queue (all teams)", labels=["queue"])
        try:
            depths = queue.queue_depths(st.redis)
            depth.add_metric([], sum(depths.values()))
            for name, n in depths.items():
                by_queue.add_metric([name], n)
        except Exception:
            depth.add_metric([], float("nan"))
        yield depth
        yield by_queue
        bakes = GaugeMetricFamily("kiln_bakes", "the team's bakes in the catalog by status", labels=["status"])
        for status, n in st.catalog.count_bakes_by_status(self.team).items():
            bakes.add_metric([status], n)
        yield bakes
        dur = SummaryMetricFamily("kiln_stage_duration_seconds", "wall time of the team's stages that ran "
                                  "(not cached)", labels=["stage"])
        agg: dict[str, list[float]] = {}
        for stage, sec in st.catalog.stage_durations(self.team):
            agg.setdefault(stage, []).append(sec)
        for stage, secs in sorted(agg.items()):
            dur.add_metric([stage], count_value=len(secs), sum_value=sum(secs))
        yield dur


@router.get("/metrics", summary="Prometheus metrics (with API keys: needs one, and shows that team's bakes)",
            response_class=Response,
            responses={200: {"description": "Prometheus text format 0.0.4",
                             "content": {"text/plain; version=0.0.4; charset=utf-8": {"schema": {"type": "string"}}}},
                       **error_responses(401)})
def metrics(request: Request, team: str = Depends(deps.team), settings: Settings = Depends(deps.settings)):
    reg = CollectorRegistry()
    reg.register(_Collector(request.app, None if settings.open else team))
    return Response(generate_latest(reg), media_type="text/plain; version=0.0.4; charset=utf-8")


@router.get("/v1/config/schema", summary="JSON Schema of the bake config (no API key needed)",
            response_model=dict[str, Any])
def config_schema():
    return BakeConfig.model_json_schema()
