"""proto/atomic.py: a file written by atomic_write_bytes is absent, the old one, or the whole new one."""
from __future__ import annotations

import os
import stat

import pytest

from proto import atomic
from proto.atomic import atomic_write_bytes


def test_writes_creates_parents_and_replaces(tmp_path):
    p = tmp_path / "a" / "b" / "f.bin"
    assert atomic_write_bytes(p, b"one") == 3 and p.read_bytes() == b"one"
    assert atomic_write_bytes(p, b"second") == 6 and p.read_bytes() == b"second"
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    assert sorted(x.name for x in p.parent.iterdir()) == ["f.bin"]          # no temp file left behind


def test_a_failed_write_keeps_the_old_file_and_no_temp(tmp_path, monkeypatch):
    p = tmp_path / "f.bin"
    atomic_write_bytes(p, b"old")

    def boom(*_):
        raise OSError("disk gone")
    monkeypatch.setattr(atomic.os, "replace", boom)
    with pytest.raises(OSError, match="disk gone"):
        atomic_write_bytes(p, b"new")
    assert p.read_bytes() == b"old" and os.listdir(tmp_path) == ["f.bin"]
