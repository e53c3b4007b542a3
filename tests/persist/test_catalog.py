"""The SQLite catalog (persist/catalog.py)."""
from __future__ import annotations

import os

from persist.catalog import Catalog


def test_catalog_bake_lifecycle(tmp_path):
    c = Catalog(tmp_path / "k.db")
    assert c.add_scene("t", "s1", {"id": "s1", "triangles": 3}, "a.glb")
    assert not c.add_scene("t", "s1", {"id": "s1", "triangles": 3}, "a.glb")
    bid = c.create_bake("t", "s1", {"seed": 0}, [("ingest", "k1"), ("place", "k2")])
    b = c.get_bake(bid)
    assert b["status"] == "queued" and [s["name"] for s in b["stages"]] == ["ingest", "place"]
    assert c.get_bake(bid, team="other") is None
    assert c.set_bake_status(bid, "running")
    c.update_stage(bid, "ingest", status="succeeded", seconds=1.5, cached=True, stats={"a": 1})
    assert c.get_bake(bid)["stages"][0]["stats"] == {"a": 1}
    assert c.set_bake_status(bid, "cancelled")
    assert not c.set_bake_status(bid, "running")  # terminal states are never left
    assert c.count_bakes_by_status()["cancelled"] == 1
    # a new Catalog on the same file (a restart) sees everything
    c2 = Catalog(tmp_path / "k.db")
    assert c2.get_bake(bid)["status"] == "cancelled" and c2.list_scenes("t", 10, 0)[1] == 1


def test_catalog_reads_reuse_a_connection_per_thread_and_see_every_write(tmp_path):
    """Reads keep one connection per thread (and process): each read still sees the latest commit, from
    another Catalog (as the API sees the workers' progress), another thread, and a forked child."""
    import threading

    api, worker = Catalog(tmp_path / "k.db"), Catalog(tmp_path / "k.db")
    bid = worker.create_bake("t", "s1", {"seed": 0}, [("ingest", "k1")])
    assert api.get_bake(bid)["stages"][0]["progress"] == 0.0
    first = api._local.conn
    for p in (0.25, 0.5):
        worker.update_stage(bid, "ingest", status="running", progress=p)
        assert api.get_bake(bid)["stages"][0]["progress"] == p
    assert api._local.conn is first                                 # reused, not reopened

    seen = []
    t = threading.Thread(target=lambda: seen.append((api.get_bake(bid)["status"], api._local.conn)))
    t.start()
    t.join()
    assert seen[0][0] == "queued" and seen[0][1] is not first      # its own connection

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                                    # the child must not use the parent's connection
        ok = api.get_bake(bid)["stages"][0]["progress"] == 0.5 and api._local.conn is not first
        os.write(w, b"1" if ok else b"0")
        os._exit(0)
    os.waitpid(pid, 0)
    assert os.read(r, 1) == b"1"


def test_mark_succeeded_records_metrics_and_manifest_once(tmp_path):
    c = Catalog(tmp_path / "k.db")
    bid = c.create_bake("t", "s1", {"seed": 0}, [("ingest", "k1")])
    assert c.mark_succeeded(bid, {"bake_id": bid}, {"artifact_bytes": 12, "stage_seconds.ingest": 0.5})
    b = c.get_bake(bid)
    assert b["status"] == "succeeded" and b["manifest"] == {"bake_id": bid} and b["finished"] is not None
    assert b["metrics"] == {"artifact_bytes": 12.0, "stage_seconds.ingest": 0.5}
    assert not c.mark_succeeded(bid, {"bake_id": "other"}, {})       # terminal: the manifest is kept
    assert c.get_bake(bid)["manifest"] == {"bake_id": bid}
