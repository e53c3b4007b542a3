"""Probe-bake benchmark (Probe bake issue): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_probes.py [--grids 16x8x16,32x16x32] [--rays 256] [--samples 8]

On ../shared/scenes/zdm2-sauerbraten (58k triangles; it has no lights, so a sun and a sky are added)
runs relocate, trace, light (3 bounces) and visibility (θ, S samples per cell) in this process with
the real pipeline, timing each stage (wall clock), and next to each stage times raw embreex (2 threads,
no validation, nothing but ``EmbreeScene.run``) on the same rays in the same run:

- relocate: the final probe rays, once per relocation iteration (the iterations trace the same
  pattern from nearly the same origins);
- trace: the final probe rays;
- light: the shadow rays toward the sun from the front-face hits, plus the cage-visibility rays from
  each hit to its 8 probes (raw: timed on the shadow rays; its other work is shading);
- visibility: the θ rays (sample -> each corner probe).

"stage Mray/s" divides the rays by the stage's whole wall time (BVH build, shading, depth moments,
writing and hashing artifacts included); "in-caster" by the time spent inside the ray caster only.
Prints a table and the same numbers as JSON on the last line. Numba kernels are compiled (or loaded
from cache) by a small warm-up bake first, outside the timings.

``--bundles 16x8x16,32x16x32,64x32x64`` (the default; ``--bundles ''`` skips it) also bakes each grid whole, the
default config (automatic θ samples, masks, compress; evaluate off: its reference is per scene, not per grid) with
the same sun and sky, each bake in a child process of its own after a warm-up bake there, and prints

- the bundle: bytes per probe of each GI mode (the artifacts the mode's textures bind, ``proto/gi_modes.json``, at
  the bake's SH order) and of the whole bundle (every artifact of the manifest, the scene GLB included, and
  without it), and the whole bundle in MB (target at 64x32x64: <= 60 MB);
- the bake: per stage its wall seconds and CPU seconds (user + sys of the process and its children, all
  threads), the total, and the peak RSS (``ru_maxrss`` of the bake's process and of its children). On a
  shared machine wall time depends on the load; CPU time much less.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from proto.gi_modes import MODE_IDS, MODES, expand, cluster_count, texture_bindings  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import build_manifest, plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.kernels.visibility import field_shape, sample_positions  # noqa: E402
from workers.stages.trace import probe_rays_of  # noqa: E402

SCENE = ROOT.parent / "shared" / "scenes" / "zdm2-sauerbraten" / "zdm2.glb"
SUN = {"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0, "color": [1.0, 0.95, 0.9]}
CHUNK = 65536


class RawEmbree:
    """embreex with nothing around it: chunks over 2 threads, ``run`` only."""

    def __init__(self, triangles: np.ndarray, threads: int = 2):
        from embreex import rtcore as rtc, rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcs.EmbreeScene(rtc.EmbreeDevice())
        TriangleMesh(self.scene, np.ascontiguousarray(triangles, np.float32))
        self.scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # build the BVH
        self.pool = ThreadPoolExecutor(threads)

    def rays_per_second(self, origins: np.ndarray, dirs: np.ndarray, occluded: bool = False,
                        tfar: np.ndarray | None = None, repeat: int = 1) -> float:
        o = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(dirs, np.float32)
        n = o.shape[0]
        far = np.ascontiguousarray(tfar if tfar is not None else np.full(n, 1e30), np.float32)
        query = "OCCLUDED" if occluded else "INTERSECT"

        def work(s):
            e = min(s + CHUNK, n)
            self.scene.run(o[s:e], d[s:e], dists=far[s:e].copy(), query=query, output=0 if occluded else 1)

        t0 = time.perf_counter()
        for _ in range(repeat):
            list(self.pool.map(work, range(0, n, CHUNK)))
        return n * repeat / (time.perf_counter() - t0)


def run_grid(scene, counts, rays, S, raw: RawEmbree) -> dict:
    cfg = BakeConfig.model_validate({
        "place": {"counts": counts}, "scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]},
        "trace": {"rays_per_probe": rays}, "light": {"bounces": 3},
        "visibility": {"samples_per_cell": S, "slabs": 1},
    })
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(tmp)
        sid = store.put_bytes(scene.to_bytes())
        times, recs = {}, {}
        for st, _ in plan(sid, cfg):
            t0 = time.perf_counter()
            rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
            times[st.name] = time.perf_counter() - t0
            recs[st.name] = pipeline._lazy(store, rec)
        tr = recs["trace"]
        P = int(np.prod(counts))
        pos = recs["relocate"]["probe_positions_relocated"].reshape(-1, 3)
        dirs = probe_rays_of(tr)
        o = np.repeat(pos, rays, axis=0)
        d = dirs.of_probes(0, P).reshape(-1, 3)
        out = {"probes": P, "rays_per_probe": rays, "stages": {}}
        raw_trace = raw.rays_per_second(o, d)
        n_rel = recs["relocate"].stats["rays"]
        out["stages"]["relocate"] = {"seconds": times["relocate"], "rays": n_rel, "raw_rays_per_s": raw_trace,
                                     "ray_seconds": recs["relocate"].stats["ray_seconds"]}
        out["stages"]["trace"] = {"seconds": times["trace"], "rays": tr.stats["rays"], "raw_rays_per_s": raw_trace,
                                  "ray_seconds": tr.stats["ray_seconds"]}
        # light: shadow rays toward the sun from the front-face hits
        from workers.kernels.probe_hits import hit_surfaces
        surf = hit_surfaces(scene, dirs, tr["ray_hits"], tr["ray_tri"])
        sun = -np.asarray(SUN["direction"], np.float64)
        sun /= np.linalg.norm(sun)
        lit = (surf.normal @ sun) > 0
        so = surf.position[lit] + 1e-3 * surf.normal[lit]
        sd = np.broadcast_to(sun.astype(np.float32), so.shape)
        raw_shadow = raw.rays_per_second(so, sd, occluded=True) if len(so) else float("nan")
        st = recs["light"].stats
        # the light stage's rays: shadow rays + the cage-visibility rays (both occlusion queries)
        out["stages"]["light"] = {"seconds": times["light"], "rays": int(lit.sum()) + st["visibility_rays"],
                                  "raw_rays_per_s": raw_shadow,
                                  "ray_seconds": st["visibility_seconds"] + st["direct_seconds"],
                                  "direct_seconds": st["direct_seconds"], "bounce_seconds": st["bounce_seconds"],
                                  "bounces": st["bounces"], "front_hits": st["front_hits"]}
        # visibility: sample -> corner-probe rays
        place = recs["place"].stats
        Z, Y, X = field_shape(counts, S)
        samples = sample_positions(counts, place["origin"], place["spacing"], S, (0, Z))
        from workers.kernels.grid import cell_coords, cage_indices
        base, _ = cell_coords(samples, counts, place["origin"], place["spacing"])
        cage = cage_indices(base, counts)
        vo = np.repeat(samples.astype(np.float32), 8, axis=0)
        vt = pos[cage.ravel()]
        vd = vt - vo
        dist = np.linalg.norm(vd, axis=1)
        vd = vd / np.maximum(dist, 1e-12)[:, None]
        raw_vis = raw.rays_per_second(vo, vd, tfar=dist)
        vis_seconds = sum(v for k, v in times.items() if k.startswith("visibility"))
        out["stages"]["visibility"] = {"seconds": vis_seconds, "rays": int(vo.shape[0]), "raw_rays_per_s": raw_vis,
                                       "ray_seconds": sum(recs[k].stats.get("ray_seconds", 0.0) for k in recs
                                                          if k.startswith("visibility."))}
        for s in out["stages"].values():
            s["stage_rays_per_s"] = s["rays"] / s["seconds"] if s["seconds"] > 0 else float("nan")
            rs = s.get("ray_seconds")
            s["caster_rays_per_s"] = s["rays"] / rs if rs else float("nan")
            s["ratio_to_raw"] = s["stage_rays_per_s"] / s["raw_rays_per_s"]
        out["total_seconds"] = sum(out["stages"][k]["seconds"] for k in ("relocate", "trace", "light", "visibility"))
        out["other_seconds"] = {k: v for k, v in times.items() if k in ("ingest", "place")}
        return out


def _cpu_seconds() -> float:
    """User + sys seconds of this process (all its threads) and of its waited-for children."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def mode_artifacts(mode: str, names, sh_order: int) -> list[str]:
    """The bundle artifacts GI ``mode`` reads (its ``needs`` and the artifacts its textures bind at ``sh_order``)."""
    K = cluster_count(names)
    wanted = {n for p in MODES[mode]["needs"] if "*" not in p for n in expand(p, K)}
    try:
        for arts, _ in texture_bindings(mode, names, sh_order).values():
            wanted.update(arts)
    except ValueError:          # prt without its section: not baked
        return []
    return sorted(n for n in wanted if n in names)


def bundle_sizes(manifest, probes: int) -> dict:
    """Bytes per probe of each GI mode and of the whole bundle (module doc)."""
    size = {a.name: a.bytes for a in manifest.artifacts}
    order = int(manifest.config["light"]["sh_order"])
    modes = {}
    for m in MODE_IDS:
        arts = mode_artifacts(m, size, order)
        if arts or not MODES[m]["needs"]:
            modes[m] = {"bytes": sum(size[a] for a in arts), "artifacts": arts}
            modes[m]["bytes_per_probe"] = modes[m]["bytes"] / probes
    whole = sum(size.values())
    scene = sum(a.bytes for a in manifest.artifacts if a.format == "glb")
    arts = {a.name: {"bytes": a.bytes, "stage": a.stage, "format": a.format,
                     "vk_format": (a.meta.get("ktx2") or {}).get("format")} for a in manifest.artifacts}
    return {"probes": probes, "modes": modes, "bundle_bytes": whole, "bundle_bytes_per_probe": whole / probes,
            "bundle_bytes_without_scene": whole - scene, "scene_bytes": scene, "artifacts": arts}


def bake_whole(scene, counts) -> dict:
    """Every stage of a default bake at ``counts`` (evaluate off) in this process: per-stage wall and CPU seconds,
    peak RSS, and the bundle sizes."""
    cfg = BakeConfig.model_validate({"place": {"counts": counts}, "scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]},
                                     "evaluate": {"enabled": False}})
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(tmp)
        sid = store.put_bytes(scene.to_bytes())
        stages = {}
        for st, _ in plan(sid, cfg):
            t0, c0 = time.perf_counter(), _cpu_seconds()
            pipeline.execute_stage(store, sid, cfg, st.name)
            stages[st.name] = {"wall_s": time.perf_counter() - t0, "cpu_s": _cpu_seconds() - c0}
        manifest = build_manifest(store, scene.summary(sid), cfg)
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"stages": stages, "wall_s": sum(s["wall_s"] for s in stages.values()),
            "cpu_s": sum(s["cpu_s"] for s in stages.values()),
            "peak_rss_mb": own.ru_maxrss / 1024, "peak_rss_children_mb": kids.ru_maxrss / 1024,
            "sizes": bundle_sizes(manifest, int(np.prod(counts)))}


def bake_in_child(grid: str) -> dict:
    """:func:`bake_whole` in a fresh process (its own peak RSS), after a warm-up bake there (numba caches)."""
    with tempfile.NamedTemporaryFile(suffix=".json") as f:
        subprocess.run([sys.executable, __file__, "--one-bake", grid, "--json-out", f.name], check=True)
        return json.loads(Path(f.name).read_text())


def print_bundles(results: dict) -> None:
    modes = [m for m in MODE_IDS if any(m in r["sizes"]["modes"] for r in results.values())]
    print("bundle on zdm2-sauerbraten, bytes per probe (a mode: the artifacts its textures bind)")
    print(f"{'grid':>10s} {'probes':>8s} " + " ".join(f"{m:>15s}" for m in modes)
          + f" {'bundle B/probe':>14s} {'bundle MB':>10s} {'w/o scene MB':>12s}")
    for g, r in results.items():
        z = r["sizes"]
        cells = " ".join(f"{z['modes'][m]['bytes_per_probe']:15.1f}" if m in z["modes"] else f"{'-':>15s}"
                         for m in modes)
        flag = "" if g != "64x32x64" else ("  (target <= 60 MB: " + ("met" if z["bundle_bytes"] <= 60e6 else "MISSED")
                                           + ")")
        print(f"{g:>10s} {z['probes']:8d} {cells} {z['bundle_bytes_per_probe']:14.1f} {z['bundle_bytes'] / 1e6:10.1f}"
              f" {z['bundle_bytes_without_scene'] / 1e6:12.1f}{flag}")
    grids = [g for g, r in results.items() if "artifacts" in r["sizes"]]
    if grids:                           # every artifact's stored bytes per probe: what the mode columns do not show
        print("bundle artifacts, stored bytes per probe (file size / probes)")
        print(f"{'artifact':>28s} {'stage':>9s} {'format':>26s} " + " ".join(f"{g:>10s}" for g in grids))
        names = sorted({n for g in grids for n in results[g]["sizes"]["artifacts"]},
                       key=lambda n: -results[grids[-1]]["sizes"]["artifacts"].get(n, {"bytes": 0})["bytes"])
        for n in names:
            info = next(results[g]["sizes"]["artifacts"][n] for g in grids if n in results[g]["sizes"]["artifacts"])
            cells = " ".join(f"{results[g]['sizes']['artifacts'][n]['bytes'] / results[g]['sizes']['probes']:10.1f}"
                             if n in results[g]["sizes"]["artifacts"] else f"{'-':>10s}" for g in grids)
            print(f"{n:>28s} {info['stage']:>9s} {info['vk_format'] or info['format']:>26s} {cells}")
    for g, r in results.items():
        print(f"bake {g}: wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s (user+sys, threads and children), "
              f"peak RSS {r['peak_rss_mb']:.0f} MB (children {r['peak_rss_children_mb']:.0f} MB)"
              + ("  (target <= 300 s wall: " + ("met" if r["wall_s"] <= 300 else "MISSED") + ")"
                 if g == "64x32x64" else ""))
        print("   " + ", ".join(f"{k} {v['wall_s']:.1f}/{v['cpu_s']:.1f}" for k, v in r["stages"].items()
                                if v["wall_s"] >= 0.05) + "  (stage wall/CPU s)")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--grids", default="16x8x16,32x16x32")
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--bundles", default="16x8x16,32x16x32,64x32x64",
                    help="grids baked whole for the bundle-size and bake-time tables ('' skips)")
    ap.add_argument("--one-bake", help=argparse.SUPPRESS)
    ap.add_argument("--json-out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if not SCENE.exists():
        print(f"skipped: {SCENE} is absent (the benchmark reads ../shared/scenes)")
        return 0
    scene = ingest_file(SCENE)
    if args.one_bake:                   # the child of bake_in_child
        bake_whole(scene, [3, 2, 3])    # warm-up: numba kernels compiled or loaded, outside the timings
        out = bake_whole(scene, [int(x) for x in args.one_bake.split("x")])
        Path(args.json_out).write_text(json.dumps(out))
        return 0
    results = {"scene": "zdm2-sauerbraten", "triangles": scene.n_triangles, "grids": {}, "bundles": {}}
    for g in filter(None, args.bundles.split(",")):
        results["bundles"][g] = bake_in_child(g)
    if results["bundles"]:
        print_bundles(results["bundles"])
    if not args.grids:
        print(json.dumps(results))
        return 0
    raw = RawEmbree(scene.triangles)
    # warm-up: compile / load numba kernels outside the timings
    run_grid(scene, [3, 2, 3], 16, 2, raw)
    for g in args.grids.split(","):
        counts = [int(x) for x in g.split("x")]
        results["grids"][g] = run_grid(scene, counts, args.rays, args.samples, raw)

    print(f"zdm2-sauerbraten ({scene.n_triangles} triangles), {args.rays} rays/probe, θ at {args.samples}/cell, "
          f"light 3 bounces, raw = embreex 2 threads on the same rays")
    print(f"{'grid':>10s} {'stage':>11s} {'seconds':>8s} {'rays':>11s} {'stage Mray/s':>13s} "
          f"{'in-caster':>10s} {'raw Mray/s':>11s} {'stage/raw':>9s}")
    for g, r in results["grids"].items():
        for name, s in r["stages"].items():
            print(f"{g:>10s} {name:>11s} {s['seconds']:8.2f} {s['rays']:11d} {s['stage_rays_per_s'] / 1e6:13.2f} "
                  f"{s['caster_rays_per_s'] / 1e6:10.2f} {s['raw_rays_per_s'] / 1e6:11.2f} {s['ratio_to_raw']:9.2f}")
        target = 8.0 if g == "16x8x16" else 40.0
        print(f"{g:>10s} {'TOTAL':>11s} {r['total_seconds']:8.2f}   (target < {target:.0f} s: "
              f"{'met' if r['total_seconds'] < target else 'MISSED'}; light: direct "
              f"{r['stages']['light']['direct_seconds']:.2f} s + 3 bounces {r['stages']['light']['bounce_seconds']:.2f} s)")
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
