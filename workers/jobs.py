"""RQ job entry points — the only RQ-aware module of the workers.

A bake is a chain of jobs, one per stage (``depends_on`` the previous one), then
:func:`finish_bake`. Jobs take ids and plain JSON, load inputs from the store, call
:func:`workers.pipeline.execute_stage`, and record progress and outcome in the catalog.

Failure handling:

- a :class:`StageError` (bad input) is recorded on the bake as ``{stage, code, message}``
  and not retried;
- any other exception is retried by RQ (``Retry``); the last attempt records
  ``{stage, code: "internal", message}``;
- a work-horse killed mid-stage (SIGKILL, OOM) is retried by RQ's worker; artifacts are
  content-addressed and renamed into place, so the killed attempt leaves nothing visible.

The data directory comes from ``KILN_DATA`` (catalog ``kiln.db`` + ``store/``).
"""
from __future__ import annotations

import os
import time
import traceback
from functools import lru_cache
from pathlib import Path

from proto.catalog import TERMINAL, Catalog
from proto.models import BakeConfig
from proto.stages import finalize_bake
from proto.store import Store
from workers import pipeline
from workers.stages.base import Cancelled, StageError

QUEUE_NAME = "kiln"
PROGRESS_INTERVAL_S = 0.2
"""Seconds between progress writes to the catalog (and cancellation checks)."""


@lru_cache(maxsize=4)
def _env(data_dir: str) -> tuple[Catalog, Store]:
    root = Path(data_dir)
    return Catalog(root / "kiln.db"), Store(root / "store")


def data_env() -> tuple[Catalog, Store]:
    data = os.environ.get("KILN_DATA")
    if not data:
        raise RuntimeError("KILN_DATA is not set: the worker does not know its data directory")
    return _env(str(Path(data).resolve()))


def _current_job():
    from rq import get_current_job
    return get_current_job()


def _fault_delay() -> float:
    """Fault-injection hook for tests: seconds to pause inside every stage (``KILN_FAULT_STAGE_DELAY``)."""
    try:
        return float(os.environ.get("KILN_FAULT_STAGE_DELAY", "0"))
    except ValueError:
        return 0.0


def run_stage(bake_id: str, stage: str) -> dict:
    """RQ job: run one stage of a bake. Returns a small JSON summary."""
    catalog, store = data_env()
    bake = catalog.get_bake(bake_id)
    if bake is None or bake["status"] in TERMINAL:
        return {"skipped": True}
    catalog.set_bake_status(bake_id, "running", only_from=("queued", "running"))
    config = BakeConfig.model_validate(bake["config"])
    now = time.time()
    catalog.update_stage(bake_id, stage, status="running", progress=0.0, pid=os.getpid(), started=now)

    last = [0.0]

    def report(fraction: float) -> None:
        t = time.monotonic()
        if t - last[0] < PROGRESS_INTERVAL_S and fraction < 1.0:
            return
        last[0] = t
        b = catalog.get_bake(bake_id)
        if b is None or b["status"] == "cancelled":
            raise Cancelled()
        catalog.update_stage(bake_id, stage, progress=max(0.0, min(1.0, float(fraction))))

    try:
        delay = _fault_delay()
        if delay > 0:
            report(0.01)
            time.sleep(delay)
        rec, cached = pipeline.execute_stage(store, bake["scene_id"], config, stage, report)
    except Cancelled:
        catalog.update_stage(bake_id, stage, status="cancelled", finished=time.time())
        return {"cancelled": True}
    except StageError as e:
        _fail(catalog, bake_id, stage, e.code, e.message)
        job = _current_job()
        if job is not None:
            job.retries_left = 0  # a deterministic input error: retrying cannot help
        raise
    except Exception as e:
        job = _current_job()
        if job is not None and job.retries_left:
            catalog.update_stage(bake_id, stage, status="retrying")
        else:
            _fail(catalog, bake_id, stage, "internal", f"{type(e).__name__}: {e}")
        traceback.print_exc()
        raise
    catalog.update_stage(bake_id, stage, status="succeeded", progress=1.0, seconds=rec["seconds"],
                         cached=cached, stats=rec["stats"], finished=time.time())
    return {"stage": stage, "cached": cached, "cache_key": rec["cache_key"]}


def _fail(catalog: Catalog, bake_id: str, stage: str, code: str, message: str) -> None:
    catalog.update_stage(bake_id, stage, status="failed", finished=time.time())
    catalog.set_bake_status(bake_id, "failed", error={"stage": stage, "code": code, "message": message})


def finish_bake(bake_id: str) -> dict:
    """RQ job: after the last stage, write the manifest onto the bake and mark it succeeded."""
    catalog, store = data_env()
    bake = catalog.get_bake(bake_id)
    if bake is None or bake["status"] in TERMINAL:
        return {"skipped": True}
    if any(s["status"] != "succeeded" for s in bake["stages"]):
        # A stage did not finish (cancelled or lost): leave the bake to recovery.
        return {"incomplete": True}
    finalize_bake(catalog, store, bake)
    return {"succeeded": True}


def ingest_upload(path: str, filename: str | None, store_root: str, limits: dict) -> dict:
    """Parse an uploaded file into a normalized scene and store it (runs in a child process of the API).

    Returns ``{"scene_id", "summary"}`` or ``{"error": {"status", "code", "message"}}``; never raises
    for bad input. Run out of process so a huge or hostile upload cannot grow the API's memory.
    """
    from workers.ingest import IngestError, IngestLimits, ingest_file

    try:
        scene = ingest_file(path, IngestLimits(**limits), filename=filename)
    except IngestError as e:
        return {"error": {"status": e.status, "code": e.code, "message": e.message}}
    data = scene.to_bytes()
    scene_id = Store(store_root).put_bytes(data)
    return {"scene_id": scene_id, "summary": scene.summary(scene_id)}
