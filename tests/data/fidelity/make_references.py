"""Cycles references for the fidelity benchmark (tests/bench/bench_fidelity.py): run by hand, needs Blender 3.4.

    .venv/bin/python tests/data/fidelity/make_references.py [--scenes two-rooms-vc,metal-room]
        [--samples 8192] [--seeds 0,1] [--points-only] [--timeout 900]

For each procedural scene (``workers.procedural.make_scene``):

1. writes ``<scene>.points.json`` here: free-space check points by region (:data:`REGIONS`, hand-placed) plus
   ``probes``, un-relocated probe positions of the grid ``place.counts = [8, 8, 8]`` over the scene bounds (the
   default grid before the automatic one) that are at least :data:`PROBE_CLEARANCE` from every surface (a subset,
   :data:`PROBES_PER_SCENE`), so the bench can compare the light stage's stored probe values too (it bakes that
   grid when the default one holds no probe there). No "normals": the oracle gives each point the 6 axis
   normals +X, -X, +Y, -Y, +Z, -Z. ``regions`` maps region -> point indices. Every point is checked to be
   outside geometry (ray parity) and at least :data:`MIN_CLEARANCE` from every triangle.
2. writes the GLB to a temp dir and runs the shared oracle (``../shared/oracle/cycles_irradiance_points.py``,
   through :file:`oracle_lambert_textures.py`, which only makes its Lambert model follow metallic textures and keep
   emissive surfaces emitting — the stock Lambert replacement drops their emission) once per seed: ``--samples N --bounces 64 --sky 0,0,0 --material lambert`` (and for ``metal-room`` also
   ``--material importer --glossy 64``), under ``nice -n 10``.
3. writes ``<scene>.<material>.cycles.json``: per receiver (point x axis normal) the seed means of ``E_direct``
   and ``E_indirect`` (RGB), ``E_probe`` (what a probe bake stores: the indirect light plus the direct light of
   emissive surfaces, which Cycles counts as direct; = ``E_indirect`` in scenes without emitters — for those
   with emitters a second run with the punctual lights removed gives that direct part, for the first
   ``--emit-seeds`` seeds: it converges far faster than the indirect light), the settings,
   seeds, wall time per run, and the spread between seeds (per region: relative difference of the region means
   of E_indirect; per receiver: RMS of the relative half-difference).

Sky 0 throughout: the procedural scenes carry their own lights, and a probe then holds exactly E_probe.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT))

from workers.procedural import ALL_SCENES, make_scene  # noqa: E402

ORACLE = Path(os.environ.get("KILN_ORACLE", ROOT.parent / "shared" / "oracle" / "cycles_irradiance_points.py"))
WRAPPER = HERE / "oracle_lambert_textures.py"
AXES = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
DEFAULT_COUNTS = (8, 8, 8)  # the probe grid of the "probes" region: place.counts over the scene bounds
MIN_CLEARANCE = 0.04        # metres from every surface, for any check point
PROBE_CLEARANCE = {"cornell": 0.08}  # default 0.15 m
PROBES_PER_SCENE = 8
MATERIALS = {"metal-room": ("lambert", "importer")}  # default: ("lambert",)
GLOSSY = 64                                          # glossy bounces of --material importer

# Shared-wall layout of two-rooms: room A x in [0, 4], the 5 cm wall x in [4, 4.05], room B x in [4.05, 8.05];
# door z in [1.55, 2.45], y < 2. The wall points sit behind the wall (0.95 m from the door's edge), below and
# above the door's height.
_WALL_YZ = [(1.0, 0.6), (2.2, 0.6), (1.0, 3.4), (2.2, 3.4)]
_TWO_ROOMS = {
    "dark-5cm": [(4.10, y, z) for y, z in _WALL_YZ],
    "dark-10cm": [(4.15, y, z) for y, z in _WALL_YZ],
    "dark-25cm": [(4.30, y, z) for y, z in _WALL_YZ],
    "dark-middle": [(6.05, 1.5, 2.0), (6.05, 1.0, 1.0), (6.5, 2.0, 3.0), (5.5, 0.8, 3.2)],
    "lit-10cm": [(3.90, y, z) for y, z in _WALL_YZ],
    "lit": [(2.5, 1.2, 1.0), (1.0, 1.0, 3.0), (3.0, 2.0, 3.2), (2.0, 0.6, 2.0)],
}
REGIONS: dict[str, dict[str, list[tuple[float, float, float]]]] = {
    "two-rooms": _TWO_ROOMS,
    "two-rooms-vc": _TWO_ROOMS,
    # metal-room: interior [0, 4] x [0, 2.5] x [0, 3], the metal wall at x = 4, the striped box
    # [0.7, 1.5] x [0, 0.8] x [0.8, 1.6], the light at (2.4, 2.0, 1.8)
    "metal-room": {
        "metal-10cm": [(3.90, y, z) for y, z in [(0.8, 0.8), (1.7, 0.8), (0.8, 2.2), (1.7, 2.2)]],
        "metal-25cm": [(3.75, y, z) for y, z in [(0.8, 0.8), (1.7, 0.8), (0.8, 2.2), (1.7, 2.2)]],
        "middle": [(2.0, 1.25, 1.5), (2.6, 1.0, 1.0), (1.6, 1.5, 2.2), (2.8, 0.9, 2.4)],
        "object": [(1.1, 1.0, 1.2), (1.7, 0.4, 1.2), (1.1, 0.4, 1.8), (0.5, 0.4, 1.2)],
        "floor": [(2.5, 0.15, 0.7), (3.0, 0.15, 2.3), (0.5, 0.15, 2.5)],
    },
    # sealed-box: floor slab y < 0, box [-0.5, 0.5] x [0, 1] x [-0.5, 0.5] with a sealed cavity (no light at all)
    "sealed-box": {
        "cavity": [(0.0, 0.5, 0.0), (0.3, 0.3, -0.3), (-0.3, 0.8, 0.3)],
        "box-10cm": [(0.6, 0.5, 0.0), (-0.6, 0.5, 0.0), (0.0, 0.5, 0.6), (0.0, 0.5, -0.6)],
        "above-box": [(0.0, 1.1, 0.0), (0.25, 1.2, 0.25)],
        "open": [(2.0, 0.5, -2.0), (-2.5, 1.0, 2.0), (3.0, 0.3, 0.0), (-1.5, 0.5, -3.0)],
    },
    # cornell: cavity [0.02, 0.98]^2 x [0.02, 1] open at z = 1; red wall x = 0.02, green x = 0.98
    "cornell": {
        "middle": [(0.5, 0.5, 0.5), (0.4, 0.35, 0.6), (0.6, 0.65, 0.4)],
        "red-5cm": [(0.07, 0.5, 0.6), (0.07, 0.8, 0.8)],
        "green-5cm": [(0.93, 0.5, 0.4), (0.93, 0.8, 0.3)],
        "low": [(0.5, 0.1, 0.5), (0.45, 0.2, 0.75)],
    },
}
UNITS_NOTE = "E in W/m^2 (glTF units: cd / m^2, lux); RGB mean per receiver; dirs = the 6 axis normals per point"


# ------------------------------------------------------------------ geometry checks
def _glb_json(data: bytes) -> tuple[dict, bytes]:
    js_len = int.from_bytes(data[12:16], "little")
    doc = json.loads(data[20:20 + js_len])
    off = 20 + js_len
    n = int.from_bytes(data[off:off + 4], "little")
    return doc, data[off + 8:off + 8 + n]


def triangles(data: bytes) -> np.ndarray:
    """(T, 3, 3) float64 world-space triangles of a procedural GLB (identity node transforms)."""
    doc, blob = _glb_json(data)
    out = []

    def acc(i, dtype, width):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        arr = np.frombuffer(blob, dtype, a["count"] * width, v["byteOffset"] + a.get("byteOffset", 0))
        return arr.reshape(a["count"], width)

    for mesh in doc["meshes"]:
        for p in mesh["primitives"]:
            pos = acc(p["attributes"]["POSITION"], np.float32, 3).astype(np.float64)
            idx = acc(p["indices"], np.uint32, 1).reshape(-1, 3)
            out.append(pos[idx])
    return np.concatenate(out)


def _crossings(tris: np.ndarray, o, d) -> int:
    o, d = np.asarray(o, float), np.asarray(d, float)
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - tris[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return int((ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)).sum())


def inside(tris: np.ndarray, p) -> bool:
    """Parity test along two oblique directions (they must agree)."""
    a = _crossings(tris, p, (0.3117, 0.8123, 0.4931)) % 2
    b = _crossings(tris, p, (-0.5237, 0.2719, -0.8073)) % 2
    if a != b:
        raise RuntimeError(f"parity disagrees at {p}")
    return bool(a)


def clearance(tris: np.ndarray, p) -> float:
    """A lower bound of the distance from p to the surface: the distance to each triangle's bounding box (exact for
    the axis-aligned grid-cell faces of the procedural scenes, whose triangles are halves of rectangles)."""
    lo, hi = tris.min(axis=1), tris.max(axis=1)
    d = np.maximum(np.maximum(lo - p, 0.0), p - hi)
    return float(np.sqrt((d * d).sum(axis=1)).min())


def probe_grid(data: bytes):
    """counts, origin, spacing of the default bake grid (place stage: counts over the scene bounds)."""
    tris = triangles(data)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    counts = np.array(DEFAULT_COUNTS)
    spacing = (hi - lo) / (counts - 1)
    return counts, lo, spacing


def probe_points(scene: str, data: bytes) -> list[list[float]]:
    tris = triangles(data)
    counts, origin, spacing = probe_grid(data)
    need = PROBE_CLEARANCE.get(scene, 0.15)
    free = []
    for k in range(counts[2]):
        for j in range(counts[1]):
            for i in range(counts[0]):
                p = origin + spacing * np.array([i, j, k])
                p = np.array([float(np.float32(x)) for x in p])  # as the place stage stores them (float32)
                if clearance(tris, p) >= need and not inside(tris, p):
                    free.append(p)
    if not free:
        return []
    pick = np.unique(np.linspace(0, len(free) - 1, min(PROBES_PER_SCENE, len(free))).round().astype(int))
    return [[float(x) for x in free[i]] for i in pick]


def points_doc(scene: str) -> dict:
    data = make_scene(scene)
    tris = triangles(data)
    pts: list[list[float]] = []
    regions: dict[str, list[int]] = {}
    for region, plist in {**REGIONS[scene], "probes": probe_points(scene, data)}.items():
        regions[region] = []
        for p in plist:
            p = [float(x) for x in p]
            c = clearance(tris, np.asarray(p))
            if c < MIN_CLEARANCE or inside(tris, p):
                raise ValueError(f"{scene} {region} point {p} is not in free space (clearance {c:.3f} m)")
            regions[region].append(len(pts))
            pts.append(p)
    counts, origin, spacing = probe_grid(data)
    return {"scene": scene, "points": pts, "regions": regions,
            "probe_grid": {"counts": counts.tolist(), "origin": origin.tolist(), "spacing": spacing.tolist(),
                           "note": "the grid of place.counts = [8, 8, 8] over the scene bounds; "
                                   "'probes' are un-relocated positions of it"},
            "glb_sha256": hashlib.sha256(data).hexdigest()}


def write_points(scene: str) -> Path:
    path = HERE / f"{scene}.points.json"
    path.write_text(json.dumps(points_doc(scene), indent=1) + "\n")
    return path


# ------------------------------------------------------------------ oracle runs
def _strip_punctual(data: bytes) -> bytes:
    """The GLB without its KHR_lights_punctual lights (emissive surfaces stay)."""
    import struct

    doc, blob = _glb_json(data)
    doc.pop("extensions", None)
    doc["extensionsUsed"] = [e for e in doc.get("extensionsUsed", []) if e != "KHR_lights_punctual"]
    if not doc["extensionsUsed"]:
        del doc["extensionsUsed"]
    keep = [i for i, n in enumerate(doc["nodes"]) if "KHR_lights_punctual" not in n.get("extensions", {})]
    remap = {old: new for new, old in enumerate(keep)}
    doc["nodes"] = [doc["nodes"][i] for i in keep]
    for sc in doc["scenes"]:
        sc["nodes"] = [remap[i] for i in sc["nodes"] if i in remap]
    js = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    return b"".join([struct.pack("<III", 0x46546C67, 2, 28 + len(js) + len(blob)),
                     struct.pack("<II", len(js), 0x4E4F534A), js, struct.pack("<II", len(blob), 0x004E4942), blob])


def has_emitters(data: bytes) -> bool:
    doc, _ = _glb_json(data)
    return any(max(m.get("emissiveFactor", [0, 0, 0])) > 0 for m in doc.get("materials", []))


def run_oracle(glb: Path, points: Path, out: Path, *, samples: int, seed: int, material: str, timeout: float,
               log: Path, reuse: bool = False) -> tuple[dict, float]:
    if reuse and out.exists() and out.with_suffix(".wall").exists():
        res = json.loads(out.read_text())
        npts = len(json.loads(points.read_text())["points"])
        if (res["samples"], res["material"], res["seed"], len(res["points"])) == (samples, material, seed, npts) \
                and res.get("glb_sha256") == hashlib.sha256(glb.read_bytes()).hexdigest():
            return res, float(out.with_suffix(".wall").read_text())
    cmd = ["nice", "-n", "10", shutil.which("blender") or "blender", "-b", "--factory-startup", "--python",
           str(WRAPPER), "--", str(glb), str(points), str(out), "--samples", str(samples), "--bounces", "64",
           "--seed", str(seed), "--sky", "0,0,0", "--material", material]
    if material == "importer":
        cmd += ["--glossy", str(GLOSSY)]
    t0 = time.perf_counter()
    with open(log, "w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, timeout=timeout,
                           env={**os.environ, "KILN_ORACLE": str(ORACLE)})
    wall = time.perf_counter() - t0
    if r.returncode != 0 or not out.exists():
        raise RuntimeError(f"oracle failed ({r.returncode}); see {log}:\n" + log.read_text()[-3000:])
    res = json.loads(out.read_text())
    res["glb_sha256"] = hashlib.sha256(glb.read_bytes()).hexdigest()
    out.write_text(json.dumps(res))
    out.with_suffix(".wall").write_text(f"{wall:.2f}")
    return res, wall


def _r(x, digits=6):
    """Round nested floats to ``digits`` significant digits (small files)."""
    a = np.asarray(x, np.float64)
    with np.errstate(divide="ignore"):
        mag = np.where(a == 0, 0, np.floor(np.log10(np.abs(np.where(a == 0, 1, a)))))
    scale = 10.0 ** (digits - 1 - mag)
    return (np.round(a * scale) / scale).tolist()


def reference(scene: str, material: str, samples: int, seeds: list[int], timeout: float, work: Path,
              reuse: bool = False, emit_seeds: int | None = None) -> dict:
    data = make_scene(scene)
    glb = work / f"{scene}.glb"
    glb.write_bytes(data)
    pdoc = json.loads((HERE / f"{scene}.points.json").read_text())
    if pdoc["glb_sha256"] != hashlib.sha256(data).hexdigest():
        raise RuntimeError(f"{scene}.points.json was made for another version of the scene: rerun --points-only")
    pts = work / f"{scene}.points.json"
    pts.write_text(json.dumps({"points": pdoc["points"]}))
    emit = has_emitters(data)
    if emit:
        (work / f"{scene}.emit.glb").write_bytes(_strip_punctual(data))
    runs, walls, emit_runs, emit_walls = [], [], [], []
    for seed in seeds:
        out = work / f"{scene}.{material}.{seed}.json"
        res, wall = run_oracle(glb, pts, out, samples=samples, seed=seed, material=material, timeout=timeout,
                               log=work / f"{out.stem}.log", reuse=reuse)
        runs.append(res)
        walls.append(wall)
        print(f"  {scene} {material} seed {seed}: {wall:.0f} s wall ({res['bake_s']:.0f} s baking), "
              f"{res['n_receivers']} receivers", flush=True)
        if emit and (emit_seeds is None or len(emit_runs) < emit_seeds):
            out = work / f"{scene}.{material}.{seed}.emit.json"
            res, wall = run_oracle(work / f"{scene}.emit.glb", pts, out, samples=samples, seed=seed,
                                   material=material, timeout=timeout, log=work / f"{out.stem}.log", reuse=reuse)
            emit_runs.append(res)
            emit_walls.append(wall)
            print(f"  {scene} {material} seed {seed} (emitters only): {wall:.0f} s", flush=True)
    d = np.array([r["E_direct_rgb"] for r in runs])      # (S, P, 6, 3)
    i = np.array([r["E_indirect_rgb"] for r in runs])
    probe = i + (np.array([r["E_direct_rgb"] for r in emit_runs]).mean(0) if emit else 0.0)
    lum = probe.mean(-1)                                  # (S, P, 6)
    spread = {}
    S = len(seeds)
    if S >= 2:
        m = lum.mean(0)
        ok = m > 1e-9 * max(float(m.max()), 1e-30)
        sem = lum.std(0, ddof=1) / math.sqrt(S)
        spread["receiver_rel_sem_rms"] = float(np.sqrt(np.mean((sem[ok] / m[ok]) ** 2))) if ok.any() else 0.0
        spread["region_rel_spread"], spread["region_rel_sem"] = {}, {}
        for reg, idx in pdoc["regions"].items():
            r = lum[:, idx].mean(axis=(1, 2))            # (S,) region means per seed
            mu = float(r.mean())
            spread["region_rel_spread"][reg] = float(r.max() - r.min()) / mu if mu > 0 else 0.0
            spread["region_rel_sem"][reg] = float(r.std(ddof=1) / math.sqrt(S)) / mu if mu > 0 else 0.0
        spread["note"] = (f"over {S} seeds, of E_probe (RGB mean): per region (max - min) / mean of the seeds' region "
                          "means, and the standard error of their mean / mean; per receiver the RMS of its relative "
                          "standard error")
    return {
        "scene": scene, "material": material,
        "oracle": {"script": "cycles_irradiance_points.py (../shared/oracle) via tests/data/fidelity/"
                             "oracle_lambert_textures.py (Lambert albedo follows metallic textures; emission kept)",
                   "blender": runs[0].get("blender", "3.4.1")},
        "settings": {"samples": samples, "bounces": runs[0]["bounces"], "glossy_bounces": GLOSSY
                     if material == "importer" else 0, "sky": [0, 0, 0], "layout": runs[0]["layout"],
                     "lighting_mode": runs[0]["lighting_mode"], "material": material},
        "seeds": seeds, "wall_seconds": [round(w, 1) for w in walls],
        "bake_seconds": [r["bake_s"] for r in runs],
        "emitter_runs": {"seeds": seeds[:len(emit_runs)], "wall_seconds": [round(w, 1) for w in emit_walls],
                         "note": "punctual lights removed: their E_direct (mean over these seeds) is the emitters' "
                                 "direct light, added to every seed's E_indirect"}
        if emit else None,
        "glb_sha256": pdoc["glb_sha256"], "units": UNITS_NOTE,
        "points": pdoc["points"], "dirs": AXES, "regions": pdoc["regions"],
        "E_direct_rgb": _r(d.mean(0)), "E_indirect_rgb": _r(i.mean(0)), "E_probe_rgb": _r(probe.mean(0)),
        "E_probe_note": "what a probe stores: E_indirect, plus the emissive surfaces' direct light (Cycles counts it "
                        "as direct)" + ("; this scene has emitters" if emit else "; no emitters: = E_indirect"),
        "spread": spread,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="two-rooms-vc,metal-room")
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--materials", default=None, help="comma list (default: lambert, plus importer for metal-room)")
    ap.add_argument("--points-only", action="store_true", help="only (re)write the points files")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per Blender run")
    ap.add_argument("--keep", type=Path, default=None, help="keep the oracle outputs and logs here")
    ap.add_argument("--emit-seeds", type=int, default=None, help="emitter-only runs for the first N seeds only "
                    "(scenes with emitters; default: every seed)")
    ap.add_argument("--reuse", action="store_true", help="reuse per-seed oracle outputs found in --keep (same "
                    "scene bytes, points, samples, material, seed)")
    args = ap.parse_args()
    scenes = [s for s in args.scenes.split(",") if s]
    for s in scenes:
        if s not in ALL_SCENES or s not in REGIONS:
            raise SystemExit(f"no check points for scene {s!r}; have {', '.join(REGIONS)}")
    for s in scenes:
        p = write_points(s)
        doc = json.loads(p.read_text())
        print(f"{p.name}: {len(doc['points'])} points, regions "
              + ", ".join(f"{k} {len(v)}" for k, v in doc["regions"].items()))
    if args.points_only:
        return
    seeds = [int(x) for x in args.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for s in scenes:
            mats = args.materials.split(",") if args.materials else MATERIALS.get(s, ("lambert",))
            for m in mats:
                t0 = time.perf_counter()
                ref = reference(s, m, args.samples, seeds, args.timeout, work, reuse=args.reuse,
                                emit_seeds=args.emit_seeds)
                out = HERE / f"{s}.{m}.cycles.json"
                out.write_text(json.dumps(ref, separators=(",", ":")) + "\n")
                spr = {k: round(v, 4) for k, v in ref["spread"].get("region_rel_spread", {}).items()}
                print(f"{out.name}: {time.perf_counter() - t0:.0f} s; seed spread {spr}", flush=True)


if __name__ == "__main__":
    main()
