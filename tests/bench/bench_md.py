"""Mask Decomposition benchmark (MD issue): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_md.py [--grids 16x8x16,32x16x32,16x32x16] [--samples 8] [--clusters 4]

On ../shared/scenes/zdm2-sauerbraten (a sun and a sky added; the scene has no lights) runs the real
pipeline up to `visibility` (untimed here: see bench_probes.py), then times the `anneal` (edge loss E
+ 1000 sweeps), `masks` and `compress` stages, and prints an MD Table 2-style spatial cost table (bytes of
each texture a mode samples) next to the paper's figures. The last line is the same numbers as JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402

SCENE = ROOT.parent / "shared" / "scenes" / "zdm2-sauerbraten" / "zdm2.glb"
SUN = {"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0}
PAPER = {"mask (16x32x16, K=4, compressed)": 1.08e6, "ratio (MD text)": "about 10x (1/16 in §3.4.2)",
         "1000 sweeps": "5-10 s for 500-1000 iterations", "full bake": "183 s (16x32x16, 96x192x96 masks)"}


def run(scene, counts, S, K) -> dict:
    cfg = BakeConfig.model_validate({
        "place": {"counts": counts}, "scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]},
        "light": {"bounces": 3}, "visibility": {"samples_per_cell": S},
        "masks": {"clusters": K, "sweeps": 1000}})
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(tmp)
        sid = store.put_bytes(scene.to_bytes())
        times, recs = {}, {}
        for st, _ in plan(sid, cfg):
            t0 = time.perf_counter()
            rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
            times[st.name] = time.perf_counter() - t0
            recs[st.name] = rec
        a, c = recs["anneal"]["stats"], recs["compress"]["stats"]
        arts = {x["name"]: x for st in ("light", "masks", "compress", "visibility") for x in recs[st]["artifacts"]}

        def gpu_bytes(name):  # uncompressed texture bytes (what the GPU holds)
            x = arts[name]
            return int(np.prod(x["shape"])) * np.dtype(x["dtype"]).itemsize

        sh = sum(gpu_bytes(f"sh_l1_{ch}") for ch in "rgb")
        cl = sum(gpu_bytes(n) for n in arts if n.startswith("cluster_sh_") or n.startswith("cluster_weights"))
        dense = sum(gpu_bytes(n) for n in arts if n.startswith("masks_"))
        atlas = sum(gpu_bytes(n) for n in arts if n.startswith("mask_atlas") or n == "mask_indirection")
        theta = sum(gpu_bytes(n) for n in arts if n.startswith("theta_"))
        return {
            "counts": counts, "S": S, "K": K,
            "seconds": {"edge_loss": a["edge_seconds"], "sweeps_1000": a["anneal_seconds"],
                        "anneal_stage": times["anneal"], "masks_stage": times["masks"],
                        "compress_stage": times["compress"],
                        "anneal+masks+compress": times["anneal"] + times["masks"] + times["compress"]},
            "loss": {"initial": a["initial_loss"], "final": a["final_loss"], "random": a["random_loss"]},
            "compression": {"blocks": c["blocks"], "unique": c["unique_blocks"], "ratio": c["ratio"],
                            "max_sample_error": c["max_sample_error"]},
            "bytes": {"leaking: sh_l1 x3": sh, "mask: cluster SH + weights": cl, "mask: dense masks": dense,
                      "mask: atlas + indirection": atlas, "visibility: theta (8 ch)": theta},
        }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--grids", default="16x8x16,32x16x32,16x32x16")
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--clusters", type=int, default=4)
    args = ap.parse_args()
    if not SCENE.exists():
        print(f"skipped: {SCENE} is absent (the benchmark reads ../shared/scenes)")
        return 0
    scene = ingest_file(SCENE)
    out = {"scene": "zdm2-sauerbraten", "paper": PAPER, "grids": {}}
    for g in args.grids.split(","):
        out["grids"][g] = run(scene, [int(x) for x in g.split("x")], args.samples, args.clusters)
    print(f"zdm2-sauerbraten, S = {args.samples}, K = {args.clusters}, 1000 sweeps")
    print(f"{'grid':>10s} {'E s':>7s} {'1000 sw s':>9s} {'anneal s':>8s} {'masks s':>7s} {'compr s':>7s} "
          f"{'a+m+c s':>7s} {'eq7 final/random':>16s} {'blocks':>7s} {'unique':>7s} {'ratio':>6s}")
    for g, r in out["grids"].items():
        s, c, lo = r["seconds"], r["compression"], r["loss"]
        print(f"{g:>10s} {s['edge_loss']:7.3f} {s['sweeps_1000']:9.3f} {s['anneal_stage']:8.2f} {s['masks_stage']:7.2f} "
              f"{s['compress_stage']:7.2f} {s['anneal+masks+compress']:7.2f} {lo['final'] / lo['random']:16.3f} "
              f"{c['blocks']:7d} {c['unique']:7d} {c['ratio']:6.2f}")
    print("\nSpatial cost (MD Table 2 style), bytes as GPU textures (uncompressed formats):")
    names = list(next(iter(out["grids"].values()))["bytes"])
    print(f"{'texture':>30s} " + " ".join(f"{g:>12s}" for g in out["grids"]))
    for n in names:
        print(f"{n:>30s} " + " ".join(f"{r['bytes'][n]:12,d}" for r in out["grids"].values()))
    print(f"paper (MD, 16x32x16, K = 4): compressed masks {PAPER['mask (16x32x16, K=4, compressed)']:,.0f} bytes; "
          f"ratio {PAPER['ratio (MD text)']}; {PAPER['1000 sweeps']}; full bake {PAPER['full bake']}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
