"""Calibration of the cost model (proto/cost.py): measured peak memory and seconds of each stage.

    .venv/bin/python tests/bench/bench_cost.py [--cases small,medium,zdm2] [--out cost.json]

Each stage of each case runs in a process forked from this warm one (as RQ forks a work-horse from a
worker that imported ``workers.jobs``), after the stages before it have run and are in the store. The
child reports its seconds, its RSS growth (``VmHWM`` at the end minus ``VmRSS`` at the start: what the stage
itself allocated, the worker's own footprint excluded) and its address-space growth (``VmPeak`` - ``VmSize``,
what ``RLIMIT_AS`` counts). Next to each measurement it prints the model's estimate for that stage and the
ratio. Prints a table and writes the measurements as JSON (``--out``).

Each row also holds the stage's stored bytes: ``artifact_bytes`` (every file it wrote to the store, internal ones
included), ``bundle_bytes`` (the artifacts the bundle takes) and per artifact ``[file bytes, raw bytes (its array's
size before Zstandard), internal]``. The byte cases (``--cases bytes``: the procedural scenes and zdm2 at 16x8x16 and
32x16x32 with the defaults) calibrate :data:`proto.cost.BYTES_CALIBRATION`; ``--check`` compares every row that has
bytes with the model's ``artifact_bytes`` / ``bundle_bytes``, per stage and per bake:

    .venv/bin/python tests/bench/bench_cost.py --cases bytes --out tests/bench/cost_bytes.json
    .venv/bin/python tests/bench/bench_cost.py --check tests/bench/cost_bytes.json
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import workers.jobs  # noqa: E402,F401  (the worker's imports, before forking)
from proto import cost  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.procedural import write_scene  # noqa: E402

ZDM2 = ROOT.parent / "shared" / "scenes" / "zdm2-sauerbraten" / "zdm2.glb"
REAL = {"zdm2": ZDM2, "living-room": ROOT.parent / "shared" / "scenes" / "godot-living-room" / "living_room.glb"}
SUN = {"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0, "color": [1.0, 0.95, 0.9]}
LIT = {"scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]}}     # zdm2 has no lights (as bench_probes bakes it)

OFF = {"evaluate": {"enabled": False}}
SMALL = {"trace": {"rays_per_probe": 64}, "visibility": {"samples_per_cell": 4, "slabs": 1},
         "masks": {"sweeps": 50}, **OFF}
CASES = {
    # name: (scene, config); measured without evaluate (and its reference) unless the case is about them
    "tiny": ("cornell", {"place": {"counts": [4, 4, 4]}, **SMALL}),
    "small": ("two-rooms", {"place": {"counts": [12, 6, 8]}, **SMALL}),
    "rays": ("two-rooms", {"place": {"counts": [12, 6, 8]}, "trace": {"rays_per_probe": 1024},
                           "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 50}, **OFF}),
    "medium": ("two-rooms", {"place": {"counts": [24, 12, 16]}, "trace": {"rays_per_probe": 256},
                             "visibility": {"samples_per_cell": 6, "slabs": 1}, "masks": {"sweeps": 50}, **OFF}),
    "field": ("cornell", {"place": {"counts": [10, 10, 10]}, "trace": {"rays_per_probe": 64},
                          "visibility": {"samples_per_cell": 12, "slabs": 1}, "masks": {"sweeps": 20}, **OFF}),
    "prt": ("cornell", {"place": {"counts": [6, 6, 6]}, **SMALL,
                        "prt": {"enabled": True, "configurations": 64, "measurement_points": 256, "basis": 16,
                                "lightmap": 64}}),
    "zdm2": ("zdm2", {"place": {"spacing": 2.5}, "trace": {"rays_per_probe": 128},
                      "visibility": {"samples_per_cell": 4, "slabs": 1}, "masks": {"sweeps": 50}, **OFF}),
    "zdm2_auto": ("zdm2", {"place": {"budget": 3000}, "trace": {"rays_per_probe": 128},
                           "visibility": {"slabs": 1}, "masks": {"sweeps": 50}, **OFF}),
    "defaults": ("two-rooms", {"place": {"counts": [16, 8, 12]}, **OFF}),
    # a closed room at 4.7 M probe rays (every ray hits): past the light stage's and relocation's bounded temporaries
    "big_room": ("two-rooms", {"place": {"counts": [32, 16, 36]}, "trace": {"rays_per_probe": 256},
                               "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 20}, **OFF}),
    "prt_default": ("cornell", {"place": {"counts": [8, 8, 8]}, **SMALL, "prt": {"enabled": True}}),
    "prt_rays": ("two-rooms", {"place": {"counts": [12, 6, 8]}, "trace": {"rays_per_probe": 512},
                               "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 20},
                               "prt": {"enabled": True, "configurations": 64, "measurement_points": 64,
                                       "lightmap": 0}, **OFF}),
    # the evaluate stage and its path-traced reference (on by default)
    "ref_default": ("cornell", {"place": {"counts": [4, 4, 4]}, **SMALL, "evaluate": {"enabled": True}}),
    "ref_points": ("two-rooms", {"place": {"counts": [12, 6, 8]}, **SMALL,
                                 "evaluate": {"enabled": True, "surface_points": 8192, "previews": 0}}),
    "ref_zdm2": ("zdm2", {"place": {"spacing": 4.0}, **SMALL, "evaluate": {"enabled": True}}),
    # the stored bytes of the defaults (S = 8, K = 4, 256 rays, four slabs) and of K = 8 (proto.cost.BYTES_CALIBRATION)
    "bytes_cornell": ("cornell", {"place": {"counts": [12, 12, 12]}, **OFF}),
    "bytes_k8": ("two-rooms", {"place": {"counts": [16, 8, 12]}, "masks": {"clusters": 8}, **OFF}),
    "bytes_zdm2_16": ("zdm2", {"place": {"counts": [16, 8, 16]}, **LIT, **OFF}),
    "bytes_zdm2_32": ("zdm2", {"place": {"counts": [32, 16, 32]}, **LIT, **OFF}),
    "bytes_zdm2_8": ("zdm2", {"place": {"counts": [8, 4, 8]}, **LIT, **OFF}),
    "bytes_zdm2_s16": ("zdm2", {"place": {"counts": [16, 8, 16]}, "visibility": {"samples_per_cell": 16},
                                **LIT, **OFF}),
    "bytes_living_16": ("living-room", {"place": {"counts": [16, 8, 16]}, **LIT, **OFF}),
    "bytes_living_32": ("living-room", {"place": {"counts": [32, 16, 32]}, **LIT, **OFF}),
}
GROUPS = {"bytes": ["tiny", "small", "field", "defaults", "bytes_cornell", "bytes_k8", "bytes_zdm2_16",
                    "bytes_zdm2_32", "bytes_zdm2_8", "bytes_zdm2_s16", "zdm2_auto", "bytes_living_16",
                    "bytes_living_32"]}


def _status() -> dict[str, int]:
    out = {}
    for line in open("/proc/self/status"):
        k, _, v = line.partition(":")
        if k in ("VmRSS", "VmHWM", "VmSize", "VmPeak"):
            out[k] = int(v.split()[0]) * 1024
    return out


def stored_bytes(rec: dict) -> dict:
    """A stage record's stored bytes: every file (``artifact_bytes``), the bundle's (``bundle_bytes``) and per
    artifact ``[file bytes, raw bytes, internal]`` (raw: the array's bytes before Zstandard; a file's own for
    json, png, glb)."""
    import numpy as np

    arts = {}
    for a in rec["artifacts"]:
        internal = bool(a.get("meta", {}).get("internal"))
        raw = a["bytes"]
        if a["format"] in ("ktx2", "npy"):
            raw = int(np.prod(a["shape"], dtype=np.int64)) * np.dtype(a["dtype"]).itemsize
        arts[a["name"]] = [a["bytes"], raw, internal]
    total, bundle = cost.stored_bytes(rec)
    return {"artifact_bytes": total, "bundle_bytes": bundle, "artifacts": arts}


def run_forked(store: Store, scene_id: str, config: BakeConfig, stage: str) -> dict:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        try:
            s0 = _status()
            t0 = time.perf_counter()
            rec, cached = pipeline.execute_stage(store, scene_id, config, stage)
            sec = time.perf_counter() - t0
            s1 = _status()
            out = {"seconds": sec, "rss": s1["VmHWM"] - s0["VmRSS"], "vm": s1["VmPeak"] - s0["VmSize"],
                   "base_rss": s0["VmRSS"], "cached": cached, **stored_bytes(rec), "stats": {k: v for k, v in rec["stats"].items()
                                                                          if k in ("probes", "samples_per_cell",
                                                                                   "bounces", "counts")}}
        except BaseException as e:  # noqa: BLE001
            out = {"error": f"{type(e).__name__}: {e}"}
        os.write(w, json.dumps(out).encode())
        os.close(w)
        os._exit(0)
    os.close(w)
    data = b""
    while chunk := os.read(r, 65536):
        data += chunk
    os.close(r)
    os.waitpid(pid, 0)
    return json.loads(data)


def _summary(store: Store, tmp: str, scene_name: str) -> tuple[str, dict] | None:
    if scene_name in REAL:
        if not REAL[scene_name].exists():
            return None
        path = REAL[scene_name]
    else:
        path = Path(tmp) / f"{scene_name}.glb"
        write_scene(scene_name, path)
    scene = ingest_file(path)
    sid = store.put_bytes(scene.to_bytes())
    summary = scene.summary(sid)
    summary["bytes"] = store.blob_path(sid).stat().st_size
    return sid, summary


def check(files: list[str]) -> int:
    """Compare stored measurements (``--out`` files) with the model as it is now: per stage and per bake."""
    rows = [r for f in files for r in json.loads(Path(f).read_text())]
    summaries: dict[str, dict] = {}
    ratios_s, ratios_m, per_bake = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "store")
        print(f"{'case':11s} {'stage':13s} {'seconds':>8s} {'est':>8s} {'ratio':>6s}   {'MB':>7s} {'est':>7s} "
              f"{'ratio':>6s}")
        for r in rows:
            scene_name, cfg = CASES[r["case"]]
            if scene_name not in summaries:
                got = _summary(store, tmp, scene_name)
                if got is None:
                    continue
                summaries[scene_name] = got[1]
            est = cost.estimate(summaries[scene_name], BakeConfig.model_validate(cfg))
            e = est.stage(r["stage"])
            if e is None or r.get("cached"):
                continue
            mem = r["rss"] + r["base_rss"]
            est_mem = e.memory_bytes + cost.WORKER_FOOTPRINT
            rs, rm = e.seconds / max(r["seconds"], 1e-3), est_mem / mem
            ratios_s.append(rs)
            ratios_m.append(rm)
            b = per_bake.setdefault(r["case"], {"s": 0.0, "m": 0, "es": est.seconds, "em": est.peak_memory_bytes})
            b["s"] += r["seconds"]
            b["m"] = max(b["m"], mem)
            print(f"{r['case']:11s} {r['stage']:13s} {r['seconds']:8.2f} {e.seconds:8.2f} {rs:6.2f}   "
                  f"{mem / 2**20:7.0f} {est_mem / 2**20:7.0f} {rm:6.2f}")
    print()
    for name, b in per_bake.items():
        print(f"bake {name:11s} seconds {b['s']:7.1f} est {b['es']:7.1f} ({b['es'] / b['s']:4.2f}x)   "
              f"peak {b['m'] / 2**20:6.0f} MB est {b['em'] / 2**20:6.0f} MB ({b['em'] / b['m']:4.2f}x)")
    import statistics as st

    for label, xs in (("seconds", ratios_s), ("memory", ratios_m)):
        xs = sorted(xs)
        under = sum(x < 1 for x in xs)
        print(f"stage {label}: estimate/measured median {st.median(xs):.2f}, min {xs[0]:.2f}, max {xs[-1]:.2f}, "
              f"under-estimated {under} of {len(xs)}")
    check_bytes([r for r in rows if "artifact_bytes" in r and CASES[r["case"]][0] in summaries], summaries)
    return 0


BYTE_GROUPS = ("ingest", "trace", "light", "visibility", "anneal", "masks", "clusters", "compress")
"""The stages whose stored bytes ``--check`` shows one by one (a sharded stage with its shards)."""


def check_bytes(rows: list[dict], summaries: dict) -> None:
    """Stored bytes against the model: every stage of ``BYTE_GROUPS`` (the visibility shards with their join) and
    every bake, all artifacts (``artifact_bytes``) and the bundle's (``bundle_bytes``), and the range of
    estimate / measured per stage and per bake. Cached stages count: their record is the one the bake would store."""
    if not rows:
        return
    import statistics as st

    print(f"\n{'case':16s} {'stage':10s} {'artifact MB':>11s} {'est':>8s} {'ratio':>6s}   {'bundle MB':>9s} "
          f"{'est':>8s} {'ratio':>6s}")
    bakes, ratios = {}, {}
    for r in rows:
        est = cost.estimate(summaries[CASES[r["case"]][0]], BakeConfig.model_validate(CASES[r["case"]][1]))
        e = est.stage(r["stage"])
        b = bakes.setdefault(r["case"], {"a": 0, "b": 0, "ea": est.artifact_bytes, "eb": est.bundle_bytes,
                                         "groups": {}})
        b["a"] += r["artifact_bytes"]
        b["b"] += r["bundle_bytes"]
        group = r["stage"].split(".")[0]
        if e is not None and group in BYTE_GROUPS:
            f = b["groups"].setdefault(group, [0, 0, 0, 0])
            f[0] += r["artifact_bytes"]
            f[1] += e.artifact_bytes
            f[2] += r["bundle_bytes"]
            f[3] += e.bundle_bytes
    for name, b in bakes.items():
        for group, (a, ea, bb, eb) in b["groups"].items():
            ra, rb = ea / max(a, 1), (eb / bb if bb else float("nan"))
            ratios.setdefault(f"{group} artifact", []).append(ra)
            if bb:
                ratios.setdefault(f"{group} bundle", []).append(rb)
            print(f"{name:16s} {group:10s} {a / 1e6:11.3f} {ea / 1e6:8.3f} {ra:6.2f}   {bb / 1e6:9.3f} {eb / 1e6:8.3f} "
                  f"{rb:6.2f}")
    print()
    for name, b in bakes.items():
        ra, rb = b["ea"] / b["a"], b["eb"] / b["b"]
        ratios.setdefault("bake artifact", []).append(ra)
        ratios.setdefault("bake bundle", []).append(rb)
        print(f"bake {name:16s} artifacts {b['a'] / 1e6:8.2f} MB est {b['ea'] / 1e6:8.2f} MB ({ra:5.2f}x)   "
              f"bundle {b['b'] / 1e6:8.2f} MB est {b['eb'] / 1e6:8.2f} MB ({rb:5.2f}x)")
    for label, xs in sorted(ratios.items()):
        xs = sorted(xs)
        print(f"{label:20s} bytes: estimate/measured median {st.median(xs):6.2f}, min {xs[0]:6.2f}, "
              f"max {xs[-1]:6.2f}, under-estimated {sum(x < 1 for x in xs)} of {len(xs)}")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=",".join(c for c in CASES if not c.startswith("bytes_")),
                    help="case names, or the group \"bytes\" (default: the 15 cases of proto.cost.CALIBRATION)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--check", nargs="*", default=None, help="compare stored measurements with the model")
    args = ap.parse_args()
    if args.check:
        return check(args.check)
    rows, results = [], []
    names = [n for c in args.cases.split(",") for n in GROUPS.get(c, [c])]
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "store")
        for name in names:
            scene_name, cfg = CASES[name]
            got = _summary(store, tmp, scene_name)
            if got is None:
                print(f"skip {name}: {REAL[scene_name]} absent", file=sys.stderr)
                continue
            sid, summary = got
            config = BakeConfig.model_validate(cfg)
            est = cost.estimate(summary, config)
            by_stage = {s.name: s for s in est.stages}
            t_case = time.perf_counter()
            for st, _ in plan(sid, config):
                m = run_forked(store, sid, config, st.name)
                if "error" in m:
                    print(f"{name} {st.name}: {m['error']}", file=sys.stderr)
                    break
                e = by_stage.get(st.name)
                row = {"case": name, "stage": st.name, "triangles": summary["triangles"], **m,
                       "est_seconds": e.seconds if e else None, "est_memory": e.memory_bytes if e else None}
                results.append(row)
                rows.append(row)
                print(f"{name:10s} {st.name:13s} {m['seconds']:8.2f}s est {row['est_seconds'] or 0:8.2f}s  "
                      f"rss {m['rss'] / 2**20:8.1f} MB est {(row['est_memory'] or 0) / 2**20:8.1f} MB  "
                      f"vm {m['vm'] / 2**20:8.1f} MB  base {m['base_rss'] / 2**20:6.0f} MB  {m['stats']}",
                      flush=True)
            print(f"{name}: {time.perf_counter() - t_case:.1f} s in all; estimate {est.seconds:.1f} s, "
                  f"{est.peak_memory_bytes / 2**20:.0f} MB, {est.probes} probes", flush=True)
            if args.out:                # after every case: a long run that stops keeps what it measured
                Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
