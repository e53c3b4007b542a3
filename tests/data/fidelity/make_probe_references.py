"""Cycles references at the probes of the DEFAULT grid (issue 12 item 2): run by hand, needs Blender 3.4.

    .venv/bin/python tests/data/fidelity/make_probe_references.py [--scenes two-rooms,two-rooms-vc]
        [--samples 8192] [--seeds 0,1] [--points-only] [--per-region 8]

``tests/data/fidelity/<scene>.points.json`` holds hand-placed check points and the probes of a fixed 8x8x8 grid; the
light stage's stored values are meant to be right at the probes a default bake actually has. For each scene this

1. runs Kiln's ``ingest`` and ``place`` stages with the default config (``BakeConfig()``: the automatic grid) and takes
   the un-relocated positions of that grid's probes (float32, as the place stage stores them) that lie in each box of
   :data:`BOXES` at least :data:`CLEARANCE` from every surface and outside every solid (the checks of
   ``make_references``), ``--per-region`` of them spread evenly in grid order;
2. writes ``default-probes/<scene>.points.json`` (points, regions, the grid they belong to, the scene's sha256);
3. runs the oracle at them exactly as ``make_references.py`` does (``--bounces 64 --material lambert``, sky 0, one
   run per seed) and writes ``default-probes/<scene>.lambert.cycles.json``.

Made on 2026-12-03 with 4096 spp x 2 seeds (``--samples 4096``) for the default grid [38, 15, 20] of room scale / 8
(``workers.kernels.autogrid.ROOM_DIVISIONS``): 97 s (two-rooms) and 84 s (two-rooms-vc) of Blender wall time on this
2-core machine, loaded (96 receivers a run). The set before (grid [28, 12, 15], room scale / 6): 87 s and 39 s; the
grid's phase is chosen the same on every numpy build (``workers.kernels.autogrid.layer_phase``). The first set (2026-12-02, 8192 spp x 2 seeds, 464 s and 474 s on
a loaded machine) had a seed spread of the dark region's mean of 1.0% / 0.5%.

``tests/bench/bench_fidelity.py`` compares the default bake's stored probe values (octahedral map and L2 SH) there
when its grid is still the recorded one (else it says the points must be regenerated).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))
sys.path.insert(0, str(HERE))

import make_references as MR  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.procedural import make_scene  # noqa: E402

OUT = HERE / "default-probes"
CLEARANCE = 0.15  # metres from every surface
# two-rooms: room A = [0, 4] x [0, 3] x [0, 4] holds the light; room B = [4.05, 8.05] x [0, 3] x [0, 4] is lit only
# through the door. "probes-dark": B's probes (the "a dark room next to a lit one"), "probes-lit": A's.
_ROOMS = {"probes-dark": ((4.05, 0.0, 0.0), (8.05, 3.0, 4.0)), "probes-lit": ((0.0, 0.0, 0.0), (4.0, 3.0, 4.0))}
BOXES = {"two-rooms": _ROOMS, "two-rooms-vc": _ROOMS}


def default_grid(scene: str, work: Path) -> dict:
    """counts, origin, spacing (and the auto reason) of the default config's grid of ``scene``."""
    glb = work / f"{scene}.glb"
    glb.write_bytes(make_scene(scene))
    store = Store(work / "store")
    sid = store.put_bytes(ingest_file(glb).to_bytes())
    cfg = BakeConfig()
    for st, _ in plan(sid, cfg):
        rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
        if st.name == "place":
            s = rec["stats"] if isinstance(rec, dict) else rec.stats
            return {k: s[k] for k in ("counts", "origin", "spacing")} | {"auto": s.get("auto")}
    raise RuntimeError("no place stage in the plan")


def points_doc(scene: str, per_region: int, work: Path) -> dict:
    data = make_scene(scene)
    tris = MR.triangles(data)
    grid = default_grid(scene, work)
    counts = np.asarray(grid["counts"])
    origin, spacing = np.asarray(grid["origin"], np.float64), np.asarray(grid["spacing"], np.float64)
    pts: list[list[float]] = []
    regions: dict[str, list[int]] = {}
    for region, (lo, hi) in BOXES[scene].items():
        free = []
        for k in range(counts[2]):
            for j in range(counts[1]):
                for i in range(counts[0]):
                    p = (origin + spacing * np.array([i, j, k])).astype(np.float32).astype(np.float64)
                    if not (np.all(p >= lo) and np.all(p <= hi)):
                        continue
                    if MR.clearance(tris, p) >= CLEARANCE and not MR.inside(tris, p):
                        free.append(p)
        if not free:
            raise RuntimeError(f"{scene}: no free default-grid probe in {region} {lo}-{hi}")
        pick = np.unique(np.linspace(0, len(free) - 1, min(per_region, len(free))).round().astype(int))
        regions[region] = list(range(len(pts), len(pts) + len(pick)))
        pts += [[float(x) for x in free[i]] for i in pick]
    return {"scene": scene, "points": pts, "regions": regions,
            "probe_grid": {"counts": counts.tolist(), "origin": origin.tolist(), "spacing": spacing.tolist(),
                           "auto": grid["auto"],
                           "note": "the default config's grid (BakeConfig(): the automatic grid); the points are "
                                   f"un-relocated positions of its probes, at least {CLEARANCE} m from every surface"},
            "glb_sha256": hashlib.sha256(data).hexdigest()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(BOXES))
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--per-region", type=int, default=8)
    ap.add_argument("--points-only", action="store_true")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per Blender run")
    args = ap.parse_args()
    OUT.mkdir(exist_ok=True)
    seeds = [int(x) for x in args.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for scene in [s for s in args.scenes.split(",") if s]:
            if scene not in BOXES:
                raise SystemExit(f"no probe boxes for {scene!r}; have {', '.join(BOXES)}")
            doc = points_doc(scene, args.per_region, work)
            path = OUT / f"{scene}.points.json"
            path.write_text(json.dumps(doc, indent=1) + "\n")
            print(f"{path.relative_to(HERE)}: {len(doc['points'])} probes of the default grid "
                  f"{doc['probe_grid']['counts']}, " + ", ".join(f"{k} {len(v)}" for k, v in doc["regions"].items()),
                  flush=True)
            if args.points_only:
                continue
            t0 = time.perf_counter()
            ref = MR.reference(scene, "lambert", args.samples, seeds, args.timeout, work, points_file=path)
            out = OUT / f"{scene}.lambert.cycles.json"
            out.write_text(json.dumps(ref, separators=(",", ":")) + "\n")
            print(f"{out.relative_to(HERE)}: {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
