"""Hostile-load benchmark (issue 15): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_load.py [--teams 3] [--bakes-per-team 4] [--clients 50] [--out FILE]

Runs the service as ``kiln serve`` lays it out, but with each piece in the benchmark's hands: an embedded Redis,
two ``kiln worker`` processes (one on the short queue only, one on both; restarted when they die) and ``kiln api``
(uvicorn) on a free loopback port, with API keys for several teams. Then, at once:

1. **chaos**: the teams upload scenes and start bakes (distinct seeds: nothing comes from the cache) while
   running work-horses are SIGKILLed (``--kills``) and Redis is killed and restarted in the middle;
   reported: bakes completed and lost (a bake is lost when it does not succeed by the deadline, or fails for
   the service's own reasons: ``internal``, ``worker_died``; must be 0);
2. **polling**: during those bakes, ``--clients`` clients each poll ``GET /v1/bakes/{id}`` of one of their
   team's bakes at 2 Hz on a keep-alive connection; reported: p50 / p99 / max latency (target p99 <= 50 ms);
3. **closed loop**: afterwards, the same clients send ``GET /v1/bakes/{id}`` back to back for ``--seconds``;
   reported: requests per second and latency.

Prints a table and writes the numbers as JSON (``--out``, default ``bench_load.json``).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from persist.catalog import Catalog  # noqa: E402
from server.supervisor import EmbeddedRedis, WorkerPool  # noqa: E402
from tests.serve_process import free_port  # noqa: E402

SCENES = ("cornell", "two-rooms", "sealed-box", "furnace")
CONFIG = {"place": {"counts": [6, 4, 6]}, "trace": {"rays_per_probe": 64},
          "visibility": {"samples_per_cell": 4, "slabs": 2}, "masks": {"sweeps": 50}}
LOST_CODES = ("internal", "worker_died")


async def poll_client(host: str, port: int, path: str, key: str, end: float, hz: float, times: list,
                      errors: list) -> None:
    """One client on one keep-alive connection: ``GET path`` every 1/hz s (open loop) until ``end``."""
    req = f"GET {path} HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {key}\r\n\r\n".encode()
    if hz > 0:
        await asyncio.sleep(random.random() / hz)      # spread the clients over the period
    r = w = None
    nxt = time.monotonic()
    while time.monotonic() < end:
        try:
            if w is None:
                r, w = await asyncio.open_connection(host, port)
            t = time.perf_counter()
            w.write(req)
            head = await r.readuntil(b"\r\n\r\n")
            lines = head.split(b"\r\n")
            n = next(int(x.split(b":")[1]) for x in lines if x.lower().startswith(b"content-length:"))
            await r.readexactly(n)
            times.append(time.perf_counter() - t)
            if lines[0].split()[1] != b"200":
                errors[0] += 1
        except (OSError, asyncio.IncompleteReadError, StopIteration):
            errors[0] += 1
            if w is not None:
                w.close()
            r = w = None
        if hz > 0:
            nxt += 1.0 / hz
            await asyncio.sleep(max(0.0, nxt - time.monotonic()))
    if w is not None:
        w.close()


def load(host: str, port: int, targets: list[tuple[str, str]], clients: int, seconds: float, hz: float):
    """``clients`` clients over ``targets`` ([(bake id, key)]): their latencies (s) and error count."""
    times: list[float] = []
    errors = [0]

    async def run():
        end = time.monotonic() + seconds
        await asyncio.gather(*(poll_client(host, port, f"/v1/bakes/{targets[i % len(targets)][0]}",
                                           targets[i % len(targets)][1], end, hz, times, errors)
                               for i in range(clients)))

    asyncio.run(run())
    return times, errors[0]


def stats(times: list[float], errors: int, seconds: float) -> dict:
    ms = np.array(times) * 1000 if times else np.zeros(1)
    return {"requests": len(times), "errors": errors, "rps": len(times) / seconds,
            "p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max())}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--teams", type=int, default=3)
    ap.add_argument("--bakes-per-team", type=int, default=4)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=10.0, help="of the closed-loop phase")
    ap.add_argument("--kills", type=int, default=3, help="work-horses SIGKILLed during the bakes")
    ap.add_argument("--deadline", type=float, default=600.0, help="seconds for every bake to finish")
    ap.add_argument("--out", default="bench_load.json")
    args = ap.parse_args()

    from workers.procedural import write_scene

    tmp = Path(tempfile.mkdtemp(prefix="kiln-bench-load-"))
    data = tmp / "data"
    data.mkdir(parents=True)
    teams = {f"team{i}": f"team{i}-key-{i:04d}xyz" for i in range(args.teams)}
    keys = ",".join(f"{t}:{k}" for t, k in teams.items())
    redis_srv = EmbeddedRedis(data)
    redis_srv.start()
    env = dict(os.environ, KILN_DATA=str(data), REDIS_URL=redis_srv.url, PYTHONUNBUFFERED="1", KILN_API_KEYS=keys,
               KILN_QUOTA_CONCURRENT_BAKES=str(args.bakes_per_team))
    pool = WorkerPool(2, env)
    pool.start()
    port = free_port()
    log = open(tmp / "api.log", "w")
    api = subprocess.Popen([sys.executable, "-m", "server.cli", "api", "--data", str(data), "--port", str(port)],
                           cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    results: dict = {"teams": args.teams, "bakes_per_team": args.bakes_per_team, "clients": args.clients}
    events: list[str] = []
    stop, finish = threading.Event(), threading.Event()
    chaos_t = None
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(url + "/healthz", timeout=2).json()["status"] == "ok":
                    break
            except (httpx.HTTPError, ValueError):
                pass
            if api.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("kiln api did not come up:\n" + (tmp / "api.log").read_text())
            time.sleep(0.2)
        for name in SCENES:
            write_scene(name, tmp / f"{name}.glb")
        catalog = Catalog(data / "kiln.db")

        # 1. teams upload and bake at once --------------------------------------------------------------
        bakes: list[tuple[str, str]] = []          # (bake id, key)
        upload_stats = {"ok": 0, "retried_429": 0, "failed": 0}
        lock = threading.Lock()

        def team_work(ti: int, team: str, key: str) -> None:
            c = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {key}"}, timeout=120)
            sids = []
            for j in range(2):
                name = SCENES[(ti + j) % len(SCENES)]
                while True:
                    r = c.post("/v1/scenes", content=(tmp / f"{name}.glb").read_bytes(),
                               headers={"X-Filename": f"{name}.glb"})
                    if r.status_code == 429:
                        with lock:
                            upload_stats["retried_429"] += 1
                        time.sleep(float(r.headers.get("retry-after", "1")))
                        continue
                    break
                with lock:
                    upload_stats["ok" if r.status_code in (200, 201) else "failed"] += 1
                if r.status_code in (200, 201):
                    sids.append(r.json()["id"])
            for b in range(args.bakes_per_team):
                cfg = {**CONFIG, "seed": 1000 * ti + b}
                while True:
                    r = c.post("/v1/bakes", json={"scene_id": sids[b % len(sids)], "config": cfg})
                    if r.status_code == 429:
                        time.sleep(min(5.0, float(r.headers.get("retry-after", "1"))))
                        continue
                    break
                if r.status_code == 202:
                    with lock:
                        bakes.append((r.json()["id"], key))
                else:
                    events.append(f"{team}: bake refused {r.status_code} {r.text[:200]}")

        t_start = time.monotonic()
        feeders = [threading.Thread(target=team_work, args=(i, t, k), daemon=True)
                   for i, (t, k) in enumerate(teams.items())]
        for f in feeders:
            f.start()

        # 2. chaos while they bake: SIGKILL work-horses, restart Redis in the middle ------------------------
        chaos = {"horses_killed": 0, "redis_restarts": 0}

        def running_horse() -> int | None:
            for bid, _ in list(bakes):
                b = catalog.get_bake(bid)
                for s in (b or {}).get("stages", []):
                    if s["status"] == "running" and s["pid"] and s["pid"] not in pool.pids:
                        return s["pid"]
            return None

        def chaos_loop() -> None:
            try:
                chaos_steps()
            finally:
                # Redis, restarted from this thread, has PR_SET_PDEATHSIG: it dies when this thread ends
                finish.wait()

        def chaos_steps() -> None:
            plan = ["kill"] * args.kills
            plan.insert(len(plan) // 2 + (len(plan) % 2), "redis")
            time.sleep(3.0)
            for step in plan:
                if stop.wait(4.0):
                    return
                if step == "redis":
                    redis_srv.proc.send_signal(signal.SIGKILL)
                    redis_srv.proc.wait(10)
                    time.sleep(0.5)
                    redis_srv.start()
                    chaos["redis_restarts"] += 1
                    events.append(f"{time.monotonic() - t_start:6.1f}s redis killed and restarted")
                    continue
                for _ in range(50):
                    pid = running_horse()
                    if pid:
                        try:
                            os.kill(pid, signal.SIGKILL)
                            chaos["horses_killed"] += 1
                            events.append(f"{time.monotonic() - t_start:6.1f}s work-horse {pid} SIGKILLed")
                        except ProcessLookupError:
                            continue
                        break
                    time.sleep(0.1)

        chaos_t = threading.Thread(target=chaos_loop, daemon=True)
        chaos_t.start()

        # 3. 50 clients polling at 2 Hz while the bakes run ------------------------------------------------
        while len(bakes) < args.teams and time.monotonic() - t_start < 60:
            time.sleep(0.1)
        host = "127.0.0.1"
        poll_times: list[float] = []
        poll_errors = 0
        poll_seconds = 0.0
        while True:
            active = [b for b in list(bakes) if (catalog.get_bake(b[0]) or {}).get("status") in ("queued", "running")]
            if not active and all(not f.is_alive() for f in feeders):
                break
            if time.monotonic() - t_start > args.deadline:
                break
            t, e = load(host, port, active or list(bakes), args.clients, 5.0, hz=2.0)
            poll_times += t
            poll_errors += e
            poll_seconds += 5.0
        stop.set()
        for f in feeders:
            f.join(30)
        # every bake to a final state
        end = t_start + args.deadline
        while time.monotonic() < end:
            if all((catalog.get_bake(b) or {}).get("status") in ("succeeded", "failed", "cancelled") for b, _ in bakes):
                break
            time.sleep(0.5)
        wall = time.monotonic() - t_start
        outcome = {"succeeded": 0, "failed": 0, "cancelled": 0, "unfinished": 0}
        lost, failed_codes = 0, {}
        for bid, _ in bakes:
            b = catalog.get_bake(bid)
            st = b["status"] if b else "missing"
            if st in outcome:
                outcome[st] += 1
            else:
                outcome["unfinished"] += 1
            if st not in ("succeeded",):
                code = (b or {}).get("error", {}) or {}
                failed_codes[code.get("code", st)] = failed_codes.get(code.get("code", st), 0) + 1
                if st not in ("failed", "cancelled") or code.get("code") in LOST_CODES:
                    lost += 1
        results["chaos"] = {**chaos, "bakes": len(bakes), "completed": outcome["succeeded"], "lost": lost,
                            "outcome": outcome, "failure_codes": failed_codes, "uploads": upload_stats,
                            "wall_seconds": wall}
        results["polling_2hz"] = {"clients": args.clients, "seconds": poll_seconds,
                                  **stats(poll_times, poll_errors, max(poll_seconds, 1e-9))}

        # 4. closed loop, 50 clients ------------------------------------------------------------------
        load(host, port, bakes, args.clients, 1.0, hz=0)        # warm-up, not counted
        t, e = load(host, port, bakes, args.clients, args.seconds, hz=0)
        results["closed_loop"] = {"clients": args.clients, "seconds": args.seconds, **stats(t, e, args.seconds)}
    finally:
        stop.set()
        api.send_signal(signal.SIGINT)
        try:
            api.wait(30)
        except subprocess.TimeoutExpired:
            api.kill()
        pool.stop()
        redis_srv.stop()
        finish.set()
        if chaos_t is not None:
            chaos_t.join(10)
        log.close()

    c, p, cl = results["chaos"], results["polling_2hz"], results["closed_loop"]
    print("\n".join(events))
    print(f"{'measure':58s} {'value':>12s}")
    rows = [
        ("teams x bakes started", f"{args.teams} x {args.bakes_per_team} = {c['bakes']}"),
        ("uploads ok / 429 retried / failed", f"{c['uploads']['ok']}/{c['uploads']['retried_429']}/"
                                              f"{c['uploads']['failed']}"),
        ("work-horses SIGKILLed / Redis restarts", f"{c['horses_killed']}/{c['redis_restarts']}"),
        ("bakes completed", c["completed"]),
        ("bakes lost (must be 0)", c["lost"]),
        ("bakes failed (codes)", json.dumps(c["failure_codes"]) if c["failure_codes"] else "0"),
        ("wall seconds, first upload to last bake", f"{c['wall_seconds']:.1f}"),
        (f"GET /v1/bakes/id, {p['clients']} clients at 2 Hz, requests", p["requests"]),
        ("  p50 (ms)", f"{p['p50_ms']:.1f}"),
        ("  p99 (ms) (target <= 50)", f"{p['p99_ms']:.1f}"),
        ("  max (ms)", f"{p['max_ms']:.1f}"),
        ("  errors", p["errors"]),
        (f"closed loop, {cl['clients']} clients: requests/s", f"{cl['rps']:.1f}"),
        ("  p50 / p99 (ms)", f"{cl['p50_ms']:.1f} / {cl['p99_ms']:.1f}"),
        ("  errors", cl["errors"]),
    ]
    for k, v in rows:
        print(f"{k:58s} {str(v):>12s}")
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"(JSON written to {args.out})")
    print(json.dumps(results))
    return 0 if c["lost"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
