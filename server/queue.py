"""The queue client: enqueue a bake as a chain of RQ jobs (by name), cancel, and recover lost bakes.

Routes enqueue jobs by their import path (``workers.jobs.run_stage``) so the API process
never imports stage code. Job ids are ``<bake>-<attempt>-<stage>``: a bake re-enqueued by
recovery gets fresh ids, and its old jobs (if any survive) find the bake already moved on.
"""
from __future__ import annotations

import logging
import time

import redis
from rq import Queue, Retry
from rq.exceptions import NoSuchJobError
from rq.job import Job, JobStatus

from proto.catalog import Catalog
from proto.models import BakeConfig
from proto.stages import dependencies, expand, plan

log = logging.getLogger("kiln.queue")

QUEUE_NAME = "kiln"
RETRIES = 2
"""Extra attempts of a stage job after a crash (a killed worker, an unexpected exception)."""
LIVE = {JobStatus.QUEUED, JobStatus.STARTED, JobStatus.DEFERRED, JobStatus.SCHEDULED, JobStatus.READY_TO_ENQUEUE}


def connect(url: str) -> redis.Redis:
    return redis.Redis.from_url(url, socket_connect_timeout=5, socket_timeout=30, health_check_interval=10)


def job_id(bake_id: str, attempt: int, stage: str) -> str:
    """RQ job ids allow letters, digits, '_' and '-': shard names ``visibility.0`` become ``visibility_0``."""
    return f"{bake_id}-{attempt}-{stage.replace('.', '_')}"


def job_ids(bake: dict) -> list[str]:
    a = bake["attempt"]
    return [job_id(bake["id"], a, s["name"]) for s in bake["stages"]] + [job_id(bake["id"], a, "finish")]


def enqueue_bake(conn: redis.Redis, bake: dict) -> list[str]:
    """Enqueue the stages of ``bake`` that have not succeeded, then ``finish_bake``; returns job ids.

    Each job depends on the jobs of the stages it waits for (``proto.stages.dependencies``): the
    chain, with a sharded stage's shards side by side and its join after all of them.
    """
    q = Queue(QUEUE_NAME, connection=conn)
    config = BakeConfig.model_validate(bake["config"])
    stages = {st.name: st for st in expand(config)}
    deps = dependencies(list(stages.values()))
    a, jobs = bake["attempt"], {}
    for s in bake["stages"]:
        if s["status"] == "succeeded":
            continue
        st = stages[s["name"]]
        after = [jobs[d] for d in deps[st.name] if d in jobs]
        jobs[st.name] = q.enqueue(
            "workers.jobs.run_stage", bake["id"], st.name, job_id=job_id(bake["id"], a, st.name),
            depends_on=after or None, job_timeout=st.timeout, retry=Retry(max=RETRIES),
            result_ttl=3600, failure_ttl=7 * 86400, description=f"bake {bake['id']} stage {st.name}")
    job = q.enqueue("workers.jobs.finish_bake", bake["id"], job_id=job_id(bake["id"], a, "finish"),
                    depends_on=list(jobs.values()) or None, job_timeout=600, retry=Retry(max=RETRIES),
                    result_ttl=3600, failure_ttl=7 * 86400)
    return [j.id for j in jobs.values()] + [job.id]


def live_jobs(conn: redis.Redis, bake: dict) -> list[str]:
    out = []
    for jid in job_ids(bake):
        try:
            st = Job.fetch(jid, connection=conn).get_status()
        except NoSuchJobError:
            continue
        if st in LIVE:
            out.append(jid)
    return out


def cancel_jobs(conn: redis.Redis, bake: dict) -> None:
    """Cancel the bake's queued/deferred jobs; a running stage notices through its progress callback."""
    for jid in job_ids(bake):
        try:
            job = Job.fetch(jid, connection=conn)
            if job.get_status() in LIVE - {JobStatus.STARTED}:   # not yet running
                job.cancel()
        except NoSuchJobError:
            continue
        except Exception:  # cancelling is best effort: the catalog status is what counts
            log.exception("cancelling job %s", jid)


def queue_depth(conn: redis.Redis) -> int:
    return len(Queue(QUEUE_NAME, connection=conn))


def drain_ready(conn: redis.Redis) -> list[str]:
    """Enqueue the jobs whose dependencies are met but that RQ left in its ready registry; returns their ids.

    When a stage job finishes, RQ 3 moves its dependents to ``ReadyJobRegistry`` and then enqueues them,
    each under WATCH of that registry (one per queue) and the job. If another worker touches the registry
    at the same moment (two bakes' stages finishing together, or a sharded stage's shards), RQ concedes
    the job to ``ReadyJobRegistry.cleanup()``, which its workers run only once per maintenance interval
    (10 minutes). The API's recovery loop calls this every second, so a conceded stage waits at most
    about a second. Each job is enqueued at most once (RQ's own claim check).
    """
    jobs = Queue(QUEUE_NAME, connection=conn).ready_job_registry.cleanup()
    for j in jobs:
        log.info("enqueued job %s, left ready by RQ", j.id)
    return [j.id for j in jobs]


def recover(conn: redis.Redis, catalog: Catalog, grace_s: float = 10.0) -> list[str]:
    """Re-enqueue bakes left queued or running with no live job (lost Redis state, crashed workers).

    Bakes created less than ``grace_s`` ago are left alone (their jobs may be being enqueued).
    Returns the ids of the bakes re-enqueued.
    """
    out = []
    now = time.time()
    for bake in catalog.bakes_with_status(("queued", "running")):
        if now - bake["created"] < grace_s:
            continue
        bake = catalog.get_bake(bake["id"])
        if bake is None or live_jobs(conn, bake):
            continue
        bake["attempt"] = catalog.bump_attempt(bake["id"])
        for s in bake["stages"]:
            if s["status"] != "succeeded":
                catalog.update_stage(bake["id"], s["name"], status="pending", progress=0.0)
                s["status"] = "pending"
        enqueue_bake(conn, bake)
        log.warning("re-enqueued bake %s (attempt %d): it had no live job", bake["id"], bake["attempt"])
        out.append(bake["id"])
    return out


def plan_stages(scene_id: str, config: BakeConfig) -> list[tuple[str, str]]:
    return [(st.name, key) for st, key in plan(scene_id, config)]
