"""The artifact store: a directory of content-addressed files, written atomically.

Layout under ``root``::

    blobs/ab/abcdef...        one file per distinct content, named by its sha256
    stages/<cache_key>.json   what a finished stage produced: its artifacts (name -> blob) and stats
    tmp/                      temp files, renamed into place when complete

A file appears under its final name only once it is complete (write to ``tmp/`` + fsync +
``os.replace``), so a reader never sees a partial artifact, even if the writer is killed
with SIGKILL half-way. A stage index is written after all its blobs: a stage is either
wholly in the store or not at all.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterator

_CHUNK = 1 << 20


class Store:
    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        for sub in ("blobs", "stages", "tmp"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    # ------------------------------------------------------------------ blobs
    def blob_path(self, sha256: str) -> Path:
        if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
            raise ValueError(f"not a sha256: {sha256!r}")
        return self.root / "blobs" / sha256[:2] / sha256

    def has_blob(self, sha256: str) -> bool:
        return self.blob_path(sha256).is_file()

    @contextmanager
    def temp_file(self, suffix: str = "") -> Iterator[Path]:
        """A fresh path under ``tmp/`` (same filesystem as the blobs), removed on exit if still there."""
        fd, name = tempfile.mkstemp(dir=self.root / "tmp", suffix=suffix)
        os.close(fd)
        path = Path(name)
        try:
            yield path
        finally:
            path.unlink(missing_ok=True)

    def put_file(self, path: str | os.PathLike, move: bool = False, sha256: str | None = None) -> str:
        """Add a finished file to the store; returns its sha256.

        ``move`` renames a file that lies under the store's ``tmp/`` instead of copying it. ``sha256``: the
        caller already hashed this very file (``bundle.write_artifact`` does), so it is not read again.
        """
        path = Path(path)
        if sha256 is None:
            h = hashlib.sha256()
            with open(path, "rb") as f:
                while chunk := f.read(_CHUNK):
                    h.update(chunk)
            sha256 = h.hexdigest()
        digest = sha256
        dest = self.blob_path(digest)
        if dest.exists():
            if move:
                path.unlink(missing_ok=True)
            return digest
        dest.parent.mkdir(parents=True, exist_ok=True)
        if move and path.resolve().is_relative_to((self.root / "tmp").resolve()):
            _fsync(path)
            os.replace(path, dest)
        else:
            with self.temp_file() as tmp:
                shutil.copyfile(path, tmp)
                _fsync(tmp)
                os.replace(tmp, dest)
            if move:
                path.unlink(missing_ok=True)
        return digest

    def put_bytes(self, data: bytes) -> str:
        digest = hashlib.sha256(data).hexdigest()
        dest = self.blob_path(digest)
        if dest.exists():
            return digest
        dest.parent.mkdir(parents=True, exist_ok=True)
        with self.temp_file() as tmp:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, dest)
        return digest

    def read_bytes(self, sha256: str) -> bytes:
        return self.blob_path(sha256).read_bytes()

    def open_blob(self, sha256: str) -> IO[bytes]:
        return open(self.blob_path(sha256), "rb")

    # ------------------------------------------------------------------ stage index
    def stage_index_path(self, cache_key: str) -> Path:
        if not cache_key.isalnum():
            raise ValueError(f"bad cache key {cache_key!r}")
        return self.root / "stages" / f"{cache_key}.json"

    def get_stage(self, cache_key: str) -> dict | None:
        """The stage record for ``cache_key``, or None when that stage has not completed.

        A record whose blobs are missing (deleted by hand) counts as absent.
        """
        p = self.stage_index_path(cache_key)
        try:
            rec = json.loads(p.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None
        if not all(self.has_blob(a["sha256"]) for a in rec.get("artifacts", [])):
            return None
        return rec

    def put_stage(self, cache_key: str, record: dict) -> None:
        """Write a stage record atomically (after its blobs are in place)."""
        data = json.dumps(record, sort_keys=True, indent=1).encode()
        with self.temp_file(suffix=".json") as tmp:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.stage_index_path(cache_key))


def _fsync(path: Path) -> None:
    with open(path, "rb+") as f:
        os.fsync(f.fileno())
