"""Service benchmark (Foundation issue): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_service.py [--upload-mb 100] [--clients 50] [--seconds 10]

Starts a real ``kiln serve`` (embedded Redis, 2 workers) on a free port and measures:

1. upload of a ~100 MB GLB: peak RSS of the server process (sampled every 10 ms) against its RSS
   before the upload, next to the file size; and the peak RSS of the ingest child process;
2. time from ``POST /v1/bakes`` to a worker starting the first stage (catalog timestamps), idle workers;
3. latency of ``GET /v1/bakes/{id}`` with N concurrent clients while bakes run (workers busy with
   real ingest + place stages of zdm2-sauerbraten, or the two-rooms scene when ../shared is absent),
   side by side in alternating phases: the workers at their default niceness (``KILN_WORKER_NICE``,
   10) and reniced to 0 (needs root; skipped otherwise).

Prints a table and the same numbers as JSON on the last line.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from persist.catalog import Catalog  # noqa: E402
from tests.serve_process import spawn_serve, stop_serve  # noqa: E402


def big_glb(path: Path, target_mb: float) -> int:
    """A valid GLB of about ``target_mb`` MB: a grid of unindexed triangles (positions + normals)."""
    n_tri = int(target_mb * 2**20 / 72)
    rng = np.random.default_rng(0)
    base = rng.uniform(0, 100, (n_tri, 1, 3)).astype(np.float32)
    tri = base + np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], np.float32)
    pos = tri.reshape(-1, 3)
    nrm = np.tile(np.array([0, 0, 1], np.float32), (pos.shape[0], 1))
    binary = pos.tobytes() + nrm.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}}]}],
        "buffers": [{"byteLength": len(binary)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": nrm.nbytes}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": pos.shape[0], "type": "VEC3",
             "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
            {"bufferView": 1, "componentType": 5126, "count": nrm.shape[0], "type": "VEC3"},
        ],
    }
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    with open(path, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<I4s", len(js), b"JSON") + js)
        f.write(struct.pack("<I4s", len(binary), b"BIN\x00") + binary)
    return total


class Sampler(threading.Thread):
    """Peak RSS of a process (and, separately, of its Python children other than workers/redis)."""

    def __init__(self, pid: int, skip: set[int]):
        super().__init__(daemon=True)
        self.p = psutil.Process(pid)
        self.skip = skip
        self.peak = 0
        self.child_peak = 0
        self.stop = threading.Event()

    def run(self):
        while not self.stop.is_set():
            try:
                self.peak = max(self.peak, self.p.memory_info().rss)
                for c in self.p.children(recursive=True):
                    if c.pid not in self.skip:
                        try:
                            self.child_peak = max(self.child_peak, c.memory_info().rss)
                        except psutil.Error:
                            pass
            except psutil.Error:
                pass
            time.sleep(0.01)


async def keep_alive_client(host: str, port: int, path: str, end: float, times: list, errors: list) -> None:
    """One client on one keep-alive HTTP/1.1 connection: GET ``path`` until ``end``, appending latencies (s).

    A lean client on purpose: on 2 shared cores, httpx's AsyncClient was the bottleneck (50 clients: 143 req/s
    and p99 1.45 s against an idle server that serves 461 req/s at p99 196 ms to this one).
    """
    r, w = await asyncio.open_connection(host, port)
    req = f"GET {path} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()
    try:
        while time.monotonic() < end:
            t = time.perf_counter()
            w.write(req)
            head = await r.readuntil(b"\r\n\r\n")
            lines = head.split(b"\r\n")
            n = next(int(x.split(b":")[1]) for x in lines if x.lower().startswith(b"content-length:"))
            await r.readexactly(n)
            times.append(time.perf_counter() - t)
            if lines[0].split()[1] != b"200":
                errors[0] += 1
    finally:
        w.close()


def worker_cpu(server_pid: int) -> float:
    """CPU seconds (user + system) used so far by the server's workers and their live work-horses."""
    total = 0.0
    for c in psutil.Process(server_pid).children():
        try:
            if "server.cli worker" in " ".join(c.cmdline()):
                t = c.cpu_times()   # children_*: work-horses already reaped
                total += t.user + t.system + t.children_user + t.children_system
                for p in c.children(recursive=True):
                    t = p.cpu_times()
                    total += t.user + t.system
        except psutil.NoSuchProcess:
            pass
    return total


def renice_workers(server_pid: int, nice: int) -> bool:
    """Set the niceness of the server's workers and their work-horses; False where not permitted (not root)."""
    try:
        for c in psutil.Process(server_pid).children():
            if "server.cli worker" in " ".join(c.cmdline()):
                for p in [c, *c.children(recursive=True)]:
                    p.nice(nice)
        return True
    except psutil.AccessDenied:
        print(f"(cannot renice the workers to {nice} without privileges: that phase is skipped)", file=sys.stderr)
        return False
    except psutil.NoSuchProcess:   # a work-horse exited meanwhile; new ones inherit the worker's niceness
        return True


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--upload-mb", type=float, default=100)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=20, help="of GET load, split over the two niceness phases")
    ap.add_argument("--rounds", type=int, default=2, help="alternations of the two niceness phases")
    ap.add_argument("--enqueue-runs", type=int, default=10)
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="kiln-bench-"))
    proc, url = spawn_serve(tmp / "data", workers=2)
    results: dict = {}
    try:
        service_children = {c.pid for c in psutil.Process(proc.pid).children(recursive=True)}
        client = httpx.Client(base_url=url, timeout=600)

        # 1. big upload ---------------------------------------------------------------------
        glb = tmp / "big.glb"
        size = big_glb(glb, args.upload_mb)
        # warm the ingest pool with a small upload first, so its start-up is not counted as growth
        small = tmp / "small.glb"
        big_glb(small, 0.01)
        client.post("/v1/scenes", content=small.read_bytes())
        time.sleep(0.5)
        rss0 = psutil.Process(proc.pid).memory_info().rss
        sampler = Sampler(proc.pid, service_children)
        sampler.start()
        t0 = time.perf_counter()
        with open(glb, "rb") as f:
            r = client.post("/v1/scenes", content=f, headers={"X-Filename": "big.glb"})
        upload_s = time.perf_counter() - t0
        time.sleep(0.2)
        sampler.stop.set()
        sampler.join()
        assert r.status_code in (200, 201), r.text
        results["upload"] = {
            "file_mb": size / 2**20, "seconds": upload_s, "triangles": r.json()["triangles"],
            "server_rss_before_mb": rss0 / 2**20, "server_rss_peak_mb": sampler.peak / 2**20,
            "server_rss_growth_mb": (sampler.peak - rss0) / 2**20,
            "growth_over_file_size": (sampler.peak - rss0) / size,
            "ingest_child_peak_mb": sampler.child_peak / 2**20,
        }

        # 2. POST -> first stage started ------------------------------------------------------
        scene = ROOT.parent / "shared" / "scenes" / "zdm2-sauerbraten" / "zdm2.glb"
        if not scene.exists():
            from workers.procedural import write_scene
            scene = tmp / "two-rooms.glb"
            write_scene("two-rooms", scene)
        sid = client.post("/v1/scenes", content=scene.read_bytes(), headers={"X-Filename": scene.name}).json()["id"]
        catalog = Catalog(tmp / "data" / "kiln.db")
        lat = []
        for i in range(args.enqueue_runs):
            bid = client.post("/v1/bakes", json={"scene_id": sid, "config": {"scene": {"sky": [1e-4 * (i + 1), 0, 0]}}}).json()["id"]
            while True:
                b = catalog.get_bake(bid)
                if b["status"] in ("succeeded", "failed"):
                    break
                time.sleep(0.01)
            assert not b["stages"][0]["cached"]
            lat.append(b["stages"][0]["started"] - b["created"])
        results["enqueue_to_start"] = {"runs": len(lat), "median_s": statistics.median(lat), "max_s": max(lat)}

        # 3. GET latency under 50 concurrent clients while bakes run ---------------------------
        stop = threading.Event()
        baked = [0]

        def feeder(k: int):
            i = 0
            while not stop.is_set():
                # a sky no bake had before: every stage really runs (no cache hit)
                bid = client.post("/v1/bakes", json={"scene_id": sid, "config": {
                    "scene": {"sky": [0.5, 1e-4 * (i + 1), 1e-4 * k]}, "place": {"counts": [32, 16, 32]}}}).json()["id"]
                i += 1
                while not stop.is_set() and catalog.get_bake(bid)["status"] in ("queued", "running"):
                    time.sleep(0.05)
                baked[0] += 1

        feeds = [threading.Thread(target=feeder, args=(k,), daemon=True) for k in range(2)]   # both workers busy
        for feed in feeds:
            feed.start()
        time.sleep(0.5)
        target = client.post("/v1/bakes", json={"scene_id": sid, "config": {"seed": 99}}).json()["id"]

        host, port = url.split("//")[1].split(":")

        async def load(seconds: float):
            times: list[float] = []
            errors = [0]
            end = time.monotonic() + seconds
            await asyncio.gather(*(keep_alive_client(host, int(port), f"/v1/bakes/{target}", end, times, errors)
                                   for _ in range(args.clients)))
            return times, errors[0]

        # side by side, alternating: the workers at their default niceness, then reniced to 0
        worker_nice = {c.pid: c.nice() for c in psutil.Process(proc.pid).children()
                       if "server.cli worker" in " ".join(c.cmdline())}
        default_nice = max(worker_nice.values())
        phases = {default_nice: ([], [0]), 0: ([], [0])}
        worker_cores: dict[int, list[float]] = {n: [] for n in phases}
        asyncio.run(load(1.0))   # warm-up (connections, first requests), not counted
        for _ in range(args.rounds):
            for n in phases:
                if not renice_workers(proc.pid, n):
                    continue
                cpu0 = worker_cpu(proc.pid)
                t, e = asyncio.run(load(args.seconds / (2 * args.rounds)))
                worker_cores[n].append((worker_cpu(proc.pid) - cpu0) / (args.seconds / (2 * args.rounds)))
                phases[n][0].extend(t)
                phases[n][1][0] += e
        renice_workers(proc.pid, default_nice)
        stop.set()
        for feed in feeds:
            feed.join(10)
        for n, (times, errors) in phases.items():
            if not times:
                continue
            ms = np.array(times) * 1000
            results[f"get_bake_latency_nice{n}"] = {
                "clients": args.clients, "worker_nice": n, "requests": len(times), "errors": errors[0],
                "rps": len(times) / (args.seconds / 2), "p50_ms": float(np.percentile(ms, 50)),
                "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max()), "bakes_during": baked[0],
                "worker_cores": float(np.mean(worker_cores[n])),
            }
        results["get_bake_latency"] = results[f"get_bake_latency_nice{default_nice}"]
    finally:
        stop_serve(proc)

    u, e = results["upload"], results["enqueue_to_start"]
    print(f"{'measure':48s} {'value':>14s}")
    print(f"{'upload: file size (MB)':48s} {u['file_mb']:14.1f}")
    print(f"{'upload: seconds (stream + ingest + store)':48s} {u['seconds']:14.2f}")
    print(f"{'upload: server RSS before / peak (MB)':48s} {u['server_rss_before_mb']:7.1f}/{u['server_rss_peak_mb']:6.1f}")
    print(f"{'upload: server RSS growth (MB)':48s} {u['server_rss_growth_mb']:14.1f}")
    print(f"{'upload: growth / file size':48s} {u['growth_over_file_size']:14.3f}")
    print(f"{'upload: ingest child peak RSS (MB)':48s} {u['ingest_child_peak_mb']:14.1f}")
    print(f"{'POST /v1/bakes -> first stage starts, median (s)':48s} {e['median_s']:14.3f}")
    print(f"{'POST /v1/bakes -> first stage starts, max (s)':48s} {e['max_s']:14.3f}")
    for key in sorted(k for k in results if k.startswith("get_bake_latency_nice")):
        g = results[key]
        tag = f"GET /v1/bakes/id, workers at nice {g['worker_nice']}"
        print(f"{tag + ', clients':48s} {g['clients']:14d}")
        print(f"{tag + ', requests/s':48s} {g['rps']:14.1f}")
        print(f"{tag + ', p50 (ms)':48s} {g['p50_ms']:14.1f}")
        print(f"{tag + ', p99 (ms)':48s} {g['p99_ms']:14.1f}")
        print(f"{tag + ', errors':48s} {g['errors']:14d}")
        print(f"{tag + ', CPU cores the bakes used':48s} {g['worker_cores']:14.2f}")
    print(f"{'bakes completed during the load':48s} {results['get_bake_latency']['bakes_during']:14d}")
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
