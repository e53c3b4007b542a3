"""OFF-probe benchmark (issue 12, "probes stuck in walls are relocated or replaced"): run by hand.

    .venv/bin/python tests/bench/bench_offprobes.py [--scene PATH] [--full] [--set SECTION.KEY=JSON]...

On ../shared/scenes/zdm2-sauerbraten (or ``--scene``) runs the default config's ``place``, ``relocate`` and
``trace`` stages in this process with the real pipeline and prints the automatic grid (counts, spacing, what it
wanted, whether the budget binds), the probe states, and the OFF probes by kind:

- ``next_to_live``: an OFF probe with a live (ACTIVE or SLEEPING) probe among its 26 grid neighbours (within one
  cell): the probes the relocation could have moved into the space its neighbours see;
- ``deep``: an OFF probe whose 26 neighbours are all OFF (inside a solid thicker than two cells);

and, from the trace stage's own rays of each OFF probe: ``free_in_cells``, an OFF probe one of whose rays leaves
the solid (through a back face) within its 8 cells (``|exit − grid position| < spacing`` per axis): free space the
probe could shade, so a probe the relocation missed; ``solid_cells``: the others, whose 8 cells hold no free space
its rays find (nothing there to shade: OFF is right, whatever its neighbours); and those exits themselves: how
many lie in a cell none of whose 8 probes is live (free space no probe shades: what an OFF probe costs);

and how far the probes moved (the largest offset, as a fraction of the spacing, and how many moved further than
the DDGI-P §5 limit of 0.45 spacing). ``--full`` runs the whole default bake (with a sun and a sky added, as
bench_probes does: the scene has no lights) and prints the seconds of every stage and their sum, wall clock and CPU
(the process's time on all threads: on a shared machine the wall clock depends on the other load, CPU time less).
Prints a table and the numbers as JSON on the last line.
"""
from __future__ import annotations

import argparse
import json
import os
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
from workers.kernels.grid import OFF, ACTIVE, SLEEPING  # noqa: E402
from workers.stages.trace import probe_rays_of  # noqa: E402

SCENES = Path(os.environ.get("KILN_SHARED_SCENES", ROOT.parent / "shared" / "scenes"))
SCENE = SCENES / "zdm2-sauerbraten" / "zdm2.glb"
SUN = {"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0, "color": [1.0, 0.95, 0.9]}


def off_kinds(states: np.ndarray) -> dict:
    """OFF probes of a (nz, ny, nx) state volume by kind: with a live probe among the 26 neighbours or not."""
    off = states == OFF
    live = ~off
    near = np.zeros_like(off)
    pad = np.pad(live, 1, constant_values=False)
    nz, ny, nx = off.shape
    for dz in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dz or dy or dx:
                    near |= pad[1 + dz:1 + dz + nz, 1 + dy:1 + dy + ny, 1 + dx:1 + dx + nx]
    return {"off": int(off.sum()), "next_to_live": int((off & near).sum()), "deep": int((off & ~near).sum())}


def _exits_in_cells(p: int, base, pos, hits, dirs, spacing, past: float = 0.0) -> np.ndarray:
    """(E, 3) the back-face exits of probe ``p``'s rays (``hits`` (P, R, 4): t, u, v, back), ``past`` metres beyond
    the face, within its 8 cells around the grid position ``base[p]``."""
    b = (hits[p, :, 3] > 0.5) & np.isfinite(hits[p, :, 0])
    e = pos[p] + dirs.of_probes(p, p + 1)[0][b] * (hits[p, b, 0][:, None] + past)
    return e[np.all(np.abs(e - base[p]) < np.where(spacing > 0, spacing, np.inf), axis=1)]


def off_free_in_cells(off: np.ndarray, base: np.ndarray, pos: np.ndarray, hits: np.ndarray, dirs: np.ndarray,
                      spacing: np.ndarray) -> int:
    """OFF probes (``off`` (P,) bool) with a back-face exit of their rays within their 8 cells."""
    return sum(bool(len(_exits_in_cells(p, base, pos, hits, dirs, spacing))) for p in np.flatnonzero(off))


def orphan_free_space(states: np.ndarray, base: np.ndarray, pos: np.ndarray, hits: np.ndarray, dirs: np.ndarray,
                      spacing: np.ndarray) -> tuple[int, int]:
    """(free-space points, of them in a cell with no live corner probe): the back-face exits (2 cm past the face)
    of the OFF probes' rays within their 8 cells and the grid's box, i.e. free space next to an OFF probe, and
    whether any of the 8 probes of the cell holding it is live (ACTIVE or SLEEPING) to shade it. ``states``
    (nz, ny, nx); ``base``, ``pos`` (P, 3) grid and relocated positions; ``hits`` (P, R, 4); ``dirs`` the probes' rays
    (:class:`workers.kernels.sampling.ProbeRays`)."""
    nz, ny, nx = states.shape
    live = states != OFF
    lo, hi = base.min(axis=0), base.max(axis=0)
    top = np.maximum(np.array([nx, ny, nz]) - 2, 0)
    total = orphan = 0
    for p in np.flatnonzero(~live.ravel()):
        e = _exits_in_cells(p, base, pos, hits, dirs, spacing, past=0.02)
        e = e[np.all((e >= lo) & (e <= hi), axis=1)]
        if not len(e):
            continue
        c = np.clip(np.floor((e - base[0]) / np.where(spacing > 0, spacing, 1.0)).astype(np.int64), 0, top)
        seen = np.zeros(len(c), bool)
        for d in np.ndindex(2, 2, 2):
            seen |= live[np.minimum(c[:, 2] + d[2], nz - 1), np.minimum(c[:, 1] + d[1], ny - 1),
                         np.minimum(c[:, 0] + d[0], nx - 1)]
        total += len(c)
        orphan += int((~seen).sum())
    return total, orphan


def run(scene_path: Path, overrides: dict, full: bool) -> dict:
    scene = ingest_file(scene_path)
    cfg_d = {"scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]}}
    for k, v in overrides.items():
        sec, key = k.split(".", 1)
        cfg_d.setdefault(sec, {})[key] = v
    cfg = BakeConfig.model_validate(cfg_d)
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(tmp)
        sid = store.put_bytes(scene.to_bytes())
        times, cpu, recs = {}, {}, {}
        for st, _ in plan(sid, cfg):
            if not full and st.name not in ("ingest", "place", "relocate", "trace"):
                continue
            t0, c0 = time.perf_counter(), time.process_time()
            rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
            times[st.name] = time.perf_counter() - t0
            cpu[st.name] = time.process_time() - c0
            recs[st.name] = pipeline._lazy(store, rec)
        place, rel, tr = recs["place"].stats, recs["relocate"].stats, recs["trace"].stats
        nx, ny, nz = place["counts"]
        states = np.asarray(recs["trace"]["probe_states"]).reshape(nz, ny, nx)
        spacing = np.asarray(place["spacing"], np.float64)
        off = np.asarray(recs["relocate"]["probe_offsets"]).reshape(-1, 3)
        frac = np.abs(off) / np.where(spacing > 0, spacing, 1.0)
        auto = place.get("auto") or {}
        base = np.asarray(recs["place"]["probe_positions"], np.float64).reshape(-1, 3)
        pos = np.asarray(recs["relocate"]["probe_positions_relocated"], np.float64).reshape(-1, 3)
        kinds = off_kinds(states)
        kinds["free_in_cells"] = off_free_in_cells(states.ravel() == OFF, base, pos, np.asarray(recs["trace"]["ray_hits"]),
                                                   probe_rays_of(recs["trace"]), spacing)
        kinds["solid_cells"] = kinds["off"] - kinds["free_in_cells"]
        kinds["free_points"], kinds["free_points_unserved"] = orphan_free_space(
            states, base, pos, np.asarray(recs["trace"]["ray_hits"]),
            probe_rays_of(recs["trace"]), spacing)
        out = {
            "scene": scene_path.name, "triangles": scene.n_triangles, "overrides": overrides,
            "counts": place["counts"], "probes": place["probes"], "spacing": spacing.tolist(),
            "spacing_wanted": auto.get("spacing_wanted"), "budget_bound": auto.get("budget_bound"),
            "reason": auto.get("reason"), "auto": auto,
            "states": {"off": int((states == OFF).sum()), "active": int((states == ACTIVE).sum()),
                       "sleeping": int((states == SLEEPING).sum())},
            "off_kinds": kinds, "relocate": {k: v for k, v in rel.items() if not isinstance(v, dict)},
            "moved_beyond_045": int((frac.max(axis=1) > 0.45 + 1e-6).sum()),
            "max_offset_fraction": float(frac.max()) if frac.size else 0.0,
            "seconds": times, "total_seconds": sum(times.values()),
            "cpu_seconds": cpu, "total_cpu_seconds": sum(cpu.values()),
        }
        return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", type=Path, default=SCENE)
    ap.add_argument("--full", action="store_true", help="run every stage of the default bake and time them")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=JSON", help="a config override")
    args = ap.parse_args()
    if not args.scene.exists():
        print(f"skipped: {args.scene} is absent (the benchmark reads ../shared/scenes)")
        return 0
    overrides = {}
    for s in args.set:
        k, v = s.split("=", 1)
        overrides[k] = json.loads(v)
    r = run(args.scene, overrides, args.full)
    print(f"{r['scene']} ({r['triangles']} triangles), default config{' + ' + str(overrides) if overrides else ''}")
    print(f"grid {r['counts']} = {r['probes']} probes, spacing {max(r['spacing']):.3f} m "
          f"(wanted {r['spacing_wanted'] or float('nan'):.3f} m, budget bound: {r['budget_bound']})")
    print(f"reason: {r['reason']}")
    st, ok = r["states"], r["off_kinds"]
    print(f"{'active':>8s} {'sleeping':>8s} {'off':>8s} {'off next to live':>16s} {'off deep':>8s} "
          f"{'off, free in cells':>18s} {'off, solid cells':>16s} {'moved':>8s} {'rescued':>8s} {'>0.45 s':>8s} "
          f"{'max |off|/s':>11s}")
    print(f"{st['active']:8d} {st['sleeping']:8d} {st['off']:8d} {ok['next_to_live']:16d} {ok['deep']:8d} "
          f"{ok['free_in_cells']:18d} {ok['solid_cells']:16d} {r['relocate'].get('moved', 0):8d} "
          f"{r['relocate'].get('rescued') or 0:8d} {r['moved_beyond_045']:8d} {r['max_offset_fraction']:11.3f}")
    print(f"free space next to OFF probes (their rays' exits in their cells): {ok['free_points']} points, "
          f"{ok['free_points_unserved']} in a cell without a live probe")
    print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in r["seconds"].items()) + f"; total {r['total_seconds']:.1f}")
    print("CPU seconds (all threads; less sensitive to other load): "
          + ", ".join(f"{k} {v:.1f}" for k, v in r["cpu_seconds"].items()) + f"; total {r['total_cpu_seconds']:.1f}")
    print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
