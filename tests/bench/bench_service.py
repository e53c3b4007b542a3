"""Service benchmark (Foundation issue): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_service.py [--upload-mb 100] [--clients 50] [--seconds 10]

Starts a real ``kiln serve`` (embedded Redis, 2 workers) on a free port and measures:

1. upload of a ~100 MB GLB: peak RSS of the server process (sampled every 10 ms) against its RSS
   before the upload, next to the file size; and the peak RSS of the ingest child process;
2. time from ``POST /v1/bakes`` to a worker starting the first stage (catalog timestamps), idle workers;
3. latency of ``GET /v1/bakes/{id}`` with N concurrent clients while bakes run (workers busy with
   real ingest + place stages of zdm2-sauerbraten, or the two-rooms scene when ../shared is absent).

Prints a table and the same numbers as JSON on the last line.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import signal
import statistics
import struct
import subprocess
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

from proto.catalog import Catalog  # noqa: E402
from tests.serve_process import spawn_serve  # noqa: E402


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


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--upload-mb", type=float, default=100)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=10)
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

        def feeder():
            i = 0
            while not stop.is_set():
                # a sky no bake had before: every stage really runs (no cache hit)
                bid = client.post("/v1/bakes", json={"scene_id": sid, "config": {
                    "scene": {"sky": [0.5, 1e-4 * (i + 1), 0]}, "place": {"counts": [32, 16, 32]}}}).json()["id"]
                i += 1
                while not stop.is_set() and catalog.get_bake(bid)["status"] in ("queued", "running"):
                    time.sleep(0.05)
                baked[0] += 1

        feed = threading.Thread(target=feeder, daemon=True)
        feed.start()
        time.sleep(0.5)
        target = client.post("/v1/bakes", json={"scene_id": sid, "config": {"seed": 99}}).json()["id"]

        async def load():
            times: list[float] = []
            errors = [0]
            end = time.monotonic() + args.seconds
            async with httpx.AsyncClient(base_url=url, timeout=30,
                                         limits=httpx.Limits(max_connections=args.clients)) as ac:
                async def one():
                    while time.monotonic() < end:
                        t = time.perf_counter()
                        r = await ac.get(f"/v1/bakes/{target}")
                        times.append(time.perf_counter() - t)
                        if r.status_code != 200:
                            errors[0] += 1
                await asyncio.gather(*(one() for _ in range(args.clients)))
            return times, errors[0]

        times, errors = asyncio.run(load())
        stop.set()
        feed.join(10)
        ms = np.array(times) * 1000
        results["get_bake_latency"] = {
            "clients": args.clients, "requests": len(times), "errors": errors, "rps": len(times) / args.seconds,
            "p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max()), "bakes_during": baked[0],
        }
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()

    u, e, g = results["upload"], results["enqueue_to_start"], results["get_bake_latency"]
    print(f"{'measure':48s} {'value':>14s}")
    print(f"{'upload: file size (MB)':48s} {u['file_mb']:14.1f}")
    print(f"{'upload: seconds (stream + ingest + store)':48s} {u['seconds']:14.2f}")
    print(f"{'upload: server RSS before / peak (MB)':48s} {u['server_rss_before_mb']:7.1f}/{u['server_rss_peak_mb']:6.1f}")
    print(f"{'upload: server RSS growth (MB)':48s} {u['server_rss_growth_mb']:14.1f}")
    print(f"{'upload: growth / file size':48s} {u['growth_over_file_size']:14.3f}")
    print(f"{'upload: ingest child peak RSS (MB)':48s} {u['ingest_child_peak_mb']:14.1f}")
    print(f"{'POST /v1/bakes -> first stage starts, median (s)':48s} {e['median_s']:14.3f}")
    print(f"{'POST /v1/bakes -> first stage starts, max (s)':48s} {e['max_s']:14.3f}")
    print(f"{'GET /v1/bakes/id, clients':48s} {g['clients']:14d}")
    print(f"{'GET /v1/bakes/id, requests/s':48s} {g['rps']:14.1f}")
    print(f"{'GET /v1/bakes/id, p50 (ms)':48s} {g['p50_ms']:14.1f}")
    print(f"{'GET /v1/bakes/id, p99 (ms)':48s} {g['p99_ms']:14.1f}")
    print(f"{'GET /v1/bakes/id, errors':48s} {g['errors']:14d}")
    print(f"{'bakes completed during the load':48s} {g['bakes_during']:14d}")
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
