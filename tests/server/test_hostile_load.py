"""Hostile load through the real service (issue 15, the resource half): embedded Redis, real RQ workers, the app
(in-process, or a real ``kiln serve`` where the test needs real sockets: a 200 MB body, a client that goes away).

- cost model and budget: ``?dry_run=true`` estimates without starting anything; over the budget is a 422
  ``over_budget`` with the estimate and the limits; a stage over the workers' memory limit fails
  ``out_of_memory`` and is not retried (the RSS watchdog and the RLIMIT_AS MemoryError paths);
- bodies bounded before auth: a 200 MB body without a key is answered 401 before it is read, and the API's RSS
  does not grow; JSON bodies over the cap are 413 (with and without Content-Length);
- ingest cannot be starved: a parse is killed when its client disconnects and at ``KILN_INGEST_TIMEOUT_S``; a
  team's concurrent uploads are limited (429 + Retry-After); waiting uploads are served round-robin by team;
- quotas per team: scenes, stored bytes, concurrent bakes (429 + Retry-After); the expanded size of an upload;
- cancel kills a running stage that reports no progress (its work-horse is gone, the job is not retried); stage
  timeouts follow the estimate; long stages go to ``kiln-long``, so one heavy bake cannot hold every worker;
- tenancy: ``/metrics`` needs a key and shows the caller's team only; the stage cache is per team; a key given to
  two teams refuses to start.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import httpx
import numpy as np
import psutil
import pytest
from rq import Queue
from rq.job import Job, JobStatus

from proto import cost
from persist.catalog import Catalog
from proto.models import BakeConfig
from server import queue as kq

ROOT = Path(__file__).resolve().parents[2]
KEYS = "red:red-key-123,blue:blue-key-456"
RED = {"Authorization": "Bearer red-key-123"}
BLUE = {"Authorization": "Bearer blue-key-456"}
TINY = {"place": {"counts": [3, 3, 3]}, "trace": {"rays_per_probe": 32},
        "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 10}, "evaluate": {"enabled": False}}
TINY_PRT = {**TINY, "prt": {"enabled": True, "configurations": 8, "measurement_points": 16, "basis": 4,
                            "lightmap": 0}}


@contextmanager
def app(service, **settings):
    """The app on ``service``'s Redis and data with extra settings (a TestClient: real routes, real queue)."""
    from fastapi.testclient import TestClient

    from server.config import Settings
    from server.main import create_app

    s = Settings(data=service.data, redis_url=service.redis.url, recover_interval_s=0.5, **settings)
    with TestClient(create_app(s)) as c:
        service.client = c
        try:
            yield c
        finally:
            service.client = None


def _stage_pid(data: Path, bake_id: str, stage: str, timeout: float = 60.0) -> int:
    cat = Catalog(data / "kiln.db")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for s in cat.get_bake(bake_id)["stages"]:
            if s["name"] == stage and s["status"] == "running" and s["pid"]:
                return s["pid"]
        time.sleep(0.05)
    raise AssertionError(f"stage {stage} of {bake_id} never ran: {cat.get_bake(bake_id)}")


def _gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def _attempts(conn, job_id: str) -> int:
    """How many times RQ ran a job (one result per execution, failed ones included)."""
    return len(Job.fetch(job_id, connection=conn).results())


# --------------------------------------------------------------------------------------------- cost and budget


def test_dry_run_estimates_without_starting_anything(service, scene_files):
    service.start_workers(1)
    with app(service) as c:
        sid = service.upload(scene_files["two-rooms"]).json()["id"]
        r = c.post("/v1/bakes?dry_run=true", json={"scene_id": sid, "config": TINY})
        assert r.status_code == 200, r.text
        est = r.json()["estimate"]
        assert {"probes", "seconds", "peak_memory_bytes", "artifact_bytes"} <= set(est)
        assert est["probes"] == 27 and est["seconds"] > 0 and est["peak_memory_bytes"] > 50 * 2**20
        assert r.json()["over_budget"] == [] and r.json()["limits"]["peak_memory_bytes"] == 8192 * 2**20
        # the automatic grid: its upper bound, place.budget probes
        auto = c.post("/v1/bakes?dry_run=true", json={"scene_id": sid, "config": {"place": {"budget": 500}}}).json()
        assert auto["estimate"]["probes"] >= 500 and auto["estimate"]["probes_exact"] is False
        # nothing recorded, nothing queued
        assert c.get("/v1/bakes").json()["total"] == 0
        assert kq.queue_depth(c.app.state.redis) == 0
        # the same model the queue uses: the estimate here is the one proto.cost gives
        scene = c.get(f"/v1/scenes/{sid}").json()
        assert est["peak_memory_bytes"] == cost.estimate(scene, BakeConfig.model_validate(TINY)).peak_memory_bytes
        assert c.post("/v1/bakes?dry_run=true", json={"scene_id": "0" * 64}).status_code == 404


def test_over_budget_is_422_with_the_estimate_and_the_limit(service, scene_files):
    with app(service, max_bake_memory_mb=2048, max_bake_seconds=600) as c:
        sid = service.upload(scene_files["cornell"]).json()["id"]
        huge = {"place": {"counts": [64, 64, 64]}, "trace": {"rays_per_probe": 1024}}
        r = c.post("/v1/bakes", json={"scene_id": sid, "config": huge})
        assert r.status_code == 422, r.text
        err = r.json()["error"]
        assert err["code"] == "over_budget" and "peak_memory_bytes" in err["message"]
        assert err["estimate"]["probes"] == 64**3
        assert err["limits"] == {"peak_memory_bytes": 2048 * 2**20, "seconds": 600.0,
                                 "artifact_bytes": 20480 * 2**20}
        over = {o["resource"]: o for o in err["over_budget"]}
        assert over["peak_memory_bytes"]["estimate"] > over["peak_memory_bytes"]["limit"]
        assert "seconds" in over
        assert c.get("/v1/bakes").json()["total"] == 0
        # within the budget: accepted
        assert c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}).status_code == 202


@pytest.mark.parametrize("alloc_mb, path", [(900, "watchdog"), (6000, "rlimit")])
def test_a_stage_over_the_memory_limit_fails_out_of_memory_once(service, scene_files, alloc_mb, path):
    """The workers' limit is 400 MB a stage: 900 MB touched a block at a time passes RSS (the watchdog kills the
    horse), 6000 MB at once passes the address-space limit (numpy raises MemoryError). Either way the bake fails
    ``out_of_memory``, not ``internal``, and the job ran once."""
    service.start_workers(1, env={"KILN_MAX_BAKE_MEMORY_MB": "400", "KILN_FAULT_STAGE_ALLOC_MB": str(alloc_mb),
                                  "KILN_FAULT_STAGE_ALLOC_BLOCK_MB": "16" if path == "watchdog" else str(alloc_mb)})
    with app(service) as c:
        sid = service.upload(scene_files["cornell"]).json()["id"]
        bid = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}).json()["id"]
        b = service.wait_bake(bid, timeout=90)
        assert b["status"] == "failed", b
        assert b["error"]["code"] == "out_of_memory" and b["error"]["stage"] == "ingest", b["error"]
        assert "400 MB" in b["error"]["message"]
        time.sleep(2)   # a retry, if there were one, would have started by now
        conn = c.app.state.redis
        jid = kq.job_id(bid, 0, "ingest")
        assert Job.fetch(jid, connection=conn).get_status() in (JobStatus.FAILED, JobStatus.STOPPED)
        assert _attempts(conn, jid) <= 1
        assert c.get(f"/v1/bakes/{bid}").json()["status"] == "failed"


# --------------------------------------------------------------------------------------------- bodies before auth


def test_json_bodies_are_capped(service, scene_files):
    with app(service, api_keys=KEYS, max_json_kb=64) as c:
        sid = service.upload(scene_files["cornell"], headers=RED).json()["id"]
        pad = {"scene_id": sid, "config": {}, "x": "a" * (100 * 1024)}
        r = c.post("/v1/bakes", json=pad, headers=RED)
        assert r.status_code == 413 and r.json()["error"]["code"] == "too_large", r.text
        # no Content-Length: counted while it streams
        r = c.post("/v1/bakes", content=iter([b"{" + b" " * 40_000] * 3), headers={**RED, "Content-Type":
                                                                                   "application/json"})
        assert r.status_code == 413, r.text
        # without a key: 401, whatever the size
        assert c.post("/v1/bakes", json=pad).status_code == 401
        # a small body still works
        assert c.post("/v1/bakes?dry_run=true", json={"scene_id": sid}, headers=RED).status_code == 200


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """A real ``kiln serve`` (uvicorn, embedded Redis, 2 workers) with two teams, uploads named slow* taking 60 s
    to parse, two parser processes."""
    from tests.serve_process import spawn_serve

    data = tmp_path_factory.mktemp("live") / "data"
    saved = dict(os.environ)
    os.environ.update(KILN_FAULT_INGEST_DELAY="60", KILN_INGEST_PROCESSES="2", KILN_MAX_UPLOADS_PER_TEAM="2",
                      KILN_INGEST_TIMEOUT_S="120")
    try:
        proc, url = spawn_serve(data, api_keys=KEYS, log=data.parent / "serve.log")
    finally:
        os.environ.clear()
        os.environ.update(saved)
    try:
        yield proc, url
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _raw_post(url: str, path: str, headers: dict, body_len: int, first: bytes = b"") -> socket.socket:
    host, port = url.removeprefix("http://").split(":")
    s = socket.create_connection((host, int(port)), timeout=10)
    head = f"POST {path} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {body_len}\r\n"
    head += "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n"
    s.sendall(head.encode() + first)
    return s


def test_a_200_mb_body_without_a_key_is_401_before_it_is_read(live):
    proc, url = live
    api = psutil.Process(proc.pid)
    for path in ("/v1/bakes", "/v1/scenes"):          # a JSON route and the upload route
        httpx.get(url + "/healthz", timeout=5)
        before = api.memory_info().rss
        for _ in range(3):
            # 64 KB of a 200 MB body sent, then the reply read: a 401 here came before the body was read
            s = _raw_post(url, path, {"Content-Type": "application/json"}, 200 * 2**20, b"{" + b" " * 65535)
            reply = s.recv(4096)
            assert reply.startswith(b"HTTP/1.1 401"), reply[:200]
            assert b"connection: close" in reply.lower()
            # the client keeps sending: the server has closed the connection, it reads nothing more
            sent = 0
            try:
                chunk = b" " * (1 << 20)
                while sent < 200 * 2**20:
                    s.sendall(chunk)
                    sent += len(chunk)
            except OSError:
                pass
            s.close()
            assert sent < 200 * 2**20, "the server read the whole body"
        time.sleep(0.5)
        grown = api.memory_info().rss - before
        assert grown < 8 * 2**20, f"the API grew by {grown / 2**20:.1f} MB"


def _parser_pids(proc) -> set[int]:
    return {c.pid for c in psutil.Process(proc.pid).children() if "spawn_main" in " ".join(c.cmdline())}


def test_an_abandoned_upload_stops_its_parse(live, scene_files):
    """Two slow uploads (60 s each) of red take both parsers; red's clients go away after 1.5 s; blue's upload
    is parsed at once, not after a minute; the two parser processes were killed and replaced."""
    proc, url = live
    glb = scene_files["cornell"].read_bytes()
    warm = httpx.post(url + "/v1/scenes", content=glb, headers={**BLUE, "X-Filename": "warm.glb"}, timeout=60)
    assert warm.status_code in (200, 201), warm.text          # the parsers start on the first upload
    deadline = time.monotonic() + 30
    while len(_parser_pids(proc)) < 2:
        assert time.monotonic() < deadline, "no parser processes"
        time.sleep(0.2)
    before = _parser_pids(proc)
    socks = [_raw_post(url, "/v1/scenes", {**RED, "X-Filename": f"slow-{i}.glb"}, len(glb), glb) for i in range(2)]
    time.sleep(1.5)
    for s in socks:
        s.close()
    other = scene_files["two-rooms"].read_bytes()
    r = httpx.post(url + "/v1/scenes", content=other, headers={**BLUE, "X-Filename": "fast.glb"}, timeout=120)
    assert r.status_code == 201, r.text
    # both parsers were busy with red's 60 s parses: blue's was parsed because they were killed and replaced
    assert not (before & _parser_pids(proc)), "the abandoned parses' processes are still there"


def test_uploads_per_team_are_limited_with_retry_after(live, scene_files):
    proc, url = live
    glb = scene_files["cornell"].read_bytes()
    socks = [_raw_post(url, "/v1/scenes", {**RED, "X-Filename": f"slow-limit-{i}.glb"}, len(glb), glb)
             for i in range(2)]
    try:
        time.sleep(1.0)
        r = httpx.post(url + "/v1/scenes", content=glb, headers={**RED, "X-Filename": "third.glb"}, timeout=30)
        assert r.status_code == 429, r.text
        assert r.json()["error"]["code"] == "too_many_uploads" and int(r.headers["retry-after"]) > 0
    finally:
        for s in socks:
            s.close()


def test_a_parse_past_the_timeout_is_stopped(service, scene_files, monkeypatch):
    monkeypatch.setenv("KILN_FAULT_INGEST_DELAY", "60")
    with app(service, ingest_timeout_s=2.0) as c:
        r = c.post("/v1/scenes", content=scene_files["cornell"].read_bytes(), headers={"X-Filename": "slow.glb"})
        assert r.status_code == 422 and r.json()["error"]["code"] == "ingest_timeout", r.text
        pool = c.app.state.ingest_pool
        assert pool.killed["timeout"] == 1                         # stopped by the timeout, not finished
        # the next upload gets a fresh parser; its own speed is not what is tested (a cold parser on a loaded
        # machine can take 2 s), so it gets a generous timeout
        pool.timeout_s = 120.0
        assert service.upload(scene_files["cornell"]).status_code == 201
        assert pool.killed["timeout"] == 1


def test_waiting_uploads_are_served_round_robin_by_team(service, scene_files, monkeypatch):
    """One parser, each slow parse 1.5 s: red queues three uploads, then blue one; blue's is parsed second, not
    fourth (first come first served would put it behind all of red's)."""
    monkeypatch.setenv("KILN_FAULT_INGEST_DELAY", "1.5")
    glb = scene_files["cornell"].read_bytes()
    done: list[tuple[str, float]] = []
    with app(service, api_keys=KEYS, ingest_processes=1, max_uploads_per_team=3) as c:
        def up(team, headers, i):
            r = c.post("/v1/scenes", content=glb, headers={**headers, "X-Filename": f"slow-{team}-{i}.glb"})
            assert r.status_code in (200, 201), r.text
            done.append((team, time.monotonic()))

        ts = []
        for i in range(3):
            ts.append(threading.Thread(target=up, args=("red", RED, i)))
            ts[-1].start()
            time.sleep(0.3)
        ts.append(threading.Thread(target=up, args=("blue", BLUE, 0)))
        ts[-1].start()
        for t in ts:
            t.join(120)
    order = [team for team, _ in sorted(done, key=lambda x: x[1])]
    assert len(order) == 4
    assert order.index("blue") <= 1, order


# --------------------------------------------------------------------------------------------- quotas


def test_quotas_on_scenes_stored_bytes_and_concurrent_bakes(service, scene_files):
    # no workers: bakes stay queued, so they stay concurrent
    with app(service, api_keys=KEYS, quota_scenes=2, quota_concurrent_bakes=1) as c:
        s1 = service.upload(scene_files["cornell"], headers=RED).json()["id"]
        s2 = service.upload(scene_files["two-rooms"], headers=RED).json()["id"]
        r = service.upload(scene_files["sealed-box"], headers=RED)
        assert r.status_code == 429 and r.json()["error"]["code"] == "quota_exceeded", r.text
        assert "scenes" in r.json()["error"]["message"] and int(r.headers["retry-after"]) > 0
        # refused before the body is read: even a scene the team has (it is not known before parsing)
        assert service.upload(scene_files["cornell"], headers=RED).status_code == 429
        assert service.upload(scene_files["sealed-box"], headers=BLUE).status_code == 201  # another team
        assert c.post("/v1/bakes", json={"scene_id": s1, "config": TINY}, headers=RED).status_code == 202
        r = c.post("/v1/bakes", json={"scene_id": s2, "config": TINY}, headers=RED)
        assert r.status_code == 429 and r.json()["error"]["code"] == "quota_exceeded", r.text
        assert 5 <= int(r.headers["retry-after"]) <= 3600
        assert c.post("/v1/bakes", json={"scene_id": s2, "config": TINY}, headers=BLUE).status_code == 404
    with app(service, api_keys=KEYS, quota_stored_mb=1) as c:
        # red holds two small scenes (< 1 MB); a 2 MB scene would pass the quota
        big = _scene_with_triangles(service.data.parent / "big.glb", 20_000)
        r = service.upload(big, headers=RED)
        assert r.status_code == 429 and "stored bytes" in r.json()["error"]["message"], r.text
        assert c.get("/v1/scenes", headers=RED).json()["total"] == 2


def _scene_with_triangles(path: Path, n: int) -> Path:
    from tests.gltf_build import GltfBuilder

    rng = np.random.default_rng(0)
    base = rng.uniform(0, 10, (n, 1, 3)).astype(np.float32)
    tri = (base + np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0]], np.float32)).reshape(-1, 3)
    g = GltfBuilder()
    g.mesh(tri, material=g.material(pbrMetallicRoughness={"baseColorFactor": [0.8, 0.8, 0.8, 1]}))
    path.write_bytes(g.glb())
    return path


def _scene_with_textures(path: Path, size: int, count: int) -> Path:
    from tests.gltf_build import GltfBuilder, quad

    g = GltfBuilder()
    for i in range(count):
        img = np.zeros((size, size, 4), np.uint8)
        img[..., 3] = 255
        tex = g.image(img)
        pos, nrm, uv, idx = quad([i, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1])
        g.mesh(pos, idx, normals=nrm, uv=uv, material=g.material(pbrMetallicRoughness={"baseColorTexture":
                                                                                      {"index": tex}}))
    path.write_bytes(g.glb())
    return path


def test_the_expanded_size_of_an_upload_is_limited(service):
    with app(service, max_scene_mb=2) as c:
        # four 512² textures: a small file, 4 MB of decoded pixels (> 2 MB): refused from the image headers
        f = _scene_with_textures(service.data.parent / "tex.glb", 512, 4)
        assert f.stat().st_size < 100_000
        r = service.upload(f)
        assert r.status_code == 413 and r.json()["error"]["code"] == "image_too_large", r.text
        # 30 k triangles: a 1 MB file whose normalized scene is 3.4 MB
        r = service.upload(_scene_with_triangles(service.data.parent / "tris.glb", 30_000))
        assert r.status_code == 413 and r.json()["error"]["code"] == "scene_too_large", r.text
        assert c.get("/v1/scenes").json()["total"] == 0
        # within the limit: stored, with its size
        r = service.upload(_scene_with_textures(service.data.parent / "ok.glb", 256, 2))
        assert r.status_code == 201, r.text
        assert 2 * 256 * 256 * 4 <= r.json()["bytes"] < 2 * 2**20


# --------------------------------------------------------------------------------------------- cancel, queues


def test_cancel_kills_a_stage_that_reports_no_progress(service, scene_files):
    service.start_workers(1, env={"KILN_FAULT_STAGE_DELAY": "place=120"})
    with app(service) as c:
        sid = service.upload(scene_files["cornell"]).json()["id"]
        bid = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}).json()["id"]
        pid = _stage_pid(service.data, bid, "place")
        r = c.post(f"/v1/bakes/{bid}/cancel")
        assert r.status_code == 200 and r.json()["status"] == "cancelled"
        deadline = time.monotonic() + 60           # a wait, not a measure: the stage itself would run 120 s
        while not _gone(pid):
            assert time.monotonic() < deadline, "the work-horse still runs 60 s after the cancel"
            time.sleep(0.05)
        conn = c.app.state.redis
        jid = kq.job_id(bid, 0, "place")
        deadline = time.monotonic() + 10
        while Job.fetch(jid, connection=conn).get_status() != JobStatus.STOPPED:
            assert time.monotonic() < deadline, Job.fetch(jid, connection=conn).get_status()
            time.sleep(0.1)
        time.sleep(2)
        b = Catalog(service.data / "kiln.db").get_bake(bid)
        place = next(s for s in b["stages"] if s["name"] == "place")
        assert b["status"] == "cancelled" and place["status"] == "cancelled" and place["pid"] == pid  # no retry
        assert _attempts(conn, jid) <= 1


def test_stage_timeouts_and_queues_follow_the_estimate(service, scene_files):
    with app(service) as c:      # no workers: the jobs stay queued, to be looked at
        sid = service.upload(scene_files["cornell"]).json()["id"]
        bid = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY_PRT}).json()["id"]
        conn = c.app.state.redis
        est = cost.estimate(c.get(f"/v1/scenes/{sid}").json(), BakeConfig.model_validate(TINY_PRT))
        for name in ("ingest", "light", "prt"):
            job = Job.fetch(kq.job_id(bid, 0, name), connection=conn)
            assert job.timeout == cost.stage_timeout(est.stage(name)) < 3600
            assert job.origin == (kq.LONG_QUEUE if name == "prt" else kq.SHORT_QUEUE)
            assert job.meta["memory_limit_bytes"] == 8192 * 2**20
        assert Job.fetch(kq.job_id(bid, 0, "finish"), connection=conn).origin == kq.SHORT_QUEUE


def test_two_heavy_bakes_do_not_hold_every_worker(service, scene_files):
    """Two workers (``kiln serve``'s layout: one takes only the short queue); two bakes whose prt stage runs 120 s;
    a third, short bake still finishes while both heavy ones are running."""
    service.start_workers(2, env={"KILN_FAULT_STAGE_DELAY": "prt=120"})
    assert [service.pool.queues(i) for i in range(2)] == ["short", "short,long"]
    with app(service, api_keys=KEYS) as c:
        sid = service.upload(scene_files["cornell"], headers=RED).json()["id"]
        heavy = [c.post("/v1/bakes", json={"scene_id": sid, "config": {**TINY_PRT, "seed": i}}, headers=RED
                        ).json()["id"] for i in range(2)]
        cat = Catalog(service.data / "kiln.db")
        deadline = time.monotonic() + 90
        while not any(s["name"] == "prt" and s["status"] == "running" for h in heavy
                      for s in cat.get_bake(h)["stages"]):        # one heavy bake holds the long-queue worker
            assert time.monotonic() < deadline, "no prt stage started"
            time.sleep(0.1)
        sid_b = service.upload(scene_files["two-rooms"], headers=BLUE).json()["id"]
        light = c.post("/v1/bakes", json={"scene_id": sid_b, "config": TINY}, headers=BLUE).json()["id"]
        b = service.wait_bake(light, timeout=120, headers=BLUE)
        assert b["status"] == "succeeded", b
        assert all(c.get(f"/v1/bakes/{h}", headers=RED).json()["status"] == "running" for h in heavy)
        for h in heavy:
            assert c.post(f"/v1/bakes/{h}/cancel", headers=RED).status_code == 200


# --------------------------------------------------------------------------------------------- tenancy


def test_metrics_need_a_key_and_show_only_the_team(service, scene_files):
    service.start_workers(1)
    with app(service, api_keys=KEYS) as c:
        assert c.get("/metrics").status_code == 401
        assert c.get("/metrics", headers={"Authorization": "Bearer nope-nope-nope"}).status_code == 401
        sid = service.upload(scene_files["cornell"], headers=RED).json()["id"]
        bid = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}, headers=RED).json()["id"]
        assert service.wait_bake(bid, headers=RED)["status"] == "succeeded"
        red = c.get("/metrics", headers=RED).text
        blue = c.get("/metrics", headers=BLUE).text
        assert 'kiln_bakes{status="succeeded"} 1.0' in red
        assert 'kiln_bakes{status="succeeded"} 0.0' in blue and 'stage="place"' not in blue
        assert "kiln_queue_depth" in blue          # aggregates name no bake


def test_the_stage_cache_tells_a_team_nothing_of_another_teams_bakes(service, scene_files):
    service.start_workers(1)
    with app(service, api_keys=KEYS) as c:
        sid = service.upload(scene_files["cornell"], headers=RED).json()["id"]
        first = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}, headers=RED).json()
        assert service.wait_bake(first["id"], headers=RED)["status"] == "succeeded"
        again = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}, headers=RED).json()
        assert again["status"] == "succeeded"           # the team's own cache: done at once
        assert service.upload(scene_files["cornell"], headers=BLUE).json()["id"] == sid
        other = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}, headers=BLUE).json()
        # blue's bake runs (a worker may have picked it up already): nothing says red baked it
        assert other["status"] in ("queued", "running"), other
        b = service.wait_bake(other["id"], headers=BLUE)
        assert b["status"] == "succeeded" and not any(s["cached"] for s in b["stages"])
        cat = Catalog(service.data / "kiln.db")
        keys_red = {s["cache_key"] for s in cat.get_bake(first["id"])["stages"]}
        keys_blue = {s["cache_key"] for s in cat.get_bake(other["id"])["stages"]}
        assert not keys_red & keys_blue


def test_a_key_given_to_two_teams_refuses_to_start(tmp_path):
    from pydantic import ValidationError

    from server.config import Settings

    with pytest.raises(ValidationError, match="one key to two teams"):
        Settings(data=tmp_path, api_keys="red:same-key-123,blue:same-key-123")
    Settings(data=tmp_path, api_keys="red:key-one-123,red:key-two-123")   # one team, two keys: fine
    env = dict(os.environ, KILN_API_KEYS="red:same-key-123,blue:same-key-123")
    env.pop("REDIS_URL", None)
    p = subprocess.run([sys.executable, "-m", "server.cli", "serve", "--data", str(tmp_path / "d"), "--port", "1"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert "one key to two teams" in p.stderr and "same-key-123" not in p.stderr
    assert not (tmp_path / "d").exists()        # nothing started


@pytest.mark.parametrize("lost", ["started", "popped"])
def test_a_bake_whose_jobs_redis_lost_midway_is_recovered(service, scene_files, lost):
    """Redis restarted mid-bake (bench_load.py found both): ``started``: the catalog says ingest succeeded, Redis
    still says its job started (its worker died with Redis), the rest is deferred behind it for ever; ``popped``:
    ingest's job is queued in its hash but in no queue list (a worker popped it, then died with Redis). Once
    nothing moved for STALL_S, recovery re-enqueues the bake and it succeeds."""
    from workers import pipeline

    with app(service) as c:      # no workers yet
        sid = service.upload(scene_files["cornell"]).json()["id"]
        bid = c.post("/v1/bakes", json={"scene_id": sid, "config": TINY}).json()["id"]
        conn, catalog, store = c.app.state.redis, c.app.state.catalog, c.app.state.store
        ingest = Job.fetch(kq.job_id(bid, 0, "ingest"), connection=conn)
        Queue(ingest.origin, connection=conn).remove(ingest.id)
        long_ago = time.time() - 2 * kq.STALL_S
        if lost == "started":
            # ingest ran (its output is in the store, the catalog says so) but Redis lost its completion
            pipeline.execute_stage(store, sid, BakeConfig.model_validate(TINY), "ingest", namespace="default")
            ingest.set_status(JobStatus.STARTED)
            catalog.update_stage(bid, "ingest", status="succeeded", progress=1.0, started=long_ago,
                                 finished=long_ago)
        else:
            assert ingest.get_status() == JobStatus.QUEUED
            with catalog._conn() as db:
                db.execute("UPDATE bakes SET created=? WHERE id=?", (long_ago, bid))
        bake = catalog.get_bake(bid)
        assert Job.fetch(kq.job_id(bid, 0, "place"), connection=conn).get_status() == JobStatus.DEFERRED
        assert kq.live_jobs(conn, bake) == []                     # nothing of it can run any more
        # a bake that moved a moment ago is left alone
        assert kq.live_jobs(conn, {**bake, "stages": [{**s, "finished": time.time()} for s in bake["stages"]]})
        assert kq.live_jobs(conn, {**bake, "created": time.time(), "stages": [
            {**s, "started": None, "finished": None} for s in bake["stages"]]})
        with catalog._conn() as db:                                # created long ago too (recovery's grace)
            db.execute("UPDATE bakes SET created=? WHERE id=?", (long_ago, bid))
        deadline = time.monotonic() + 30
        while catalog.get_bake(bid)["attempt"] == 0:              # the app's recovery loop (every 0.5 s here)
            assert time.monotonic() < deadline, "the stalled bake was not re-enqueued"
            time.sleep(0.1)
        assert Job.fetch(kq.job_id(bid, 0, "place"), connection=conn).get_status() == JobStatus.CANCELED
        service.start_workers(1)
        b = service.wait_bake(bid, timeout=120)
        assert b["status"] == "succeeded", b
        assert b["stages"][0]["status"] == "succeeded"
