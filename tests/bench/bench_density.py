"""Probe density against Cycles near shaded walls (issue 12's "make the density adaptive" question): run by hand.

    .venv/bin/python tests/bench/bench_density.py [--spots 5,8,9] [--spacings 2.19,1.1,0.55] [--half 10]
        [--json OUT.json]

zdm2-sauerbraten's default grid is budget-bound (2.19 m where its rooms ask for 0.985 m; bench_fidelity's
``wall-shade`` region reads 1.12-1.13x Cycles in normalized mask GI). Is that the probes' spacing, or something a
finer grid would not fix (the light stage's stored values, the sampler)? For each wall spot of zdm2's
``wall-shade`` region (``--spots``: indices of its 5 cm points in ``tests/data/fidelity/zdm2.points.json``; the
10 and 25 cm points in front of the same spot come with it), this bakes a box of ``--half`` metres around the spot
with the default config and only ``place.box`` and ``place.spacing`` set, at each of ``--spacings``, and prints the
mean over the spot's 3 points x 6 axis normals of mode / Cycles (RGB means; Cycles: the zdm2 reference of
bench_fidelity), per normal too. Light entering the box from geometry outside it is gathered from the box's edge
probes (the light stage clamps to the grid), so each spot's box is centred on it and only its own points are read.

Also prints the probes a grid needs to reach each spacing near every surface of the scene (an adaptive layout's
lower bound: one layer of probes per ``spacing²`` of surface area, zdm2's 29,349 m² of triangles) and a uniform
grid over the default box, against the default budget (``place.budget``, 24,000).

Measured (2026-12-03, loaded machine; normalized mask GI / Cycles at 2.19 / 1.1 / 0.55 m): spot 5 1.145 / 1.106 /
0.995, spot 8 1.298 / 1.087 / 0.987, spot 9 1.379 / 1.307 / 1.061 (its +Z normal, facing a close dark surface, 1.83 at
0.55 m). The error is the spacing; 0.55 m near every surface takes ~97,000 probes in a single layer (4x the budget),
1.1 m ~24,000 (the whole budget), a uniform grid over the default box at 0.55 m ~1.3 million.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

import bench_fidelity as BF  # noqa: E402
from proto.models import BakeConfig  # noqa: E402

SCENE = "zdm2"
MODES = ("ddgi", "mask", "mask_normalized")


def spot_points(pdoc: dict, spot: int) -> list[int]:
    """The spot's 5, 10 and 25 cm points (same position in the three wall regions)."""
    k = pdoc["regions"]["wall-5cm"].index(spot)
    return [pdoc["regions"][r][k] for r in ("wall-5cm", "wall-10cm", "wall-25cm")]


def run(spots: list[int], spacings: list[float], half: float, store: Path) -> dict:
    pdoc = json.loads((BF.DATA / f"{SCENE}.points.json").read_text())
    source = BF.source_of(pdoc)
    if not source.is_file():
        raise SystemExit(f"{source} is not there (a real scene, read from ../shared/scenes; KILN_SHARED_SCENES)")
    ref = json.loads((BF.DATA / f"{SCENE}.lambert.cycles.json").read_text())
    points = np.asarray(pdoc["points"], np.float64)
    dirs = np.asarray(ref["dirs"], np.float64)
    target = np.asarray(ref.get("E_probe_rgb", ref["E_indirect_rgb"]), np.float64).reshape(len(points), 6, 3)
    out = {"spots": {}}
    work = store / "work"
    work.mkdir(parents=True, exist_ok=True)
    for spot in spots:
        idx = spot_points(pdoc, spot)
        c = points[spot]
        rows = []
        for h in spacings:
            cfg = BF.deep_merge(pdoc.get("config") or {}, {"place": {"box": {"min": (c - half).tolist(),
                                                                              "max": (c + half).tolist()},
                                                                      "spacing": h}})
            t0 = time.perf_counter()
            scene, recs, bcfg, _ = BF.bake(SCENE, work, store, cfg, source)
            secs = time.perf_counter() - t0
            pts = np.repeat(points[idx], 6, axis=0)
            nrm = np.tile(dirs, (len(idx), 1))
            modes = BF.reconstruct(recs, bcfg, pts, nrm)
            tgt = target[idx].reshape(-1, 3)
            row = {"spacing": h, "counts": list(recs["place"].stats["counts"]), "seconds": secs, "modes": {}}
            for m in MODES:
                v = np.asarray(modes[m], np.float64).reshape(len(idx), 6, 3)
                per_normal = v.mean(axis=(0, 2)) / target[idx].mean(axis=(0, 2))
                row["modes"][m] = {"mean": float(v.mean() / tgt.mean()), "per_normal": per_normal.tolist()}
            rows.append(row)
            mn = row["modes"]["mask_normalized"]
            print(f"spot {spot} {c.round(2).tolist()} spacing {h:5.2f} m grid {row['counts']}: "
                  + " ".join(f"{m} {row['modes'][m]['mean']:.3f}" for m in MODES)
                  + "; mask_normalized per normal (+X -X +Y -Y +Z -Z) "
                  + " ".join(f"{x:.2f}" for x in mn["per_normal"]) + f"  ({secs:.0f} s)", flush=True)
        out["spots"][spot] = rows
    return out


def probe_counts(spacings: list[float]) -> dict:
    """Probes for each spacing: one layer over every surface (area / h²) and a uniform grid over the default box."""
    from workers.gltf import ingest_file
    pdoc = json.loads((BF.DATA / f"{SCENE}.points.json").read_text())
    s = ingest_file(BF.source_of(pdoc))
    t = np.asarray(s.triangles, np.float64)
    area = float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())
    budget = BakeConfig().place.budget
    default_spacing = 2.19  # the default grid's spacing (bench_fidelity's grid.auto.reason), 20,387 probes
    uniform20k = 20387
    out = {"area_m2": area, "budget": budget, "rows": []}
    for h in spacings:
        out["rows"].append({"spacing": h, "surface_layer": area / h ** 2,
                            "uniform": uniform20k * (default_spacing / h) ** 3})
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spots", default="5,8,9", help="indices of wall-5cm points of zdm2.points.json (the shaded "
                    "ones: 5-9)")
    ap.add_argument("--spacings", default="2.19,1.1,0.55")
    ap.add_argument("--half", type=float, default=10.0, help="half size of the box around each spot, metres")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    spacings = [float(x) for x in args.spacings.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        res = run([int(x) for x in args.spots.split(",")], spacings, args.half, Path(tmp))
    res["probes"] = probe_counts(spacings)
    print(f"zdm2 surface area {res['probes']['area_m2']:.0f} m2; default budget {res['probes']['budget']} probes")
    for r in res["probes"]["rows"]:
        print(f"  spacing {r['spacing']:.2f} m: one layer over every surface {r['surface_layer']:,.0f} probes; "
              f"uniform over the default box {r['uniform']:,.0f}")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
