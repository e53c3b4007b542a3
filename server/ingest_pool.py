"""Uploads are parsed in child processes, so a huge or hostile file cannot grow or crash the API, and no team's
uploads can starve another's.

The API streams the upload to disk; a child runs :func:`workers.jobs.ingest_upload` (by name) on that file and
stores the normalized scene; the API only sees a small summary. The pool is built for hostile load:

- **a timeout per upload** (``KILN_INGEST_TIMEOUT_S``): a parse that runs longer is killed with its process
  (``ingest_timeout``, 422) and the process replaced;
- **cancellation**: when the client disconnects while its file is parsed (or waits for a parser), the parse is
  killed (or never starts);
- **a per-team limit** on concurrent uploads (``KILN_MAX_UPLOADS_PER_TEAM``, :meth:`IngestPool.admit`, 429 with
  ``Retry-After`` beyond it), counted from the first byte of the body to the answer;
- **fair order**: an upload waiting for a parser goes to the team served least recently, not first come first
  served, so a team with many uploads waiting delays another team's by at most one parse per parser.

Each child has its own temporary directory under the upload directory, emptied when it is killed.
"""
from __future__ import annotations

import asyncio
import contextlib
import importlib
import logging
import multiprocessing as mp
import shutil
import tempfile
import time
from collections import OrderedDict, deque
from pathlib import Path
from typing import Awaitable, Callable

log = logging.getLogger("kiln.ingest")

INGEST_FUNCTION = "workers.jobs:ingest_upload"
DISCONNECT_POLL_S = 0.25


def _call(target: str, *args):
    mod, _, fn = target.partition(":")
    return getattr(importlib.import_module(mod), fn)(*args)


def _child_main(conn, tmpdir: str) -> None:
    """A parser process: run each ``(target, args)`` it is sent and send back the result (or the error)."""
    tempfile.tempdir = tmpdir
    while True:
        try:
            msg = conn.recv()
        except EOFError:
            return
        if msg is None:
            return
        target, args = msg
        try:
            out = _call(target, *args)
        except MemoryError:
            out = {"error": {"status": 413, "code": "too_large",
                             "message": "the file needs more memory to read than this service allows"}}
        except Exception as e:  # never expected: ingest_upload returns its errors
            out = {"error": {"status": 422, "code": "invalid_gltf",
                             "message": f"the file could not be read ({type(e).__name__})"}}
        conn.send(out)


class UploadsBusy(Exception):
    """The team already has as many uploads in flight as it may."""

    def __init__(self, team: str, limit: int):
        super().__init__(f"team {team} has {limit} uploads in progress")
        self.limit = limit


class _Child:
    def __init__(self, ctx, tmp_root: Path, index: int):
        self.tmpdir = tmp_root / f"parser-{index}"
        shutil.rmtree(self.tmpdir, ignore_errors=True)
        self.tmpdir.mkdir(parents=True, exist_ok=True)
        self.conn, child_conn = ctx.Pipe()
        self.proc = ctx.Process(target=_child_main, args=(child_conn, str(self.tmpdir)), daemon=True,
                                name=f"kiln-ingest-{index}")
        self.proc.start()
        child_conn.close()
        self.index = index
        self.tasks = 0

    def kill(self) -> None:
        with contextlib.suppress(Exception):
            self.proc.kill()
        self.proc.join(5)
        with contextlib.suppress(Exception):
            self.conn.close()
        shutil.rmtree(self.tmpdir, ignore_errors=True)

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            self.conn.send(None)
        self.proc.join(2)
        if self.proc.is_alive():
            self.kill()
        with contextlib.suppress(Exception):
            self.conn.close()
        shutil.rmtree(self.tmpdir, ignore_errors=True)


class IngestPool:
    def __init__(self, processes: int = 2, tasks_per_child: int = 16, *, timeout_s: float = 300.0,
                 per_team: int = 2, tmp_root: str | Path | None = None):
        self._n, self._tasks, self.timeout_s, self.per_team = processes, tasks_per_child, timeout_s, per_team
        self._ctx = mp.get_context("spawn")
        self._tmp_root = Path(tmp_root) if tmp_root else Path(tempfile.mkdtemp(prefix="kiln-ingest-"))
        self._children: list[_Child] = []
        self._idle: list[_Child] = []
        self._waiting: "OrderedDict[str, deque[asyncio.Future]]" = OrderedDict()
        self._in_flight: dict[str, int] = {}
        self._served: dict[str, int] = {}      # team -> when it last got a parser (a counter)
        self._clock = 0
        self._closed = False
        self.killed = {"timeout": 0, "disconnect": 0, "crash": 0}

    # ------------------------------------------------------------------ processes
    def _start(self) -> None:
        if not self._children and not self._closed:
            for i in range(self._n):
                c = _Child(self._ctx, self._tmp_root, i)
                self._children.append(c)
                self._idle.append(c)

    def _replace(self, child: _Child) -> _Child:
        child.kill()
        new = _Child(self._ctx, self._tmp_root, child.index)
        self._children[self._children.index(child)] = new
        return new

    async def _acquire(self, team: str) -> _Child:
        self._start()
        if self._idle and not self._waiting:
            self._mark_served(team)
            return self._idle.pop()
        fut = asyncio.get_running_loop().create_future()
        self._waiting.setdefault(team, deque()).append(fut)
        try:
            return await fut
        except asyncio.CancelledError:
            q = self._waiting.get(team)
            if q is not None and fut in q:
                q.remove(fut)
                if not q:
                    del self._waiting[team]
            if fut.done() and not fut.cancelled():
                self._release(fut.result())
            raise

    def _mark_served(self, team: str) -> None:
        self._clock += 1
        self._served[team] = self._clock
        if len(self._served) > 10_000:          # forget teams served long ago (they count as never served)
            for t, _ in sorted(self._served.items(), key=lambda kv: kv[1])[:5_000]:
                del self._served[t]

    def _release(self, child: _Child) -> None:
        """Hand ``child`` to the next waiting upload: of the team served least recently (never served first; ties
        by arrival), so teams take turns however many uploads each has waiting."""
        if self._closed:
            child.stop()
            return
        while self._waiting:
            order = {t: i for i, t in enumerate(self._waiting)}
            team = min(self._waiting, key=lambda t: (self._served.get(t, -1), order[t]))
            q = self._waiting[team]
            fut = q.popleft()
            if not q:
                del self._waiting[team]
            if not fut.done():
                self._mark_served(team)
                fut.set_result(child)
                return
        self._idle.append(child)

    # ------------------------------------------------------------------ per-team admission
    @contextlib.contextmanager
    def admit(self, team: str):
        """Count one upload of ``team`` in flight for the ``with`` block; :class:`UploadsBusy` at the limit."""
        n = self._in_flight.get(team, 0)
        if n >= self.per_team:
            raise UploadsBusy(team, self.per_team)
        self._in_flight[team] = n + 1
        try:
            yield
        finally:
            left = self._in_flight.get(team, 1) - 1
            if left > 0:
                self._in_flight[team] = left
            else:
                self._in_flight.pop(team, None)

    def in_flight(self, team: str) -> int:
        return self._in_flight.get(team, 0)

    # ------------------------------------------------------------------ running
    async def run(self, *args, team: str = "default",
                  disconnected: Callable[[], Awaitable[bool]] | None = None) -> dict:
        """Parse one upload (``ingest_upload(*args)``) in a child; its result, or an error dict.

        Waits for a free child in the fair order; gives up (and kills the parse) when ``disconnected()``
        becomes true or the parse passes ``timeout_s``.
        """
        acquire = asyncio.ensure_future(self._acquire(team))
        try:
            while True:
                done, _ = await asyncio.wait({acquire}, timeout=DISCONNECT_POLL_S)
                if done:
                    break
                if disconnected is not None and await disconnected():
                    acquire.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await acquire
                    return _gone()
        except asyncio.CancelledError:
            acquire.cancel()
            raise
        child = acquire.result()
        return await self._run_on(child, args, disconnected)

    async def _run_on(self, child: _Child, args, disconnected) -> dict:
        loop = asyncio.get_running_loop()
        ready = loop.create_future()
        fd = child.conn.fileno()
        loop.add_reader(fd, lambda: ready.done() or ready.set_result(None))
        outcome = "crash"
        try:
            try:
                child.conn.send((INGEST_FUNCTION, args))
            except (BrokenPipeError, OSError):
                outcome = "crash"
                return _crashed()
            deadline = time.monotonic() + self.timeout_s
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    outcome = "timeout"
                    return {"error": {"status": 422, "code": "ingest_timeout", "message": (
                        f"reading the file took longer than {self.timeout_s:g} s (KILN_INGEST_TIMEOUT_S); "
                        "it was stopped")}}
                done, _ = await asyncio.wait({ready}, timeout=min(DISCONNECT_POLL_S, left))
                if done:
                    break
                if disconnected is not None and await disconnected():
                    outcome = "disconnect"
                    return _gone()
            try:
                out = child.conn.recv()
            except (EOFError, OSError):
                outcome = "crash"
                return _crashed()
            outcome = "ok"
            return out
        except asyncio.CancelledError:
            outcome = "disconnect"
            raise
        finally:
            with contextlib.suppress(Exception):
                loop.remove_reader(fd)
            if outcome == "ok":
                child.tasks += 1
                if child.tasks >= self._tasks:
                    child.stop()
                    child = self._replace_stopped(child)
            else:
                self.killed[outcome] = self.killed.get(outcome, 0) + 1
                if outcome != "crash" or child.proc.is_alive():
                    log.warning("ingest: killing parser %d (%s)", child.proc.pid or -1, outcome)
                child = self._replace(child)
            self._release(child)

    def _replace_stopped(self, child: _Child) -> _Child:
        new = _Child(self._ctx, self._tmp_root, child.index)
        self._children[self._children.index(child)] = new
        return new

    def shutdown(self) -> None:
        self._closed = True
        for q in self._waiting.values():
            for fut in q:
                if not fut.done():
                    fut.cancel()
        self._waiting.clear()
        for c in self._children:
            c.stop()
        self._children, self._idle = [], []

    @property
    def pids(self) -> list[int]:
        return [c.proc.pid for c in self._children if c.proc.pid]


def _crashed() -> dict:
    return {"error": {"status": 422, "code": "invalid_gltf",
                      "message": "the file crashed the glTF parser (out of memory or a malformed buffer)"}}


def _gone() -> dict:
    return {"error": {"status": 499, "code": "client_disconnected", "message": "the client went away"}}
