"""Stages run as a DAG, not a chain: in the CLI's in-process bake (``workers.pipeline.bake_local``) and in the
service's jobs (``proto.stages.dependencies`` → ``server.queue.enqueue_bake``'s ``depends_on``).

The concurrency checks do not time anything: two stages that must overlap meet at a barrier, which breaks
(failing the bake) when one runs only after the other has finished.
"""
from __future__ import annotations

import threading

import pytest

from persist.store import Store
from proto.models import BakeConfig
from proto.stages import STAGE_BY_NAME, dependencies, expand
from workers import pipeline
from workers.gltf import ingest_file
from workers.stages.base import StageError

SMALL = {"place": {"counts": [3, 2, 2]}, "trace": {"rays_per_probe": 32, "relocate_iterations": 1},
         "light": {"bounces": 1}, "visibility": {"samples_per_cell": 2, "slabs": 2},
         "masks": {"clusters": 2, "sweeps": 20},
         "evaluate": {"enabled": True, "cameras": 1, "surface_points": 64, "spp": 2, "previews": 0}}


def test_dependencies_are_the_stages_inputs():
    config = BakeConfig.model_validate(SMALL)
    stages = expand(config)
    deps = dependencies(stages)
    order = [s.name for s in stages]
    assert set(deps) == set(order)
    for name, ds in deps.items():
        assert all(order.index(d) < order.index(name) for d in ds), name      # run order is a topological order
    assert deps["ingest"] == []
    assert deps["reference"] == ["ingest"]                                   # beside every probe stage
    assert deps["visibility.0"] == deps["visibility.1"] == ["place", "relocate", "trace"]   # beside light
    assert deps["visibility"] == ["place", "relocate", "trace", "visibility.0", "visibility.1"]
    assert "light" not in deps["anneal"] and "light" in deps["clusters"]
    # the masks and their compression read no light unless the masks are fitted to it (eq 9)
    assert "light" not in deps["masks"] and deps["compress"] == ["place", "masks"]
    aware = dependencies(expand(BakeConfig.model_validate({**SMALL, "masks": {**SMALL["masks"], "light_aware": True}})))
    assert "light" in aware["masks"]
    assert set(deps["evaluate"]) == set(STAGE_BY_NAME["evaluate"].inputs)
    # the light stage's chain is still there: each probe stage waits for the one it reads
    assert deps["light"] == ["ingest", "place", "relocate", "trace"]


def test_enqueued_jobs_wait_only_for_their_inputs(tmp_path):
    from rq.job import Job

    from server import queue as kq
    from server.supervisor import EmbeddedRedis

    r = EmbeddedRedis(tmp_path / "redis")
    r.start()
    try:
        conn = kq.connect(r.url)
        config = BakeConfig.model_validate(SMALL)
        names = [s.name for s in expand(config)]
        bake = {"id": "dagtest", "attempt": 0, "config": config.model_dump(mode="json"),
                "stages": [{"name": n, "status": "pending"} for n in names]}
        ids = kq.enqueue_bake(conn, bake)
        jid = lambda n: kq.job_id("dagtest", 0, n)                      # noqa: E731
        waits = {n: sorted(Job.fetch(jid(n), connection=conn).dependency_ids) for n in names}
        waits = {n: [d.decode() if isinstance(d, bytes) else d for d in ds] for n, ds in waits.items()}
        assert waits["ingest"] == []
        assert waits["reference"] == [jid("ingest")]
        assert waits["visibility.0"] == sorted(jid(d) for d in ("place", "relocate", "trace"))
        assert jid("light") not in waits["anneal"] and jid("light") in waits["clusters"]
        assert jid("light") not in waits["masks"] and jid("light") not in waits["compress"]
        assert len(Job.fetch(ids[-1], connection=conn).dependency_ids) == len(names)   # finish waits for all
        conn.close()
    finally:
        r.stop()


@pytest.fixture(scope="module")
def two_rooms(scene_files):
    return ingest_file(scene_files["two-rooms"])


def test_concurrent_bake_equals_the_sequential_one_and_overlaps(tmp_path, two_rooms, monkeypatch):
    config = BakeConfig.model_validate(SMALL)
    seq = pipeline.bake_local(Store(tmp_path / "a"), two_rooms, config, concurrency=1)

    # place and reference become ready together (both read only ingest): with two at a time they must overlap
    barrier = threading.Barrier(2, timeout=120)
    real = pipeline.execute_stage

    def meeting(store, scene_id, cfg, stage, *args, **kw):
        if stage in ("place", "reference"):
            barrier.wait()                      # BrokenBarrierError (the bake fails) if the other never comes
        return real(store, scene_id, cfg, stage, *args, **kw)

    monkeypatch.setattr(pipeline, "execute_stage", meeting)
    events = []
    par = pipeline.bake_local(Store(tmp_path / "b"), two_rooms, config, concurrency=2,
                              report=lambda s, f: events.append((s, f)))
    art = lambda m: {a.name: a.sha256 for a in m.artifacts}     # noqa: E731
    assert art(par) == art(seq) and len(art(seq)) > 20
    assert [s.name for s in par.stages] == [s.name for s in seq.stages]     # the manifest keeps run order
    assert par.grid == seq.grid
    first = lambda name, f: events.index((name, f))      # noqa: E731  (stages may report 1.0 more than once)
    assert {s for s, f in events if f == 0.0} == {s for s, f in events if f == 1.0} == {s.name for s in seq.stages}
    for st in expand(config):                    # nothing starts before the stages it reads have ended
        for dep in st.inputs:
            assert first(dep, 1.0) < first(st.name, 0.0), (st.name, dep)


def test_a_stage_runs_with_one_blas_thread(tmp_path, two_rooms, monkeypatch):
    """OpenBLAS's threads spin beside the other stage (workers/pipeline.py BLAS_THREADS): the first stage a process
    runs sets every loaded OpenBLAS to one thread."""
    from threadpoolctl import threadpool_info, threadpool_limits

    monkeypatch.setattr(pipeline, "_blas_limited", False)
    with threadpool_limits(limits=2, user_api="blas"):
        assert {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == {2}
        store = Store(tmp_path / "s")
        sid = store.put_bytes(two_rooms.to_bytes())
        pipeline.execute_stage(store, sid, BakeConfig.model_validate(SMALL), "ingest")
        blas = [i for i in threadpool_info() if i["user_api"] == "blas"]
        assert blas and {i["num_threads"] for i in blas} == {pipeline.BLAS_THREADS} == {1}


def test_a_failing_stage_stops_what_reads_it(tmp_path, two_rooms, monkeypatch):
    config = BakeConfig.model_validate(SMALL)
    real = pipeline.execute_stage
    ran = []

    def failing(store, scene_id, cfg, stage, *args, **kw):
        ran.append(stage)
        if stage == "trace":
            raise StageError("bad_trace", "trace failed on purpose")
        return real(store, scene_id, cfg, stage, *args, **kw)

    monkeypatch.setattr(pipeline, "execute_stage", failing)
    with pytest.raises(StageError, match="on purpose"):
        pipeline.bake_local(Store(tmp_path / "s"), two_rooms, config, concurrency=2)
    assert "trace" in ran
    assert not {"light", "visibility.0", "visibility.1", "anneal", "masks", "clusters", "evaluate"} & set(ran)


INTERRUPT_SCRIPT = r"""
import os, signal, sys, threading
from persist.store import Store
from proto.models import BakeConfig
from workers import pipeline
from workers.gltf import ingest_file

signal.signal(signal.SIGINT, signal.default_int_handler)   # as in a terminal, even where the test runs with it ignored
release = threading.Event()
real = pipeline.execute_stage

def stuck(store, scene_id, cfg, stage, *args, **kw):
    if stage == "light":                       # Ctrl+C while a long stage runs, which then never ends by itself
        os.kill(os.getpid(), signal.SIGINT)
        release.wait(600)
        return None, False
    return real(store, scene_id, cfg, stage, *args, **kw)

pipeline.execute_stage = stuck
try:
    pipeline.bake_local(Store(sys.argv[1]), ingest_file(sys.argv[2]), BakeConfig.model_validate_json(sys.argv[3]))
    print("finished")
except KeyboardInterrupt:
    alive = [t.name for t in threading.enumerate() if t.name.startswith("kiln-stage-")]
    print("interrupted while running:", ",".join(alive))
"""


def test_ctrl_c_returns_without_waiting_for_the_running_stages(tmp_path, scene_files):
    """An interrupt in the waiting thread ends the bake at once; the stage still running is abandoned (it would
    block for 10 minutes here), not waited for."""
    import json
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    r = subprocess.run([sys.executable, "-c", INTERRUPT_SCRIPT, str(tmp_path / "s"), str(scene_files["two-rooms"]),
                        json.dumps(SMALL)], capture_output=True, text=True, cwd=root, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "interrupted while running:" in r.stdout and "kiln-stage-light" in r.stdout, r.stdout + r.stderr
