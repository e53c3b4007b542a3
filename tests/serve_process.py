"""A real `kiln serve` in a subprocess (embedded Redis, workers, uvicorn) on a free loopback port.

Shared by the CLI test, the browser tests and the service benchmark.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def spawn_serve(data: Path, *, workers: int = 2, api_keys: str | None = None, log: Path | None = None,
                timeout: float = 60.0) -> tuple[subprocess.Popen, str]:
    """Start `kiln serve --data DATA` and wait until /healthz says ok; returns (process, base URL).

    Output goes to ``log`` (or nowhere). On failure the process is killed and RuntimeError carries the log.
    """
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("REDIS_URL", None)
    env.pop("KILN_API_KEYS", None)
    if api_keys:
        env["KILN_API_KEYS"] = api_keys
    port = free_port()
    out = open(log, "w") if log else subprocess.DEVNULL
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "serve", "--port", str(port), "--workers",
                             str(workers), "--data", str(data)], cwd=ROOT, env=env, stdout=out,
                            stderr=subprocess.STDOUT)
    if log:
        out.close()  # the child holds its own descriptor
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + timeout
    while True:
        try:
            if httpx.get(url + "/healthz", timeout=2).json()["status"] == "ok":
                return proc, url
        except (httpx.HTTPError, ValueError):
            pass
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            proc.wait(10)
            text = log.read_text() if log and log.exists() else "(no log)"
            raise RuntimeError(f"kiln serve did not come up (exit {proc.returncode}):\n{text}")
        time.sleep(0.2)


def stop_serve(proc: subprocess.Popen, timeout: float = 30.0, *, strict: bool = False) -> None:
    """Stop ``kiln serve`` as a person at its terminal does: Ctrl-C (SIGINT), then up to ``timeout`` s for it to
    stop its workers and Redis and exit. One still running then is killed; with ``strict`` the TimeoutExpired is
    raised after the kill (for a test of Ctrl-C itself)."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)
        if strict:
            raise
