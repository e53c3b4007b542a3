"""The content-addressed store and the SQLite catalog."""
from __future__ import annotations

import hashlib
import multiprocessing as mp
import os
import signal
import time

from proto.catalog import Catalog
from proto.store import Store


def test_blobs_are_content_addressed_and_deduplicated(tmp_path):
    s = Store(tmp_path)
    d1 = s.put_bytes(b"hello")
    assert d1 == hashlib.sha256(b"hello").hexdigest()
    assert s.put_bytes(b"hello") == d1
    assert s.read_bytes(d1) == b"hello"
    f = tmp_path / "x.bin"
    f.write_bytes(b"world" * 1000)
    d2 = s.put_file(f)
    assert f.exists() and s.read_bytes(d2) == b"world" * 1000
    assert len(list((tmp_path / "blobs").glob("*/*"))) == 2
    assert not any((tmp_path / "tmp").iterdir())


def _writer(root, n):
    s = Store(root)
    for i in range(n):
        s.put_bytes(os.urandom(1 << 20))


def test_killed_writer_leaves_no_partial_blob(tmp_path):
    p = mp.get_context("spawn").Process(target=_writer, args=(str(tmp_path), 10_000))
    p.start()
    time.sleep(1.5)
    os.kill(p.pid, signal.SIGKILL)
    p.join()
    blobs = list((tmp_path / "blobs").glob("*/*"))
    assert blobs
    for b in blobs:
        assert hashlib.sha256(b.read_bytes()).hexdigest() == b.name


def test_stage_record_missing_blob_counts_as_absent(tmp_path):
    s = Store(tmp_path)
    d = s.put_bytes(b"a")
    s.put_stage("k1", {"stage": "x", "artifacts": [{"sha256": d}]})
    assert s.get_stage("k1")["stage"] == "x"
    s.blob_path(d).unlink()
    assert s.get_stage("k1") is None
    assert s.get_stage("nothere") is None


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


def test_put_file_moves_from_a_folder_under_tmp_and_trusts_a_given_hash(tmp_path):
    s = Store(tmp_path / "store")
    sub = s.root / "tmp" / "stage-x"
    sub.mkdir(parents=True)
    f = sub / "a.bin"
    f.write_bytes(b"kiln" * 1000)
    ino = f.stat().st_ino
    digest = hashlib.sha256(b"kiln" * 1000).hexdigest()
    assert s.put_file(f, move=True, sha256=digest) == digest
    assert not f.exists() and s.blob_path(digest).stat().st_ino == ino   # renamed, not copied
    g = tmp_path / "outside.bin"                                         # outside tmp/: copied, hashed
    g.write_bytes(b"other")
    assert s.put_file(g, move=True) == hashlib.sha256(b"other").hexdigest() and not g.exists()
