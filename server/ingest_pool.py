"""Uploads are parsed in child processes, so a huge or hostile file cannot grow or crash the API.

The API streams the upload to disk; a child runs :func:`workers.jobs.ingest_upload` (by
name) on that file and stores the normalized scene; the API only sees a small summary.
"""
from __future__ import annotations

import asyncio
import importlib
import multiprocessing as mp
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

INGEST_FUNCTION = "workers.jobs:ingest_upload"


def _call(target: str, *args):
    mod, _, fn = target.partition(":")
    return getattr(importlib.import_module(mod), fn)(*args)


class IngestPool:
    def __init__(self, processes: int = 2, tasks_per_child: int = 16):
        self._n, self._tasks = processes, tasks_per_child
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None

    def _get(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(self._n, mp_context=mp.get_context("spawn"),
                                                 max_tasks_per_child=self._tasks)
            return self._pool

    def _reset(self) -> None:
        with self._lock:
            if self._pool is not None:
                self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    async def run(self, *args) -> dict:
        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(self._get(), _call, INGEST_FUNCTION, *args)
        except BrokenProcessPool:
            self._reset()
            return {"error": {"status": 422, "code": "invalid_gltf",
                              "message": "the file crashed the glTF parser (out of memory or a malformed buffer)"}}

    def shutdown(self) -> None:
        with self._lock:
            if self._pool is not None:
                self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
