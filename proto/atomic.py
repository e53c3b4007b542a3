"""Atomic file writes for the bundle writers (:mod:`proto.ktx2`, :mod:`proto.bundle`) and their callers.

A bundle file is either absent or whole: a reader (the viewer, ``open_bundle``, a build tool polling the
folder) never sees a partial artifact, even when the writer is killed half-way.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes"]


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> int:
    """Write ``data`` to ``path`` via a temp file in the same directory + fsync + rename (mode 0644).

    A reader sees the old file or the whole new one, never a part. Returns the byte count.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return len(data)
