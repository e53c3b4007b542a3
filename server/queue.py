"""The queue client: enqueue a bake as RQ jobs (by name), each waiting for the stages it reads; cancel; recover.

Routes enqueue jobs by their import path (``workers.jobs.run_stage``) so the API process
never imports stage code. Job ids are ``<bake>-<attempt>-<stage>``: a bake re-enqueued by
recovery gets fresh ids, and its old jobs (if any survive) find the bake already moved on.

Two queues: :data:`LONG_QUEUE` (``kiln-long``) takes the stages the cost model (:mod:`proto.cost`) expects
to run long — prt, and any stage estimated over ``proto.cost.LONG_STAGE_SECONDS`` (a large evaluate, light or
visibility) — and
:data:`SHORT_QUEUE` (``kiln-short``) the rest. Workers listen to both, short first, and ``kiln serve``
dedicates one worker to the short queue, so one heavy bake cannot hold every worker. Each stage's job
timeout follows its estimate (:func:`proto.cost.stage_timeout`), not a flat hour.
"""
from __future__ import annotations

import logging
import time

import redis
from rq import Queue, Retry
from rq.command import send_stop_job_command
from rq.exceptions import InvalidJobOperation, NoSuchJobError
from rq.job import Job, JobStatus

from persist.catalog import Catalog
from proto import cost
from proto.models import BakeConfig
from proto.stages import dependencies, expand, plan

log = logging.getLogger("kiln.queue")

SHORT_QUEUE = "kiln-short"
LONG_QUEUE = "kiln-long"
QUEUES = (SHORT_QUEUE, LONG_QUEUE)
"""In the order workers listen to them: short first."""
LEGACY_QUEUE = "kiln"
"""The single queue of earlier versions: workers still drain it, nothing new goes there."""
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


def stage_queue(stage: cost.StageCost | None) -> str:
    """The queue a stage's job goes to: long when the cost model says so (prt, big stages)."""
    return LONG_QUEUE if stage is not None and stage.long else SHORT_QUEUE


def enqueue_bake(conn: redis.Redis, bake: dict, scene: dict | None = None,
                 memory_limit_bytes: int | None = None) -> list[str]:
    """Enqueue the stages of ``bake`` that have not succeeded, then ``finish_bake``; returns job ids.

    Each job depends on the jobs of the stages it reads (``proto.stages.dependencies``): a DAG, so the
    reference, a sharded stage's shards and anneal run beside the light stage, and a join waits for all its
    shards. ``scene`` (the
    catalog's scene summary) feeds the cost model that picks each stage's queue and timeout; without it
    the stage table's timeouts apply and every stage but prt/evaluate goes to the short queue.
    ``memory_limit_bytes`` goes into each stage job's meta: the work-horse's memory limit
    (``workers.jobs``).
    """
    queues = {name: Queue(name, connection=conn) for name in QUEUES}
    config = BakeConfig.model_validate(bake["config"])
    stages = {st.name: st for st in expand(config)}
    deps = dependencies(list(stages.values()))
    est = cost.estimate(scene, config) if scene is not None else None
    meta = {"memory_limit_bytes": int(memory_limit_bytes)} if memory_limit_bytes else {}
    a, jobs = bake["attempt"], {}
    for s in bake["stages"]:
        if s["status"] == "succeeded":
            continue
        st = stages[s["name"]]
        after = [jobs[d] for d in deps[st.name] if d in jobs]
        sc = est.stage(st.name) if est is not None else None
        if sc is not None:
            timeout = cost.stage_timeout(sc)
            qname = stage_queue(sc)
        else:
            timeout = st.timeout
            qname = LONG_QUEUE if st.name in ("prt", "evaluate") else SHORT_QUEUE
        jobs[st.name] = queues[qname].enqueue(
            "workers.jobs.run_stage", bake["id"], st.name, job_id=job_id(bake["id"], a, st.name),
            depends_on=after or None, job_timeout=timeout, retry=Retry(max=RETRIES), meta=dict(meta),
            result_ttl=3600, failure_ttl=7 * 86400, description=f"bake {bake['id']} stage {st.name}")
    job = queues[SHORT_QUEUE].enqueue(
        "workers.jobs.finish_bake", bake["id"], job_id=job_id(bake["id"], a, "finish"),
        depends_on=list(jobs.values()) or None, job_timeout=600, retry=Retry(max=RETRIES),
        result_ttl=3600, failure_ttl=7 * 86400)
    return [j.id for j in jobs.values()] + [job.id]


STALL_S = 30.0
"""Seconds of no progress after which a bake whose jobs can no longer run counts as lost (see :func:`live_jobs`)."""
GHOST_HEARTBEAT_S = 150.0
"""A started job whose worker has not heartbeaten it for this long has no worker (RQ heartbeats every 30 s)."""
RUNNABLE = {JobStatus.QUEUED, JobStatus.SCHEDULED, JobStatus.READY_TO_ENQUEUE}


def _ghost(job: Job, stage: dict | None, now: float) -> bool:
    """A STARTED job that nothing runs any more: the catalog says its stage ended (succeeded, failed or
    cancelled) more than :data:`STALL_S` ago — its worker died before it could tell Redis — or no worker has
    heartbeaten it for :data:`GHOST_HEARTBEAT_S`."""
    if stage is not None and stage["status"] in ("succeeded", "failed", "cancelled") and stage.get("finished") \
            and now - stage["finished"] > STALL_S:
        return True
    beat = getattr(job, "last_heartbeat", None) or getattr(job, "started_at", None)
    return beat is not None and now - beat.timestamp() > GHOST_HEARTBEAT_S


def _in_queue(conn: redis.Redis, job: Job) -> bool:
    q = Queue(job.origin, connection=conn)
    return any(conn.lpos(key, job.id) is not None for key in (q.key, q.intermediate_queue_key))


def live_jobs(conn: redis.Redis, bake: dict) -> list[str]:
    """The bake's jobs that will still run.

    Redis restarted between a job's end and the enqueue of its dependents (its append-only file keeps up to the
    last second), or a worker died with Redis: then a bake can hold only DEFERRED jobs waiting for jobs that
    ended (or STARTED ghosts, :func:`_ghost`; or QUEUED ones that a dead worker had popped from their queue),
    which nothing will ever run. Such a bake has no live job once nothing of it moved for :data:`STALL_S`, so
    :func:`recover` re-enqueues it (bench_load.py lost 1-2 bakes of 12 this way before).
    """
    stages = {s["name"].replace(".", "_"): s for s in bake.get("stages", [])}
    prefix = f"{bake['id']}-{bake['attempt']}-"
    now = time.time()
    runnable, deferred = [], []
    for jid in job_ids(bake):
        try:
            job = Job.fetch(jid, connection=conn)
            st = job.get_status()
        except NoSuchJobError:
            continue
        if st == JobStatus.QUEUED and not _in_queue(conn, job):
            # queued in its hash but in no queue list: a worker popped it and died with Redis before it started
            log.warning("job %s is queued but in no queue (popped by a worker that died)", jid)
            deferred.append(jid)          # counts as waiting: lost once nothing moved for STALL_S
        elif st in RUNNABLE:
            runnable.append(jid)
        elif st == JobStatus.STARTED:
            if _ghost(job, stages.get(jid.removeprefix(prefix)), now):
                log.warning("job %s is started but nothing runs it (its worker is gone)", jid)
            else:
                runnable.append(jid)
        elif st == JobStatus.DEFERRED:
            deferred.append(jid)
    if runnable or not deferred:
        return runnable + deferred
    moved = [t for s in bake.get("stages", []) for t in (s.get("started"), s.get("finished")) if t]
    last = max(moved, default=bake.get("created") or 0.0)
    if now - last > STALL_S:
        log.warning("bake %s is stalled: %d deferred jobs wait for jobs that ended", bake["id"], len(deferred))
        return []
    return deferred


def cancel_jobs(conn: redis.Redis, bake: dict) -> list[str]:
    """Cancel the bake's queued/deferred jobs and stop its running ones; returns the ids of those stopped.

    A running stage is stopped by its worker (RQ's ``stop-job`` command over Redis pub/sub): the worker
    kills the work-horse at once, whether or not the stage reports progress, and RQ marks the job
    ``stopped``, which is never retried. (A stage that does report progress also notices the cancelled
    bake itself and unwinds.)
    """
    stopped = []
    for jid in job_ids(bake):
        try:
            job = Job.fetch(jid, connection=conn)
            status = job.get_status()
            if status == JobStatus.STARTED:
                try:
                    send_stop_job_command(conn, jid)
                    stopped.append(jid)
                except InvalidJobOperation:   # between dequeue and start: no worker name yet
                    job.cancel()
            elif status in LIVE:   # not yet running
                job.cancel()
        except NoSuchJobError:
            continue
        except Exception:  # cancelling is best effort: the catalog status is what counts
            log.exception("cancelling job %s", jid)
    return stopped


def queue_depths(conn: redis.Redis) -> dict[str, int]:
    return {name: len(Queue(name, connection=conn)) for name in QUEUES}


def queue_depth(conn: redis.Redis) -> int:
    return sum(queue_depths(conn).values())


def drain_ready(conn: redis.Redis) -> list[str]:
    """Enqueue the jobs whose dependencies are met but that RQ left in its ready registry; returns their ids.

    When a stage job finishes, RQ 3 moves its dependents to ``ReadyJobRegistry`` and then enqueues them,
    each under WATCH of that registry (one per queue) and the job. If another worker touches the registry
    at the same moment (two bakes' stages finishing together, or a sharded stage's shards), RQ concedes
    the job to ``ReadyJobRegistry.cleanup()``, which its workers run only once per maintenance interval
    (10 minutes). The API's recovery loop calls this every second, so a conceded stage waits at most
    about a second. Each job is enqueued at most once (RQ's own claim check).
    """
    jobs = []
    for name in QUEUES:
        jobs += Queue(name, connection=conn).ready_job_registry.cleanup()
    for j in jobs:
        log.info("enqueued job %s, left ready by RQ", j.id)
    return [j.id for j in jobs]


def recover(conn: redis.Redis, catalog: Catalog, grace_s: float = 10.0,
            memory_limit_bytes: int | None = None) -> list[str]:
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
        for jid in job_ids(bake):       # the old attempt's stalled jobs must not run later beside the new ones
            try:
                job = Job.fetch(jid, connection=conn)
                if job.get_status() in LIVE - {JobStatus.STARTED}:
                    job.cancel()
            except Exception:
                pass
        bake["attempt"] = catalog.bump_attempt(bake["id"])
        for s in bake["stages"]:
            if s["status"] != "succeeded":
                catalog.update_stage(bake["id"], s["name"], status="pending", progress=0.0)
                s["status"] = "pending"
        scene = catalog.get_scene(bake["team"], bake["scene_id"])
        enqueue_bake(conn, bake, scene, memory_limit_bytes)
        log.warning("re-enqueued bake %s (attempt %d): it had no live job", bake["id"], bake["attempt"])
        out.append(bake["id"])
    return out


def plan_stages(scene_id: str, config: BakeConfig, namespace: str | None = None) -> list[tuple[str, str]]:
    return [(st.name, key) for st, key in plan(scene_id, config, namespace)]
