"""The content-addressed store (persist/store.py)."""
from __future__ import annotations

import hashlib
import multiprocessing as mp
import os
import signal
import time

from persist.store import Store


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
    deadline = time.monotonic() + 60            # a wait for the first blob, not a measure (the child may start slowly)
    while not any((tmp_path / "blobs").glob("*/*")):
        assert time.monotonic() < deadline and p.is_alive(), "the writer wrote nothing"
        time.sleep(0.05)
    time.sleep(0.5)                             # kill it mid-way through a later blob
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
