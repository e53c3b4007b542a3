"""The automatic grid's rectilinear layers (autogrid step 4b) against the uniform fit, side by side: run by hand.

    .venv/bin/python tests/bench/bench_rectilinear.py [--scenes apartments,apartments-20cm] [--json OUT.json]

Each scene is baked twice with the default config: as the automatic grid chooses (rectilinear where the budget binds
2x or more in an enclosed scene), and with the uniform grid the same planning gives (``choose_grid(rectilinear=False)``)
reproduced through ``place.box`` + ``place.counts`` (the outermost layers on the box's faces: the same origin and
per-axis spacing). The reference is Kiln's own path tracer at check points (``evaluate.points``; within 1% of Cycles on
these rooms, bench_fidelity's ``kiln_pt``): a dark room beside the lit one, 5 / 10 / 25 cm from their shared wall (12
points each x 6 axis normals), its middle and the lit room's middle. Prints normalized mask GI and DDGI / reference
per region, the reference's relative standard error, the grid and the bake's seconds.

Scenes: ``apartments`` (workers/procedural_interiors.py: 5 x 3 x 3 rooms of 4 x 2.8 x 4 m, 10 cm walls; bench_fidelity
has its Cycles references) and ``apartments-20cm``, a held-out variant: 4 x 2 x 3 rooms of 5 x 3.2 x 3.5 m, 20 cm walls,
the lamp in a corner room.

Measured (2026-12-06, this machine): see docs/architecture.md "Rectilinear grid, built".
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import workers.procedural_interiors as PI  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.kernels.autogrid import analyze_free_space, choose_grid  # noqa: E402
from workers.kernels.materials import double_sided_triangles  # noqa: E402
from workers.raycast import caster_for_scene  # noqa: E402

VARIANTS = {  # name: (rooms, room size (m), wall (m), lit room)
    "apartments": ((5, 3, 3), (4.0, 2.8, 4.0), 0.10, (2, 1, 1)),
    "apartments-20cm": ((4, 2, 3), (5.0, 3.2, 3.5), 0.20, (0, 0, 1)),
}


def scene_and_points(name: str, work: Path):
    """(glb path, points (N, 3), regions {name: indices}) of a variant: the apartments builder with its constants set."""
    rooms, room, wall, lit = VARIANTS[name]
    saved = PI.APARTMENT_ROOMS, PI.APARTMENT_ROOM, PI.APARTMENT_WALL
    PI.APARTMENT_ROOMS, PI.APARTMENT_ROOM, PI.APARTMENT_WALL = rooms, room, wall
    try:
        spec = PI._apartments()
        x, y, z = PI.apartment_room(*lit)
        if name != "apartments":
            spec.lights[0].position = (x + 1.2, y + 2.6, z + 0.9)
        glb = PI.encode_glb(spec)
        dx = PI.apartment_room(lit[0] + 1, lit[1], lit[2])[0]
    finally:
        PI.APARTMENT_ROOMS, PI.APARTMENT_ROOM, PI.APARTMENT_WALL = saved
    w, h, d = room
    path = work / f"{name}.glb"
    path.write_bytes(glb)
    ys, zs = [y + 0.8, y + 1.6, y + 2.4], [z + 0.5, z + 1.0, z + d - 0.9, z + d - 0.5]
    pts, regions = [], {}
    for region, off in (("dark-5cm", 0.05), ("dark-10cm", 0.10), ("dark-25cm", 0.25)):
        regions[region] = list(range(len(pts), len(pts) + 12))
        pts += [[dx + off, yy, zz] for yy in ys for zz in zs]
    for region, x0 in (("dark-middle", dx), ("lit", x)):
        regions[region] = list(range(len(pts), len(pts) + 4))
        pts += [[x0 + w / 2 + a, y + 1.6, z + d / 2 + b] for a in (-0.5, 0.5) for b in (-0.5, 0.5)]
    return path, np.asarray(pts), regions


def uniform_place(path: Path) -> dict:
    """``place`` of the uniform grid the planning gives (``rectilinear=False``), as a box with counts."""
    s = ingest_file(path)
    fs = analyze_free_space(caster_for_scene(s), s.bounds, double_sided_triangles(s), seed=0)
    counts, origin, spacing, _ = choose_grid(s.bounds, fs, rectilinear=False)
    hi = origin + spacing * (counts - 1)
    return {"box": {"min": origin.tolist(), "max": hi.tolist()}, "counts": counts.tolist()}


def bake(path: Path, work: Path, tag: str, pts: np.ndarray, place: dict | None) -> tuple[dict, dict]:
    cfg = {"evaluate": {"points": {"points": pts.tolist()}, "spp": 1024, "dark_spp": 4096}}
    if place:
        cfg["place"] = place
    (work / f"{tag}.json").write_text(json.dumps(cfg))
    out = work / f"out-{tag}"
    r = subprocess.run([str(ROOT / ".venv" / "bin" / "kiln"), "bake", str(path), "--config", str(work / f"{tag}.json"),
                        "--cache", str(work / "cache"), "--out", str(out), "--quiet"], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"kiln bake {tag}: {r.returncode}\n{r.stderr[-3000:]}")
    return json.loads((out / "manifest.json").read_text()), json.loads((out / "check_points.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=",".join(VARIANTS))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="kiln-rect-"))
    report = {}
    for name in args.scenes.split(","):
        path, pts, regions = scene_and_points(name, work)
        rows = {}
        for grid, place in (("automatic", None), ("uniform", uniform_place(path))):
            m, cp = bake(path, work, f"{name}-{grid}", pts, place)
            ref = np.asarray(cp["reference_indirect"]).mean(axis=2)              # [point][normal], RGB mean
            se = np.asarray(cp["reference_stderr"]).mean(axis=2)
            row = {"grid": m["grid"]["counts"], "rectilinear": "layers" in m["grid"],
                   "seconds": sum(s["seconds"] for s in m["stages"] if s["name"] not in ("reference", "evaluate")),
                   "ref_rel_stderr": {k: float(np.sqrt((se[i] ** 2).sum()) / ref[i].sum()) for k, i in regions.items()}}
            for mode in ("mask_normalized", "ddgi"):
                v = np.asarray(cp["modes"][mode]).mean(axis=2)
                row[mode] = {k: float(v[i].mean() / ref[i].mean()) for k, i in regions.items()}
            rows[grid] = row
        report[name] = rows
        print(f"== {name}: mode / Kiln path tracer at the check points (default config)")
        print(f"{'grid':<11}{'mode':<17}" + "".join(f"{k:>13}" for k in regions) + f"{'grid':>16}{'bake s':>8}")
        for grid, row in rows.items():
            for mode in ("mask_normalized", "ddgi"):
                print(f"{grid:<11}{mode:<17}" + "".join(f"{row[mode][k]:>13.3f}" for k in regions)
                      + f"{'x'.join(map(str, row['grid'])) + (' rect' if row['rectilinear'] else ''):>16}"
                      + f"{row['seconds']:>8.1f}")
        print("reference relative standard error: "
              + ", ".join(f"{k} {v:.1%}" for k, v in rows["automatic"]["ref_rel_stderr"].items()))
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
