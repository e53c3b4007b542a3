"""A stage job that RQ moved to its ready registry but did not enqueue still runs (server.queue.drain_ready).

RQ 3 enqueues a finished job's dependents under WATCH of the queue's ready registry and concedes a job to the
registry's cleanup (every 10 minutes in its workers) when another worker touched the registry at the same
moment. Two bakes finishing stages together hit that race: a bake then sat "running" for minutes. Real
embedded Redis; the race is replayed by doing only the first half of RQ's ``enqueue_dependents``.
"""
from __future__ import annotations

import pytest
from rq import Queue
from rq.job import JobStatus

from server import queue as kq
from server.supervisor import EmbeddedRedis


@pytest.fixture
def conn(tmp_path):
    r = EmbeddedRedis(tmp_path / "data")
    r.start()
    try:
        c = kq.connect(r.url)
        yield c
        c.close()
    finally:
        r.stop()


def _conceded(conn):
    """Job B depends on A; A finishes and B is moved to ready, but (as when RQ concedes it) never enqueued."""
    q = Queue(kq.SHORT_QUEUE, connection=conn)
    a = q.enqueue("workers.jobs.finish_bake", "bake-a", job_id="a-0-place")
    b = q.enqueue("workers.jobs.finish_bake", "bake-a", job_id="a-0-relocate", depends_on=a)
    assert b.get_status() == JobStatus.DEFERRED
    assert q.pop_job_id() == a.id
    a.set_status(JobStatus.FINISHED)
    moved = q.move_dependents_to_ready(a)
    assert moved == {kq.SHORT_QUEUE: [b.id]}
    return q, b


def test_drain_enqueues_a_job_rq_left_ready(conn):
    q, b = _conceded(conn)
    assert b.get_status() == JobStatus.READY_TO_ENQUEUE
    assert b.id not in q.job_ids                      # the stall: nothing would run it for 10 minutes
    assert kq.drain_ready(conn) == [b.id]
    assert b.get_status() == JobStatus.QUEUED
    assert q.job_ids == [b.id]
    assert kq.drain_ready(conn) == []                 # enqueued once, not twice
    assert q.job_ids == [b.id]


def test_a_ready_job_counts_as_live_so_recovery_does_not_re_enqueue_the_bake(conn):
    _, b = _conceded(conn)
    assert b.get_status() in kq.LIVE


def test_cancelling_the_bake_cancels_a_ready_job_too(conn):
    q, b = _conceded(conn)
    kq.cancel_jobs(conn, {"id": "a", "attempt": 0, "stages": [{"name": "place"}, {"name": "relocate"}]})
    assert b.get_status() == JobStatus.CANCELED
    assert kq.drain_ready(conn) == [] and q.job_ids == []


def test_the_api_drains_the_ready_registry_on_its_own(service):
    """The app's recovery loop (no worker running here) enqueues a conceded job within a few seconds."""
    import time

    service.start_app()
    conn = kq.connect(service.redis.url)
    q, b = _conceded(conn)
    deadline = time.monotonic() + 10
    while b.get_status() != JobStatus.QUEUED:
        assert time.monotonic() < deadline, f"job still {b.get_status()} after 10 s"
        time.sleep(0.1)
    assert q.job_ids == [b.id]
