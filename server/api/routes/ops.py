"""``/healthz``, ``/metrics`` (Prometheus text format) and ``/v1/config/schema``."""
from __future__ import annotations

from fastapi import APIRouter, Request, Response
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily, SummaryMetricFamily

from proto.models import BakeConfig
from server import queue

router = APIRouter(tags=["ops"])


@router.get("/healthz", summary="Liveness and dependencies")
def healthz(request: Request):
    st = request.app.state
    redis_ok = True
    try:
        st.redis.ping()
    except Exception:
        redis_ok = False
    try:
        st.catalog.count_bakes_by_status()
        catalog_ok = True
    except Exception:
        catalog_ok = False
    ok = redis_ok and catalog_ok
    return {"status": "ok" if ok else "degraded", "redis": redis_ok, "catalog": catalog_ok,
            "auth": "open" if st.settings.open else "api-keys"}


class _Collector:
    def __init__(self, app):
        self.app = app

    def collect(self):
        st = self.app.state
        depth = GaugeMetricFamily("kiln_queue_depth", "jobs waiting in the bake queue")
        try:
            depth.add_metric([], queue.queue_depth(st.redis))
        except Exception:
            depth.add_metric([], float("nan"))
        yield depth
        bakes = GaugeMetricFamily("kiln_bakes", "bakes in the catalog by status", labels=["status"])
        for status, n in st.catalog.count_bakes_by_status().items():
            bakes.add_metric([status], n)
        yield bakes
        dur = SummaryMetricFamily("kiln_stage_duration_seconds", "wall time of stages that ran (not cached)",
                                  labels=["stage"])
        agg: dict[str, list[float]] = {}
        for stage, sec in st.catalog.stage_durations():
            agg.setdefault(stage, []).append(sec)
        for stage, secs in sorted(agg.items()):
            dur.add_metric([stage], count_value=len(secs), sum_value=sum(secs))
        yield dur


@router.get("/metrics", summary="Prometheus metrics")
def metrics(request: Request):
    reg = CollectorRegistry()
    reg.register(_Collector(request.app))
    return Response(generate_latest(reg), media_type="text/plain; version=0.0.4; charset=utf-8")


@router.get("/v1/config/schema", summary="JSON Schema of the bake config")
def config_schema():
    return BakeConfig.model_json_schema()
