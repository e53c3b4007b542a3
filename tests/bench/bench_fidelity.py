"""Fidelity benchmark (outside check of materials and default bakes): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_fidelity.py [--scenes two-rooms-vc,metal-room,living-room] [--json OUT.json]
        [--store DIR]

Compares Kiln's baked light with Blender Cycles (tests/data/fidelity/*.cycles.json, made by
tests/data/fidelity/make_references.py with ../shared/oracle; Blender is not needed here). By default every scene
with a points file in tests/data/fidelity (:data:`DEFAULT_SCENES`). Per scene:

1. bakes the scene in this process with the real pipeline and the **default config**, timing each stage: a
   procedural scene (``workers.procedural.make_scene``) with ``BakeConfig()`` (the scenes carry their own lights and
   emitters; sky 0); a real scene (its points file names a ``source`` under ``../shared/scenes``, read there, never
   copied into the project; ``KILN_SHARED_SCENES`` sets the folder; skipped with a message when absent) with the
   default config plus the points file's ``config`` — only added lights (``scene.lights``) and a sky (``scene.sky``):
   ``living-room`` is godot-living-room's living_room.glb (no lights of its own) with two point lights and a sky
   through its courtyard. The automatic grid's reason (``grid.auto.reason``) is printed with the bake time;
2. at every check point of ``<scene>.points.json`` and each of the 6 axis normals, reconstructs the indirect
   irradiance of each GI mode from the baked volumes with the Python references of the runtime shaders:
   ``leaking``, ``visibility_weighted``, ``mask``, ``mask_normalized`` (:func:`workers.kernels.samplers.irradiance`,
   mask offset = the runtime default) and ``ddgi`` (:func:`workers.kernels.ddgi.sample_irradiance` on the light
   stage's octahedral irradiance, the trace stage's depth moments, relocated probes, self-shadow bias of the config).
   The points are receivers in free space, so the view direction is taken equal to the normal (a viewer in front
   of a surface facing n);
3. at the probes of the default bake's OWN grid, where ``default-probes/<scene>.points.json`` has some (rows
   ``probes-dark*``, ``probes-lit*``: un-relocated positions of the automatic grid's probes in two-rooms' dark and lit
   rooms, their Cycles references made by ``tests/data/fidelity/make_probe_references.py``): the light stage's
   stored values there (``probe_oct``, ``probe_sh`` as below) — issue 12's "stored probe values within 5% of Cycles at
   the probe positions in a dark room next to a lit one, at the default spacing". When the default grid is no longer
   the one recorded there, the table says so (regenerate the points and references);
   and at the ``probes`` region (un-relocated positions, in free space, of the grid ``place.counts = [8, 8, 8]`` over
   the scene bounds, recorded in the points file) also the light stage's **stored** values of that very probe: its
   octahedral irradiance map (``probe_oct``, bilinear, the map DDGI samples) and its L2 SH (``probe_sh``, linear
   evaluation) — only for probes the relocation moved by less than :data:`MAX_PROBE_SHIFT` and that are not OFF.
   Taken from the default bake when its grid has probes there; else (the automatic default grid) from a second
   bake with only ``place.counts = [8, 8, 8]`` set;
4. also path-traces the same receivers with Kiln's own reference path tracer
   (:func:`workers.kernels.pathtrace.indirect_irradiance`, ``--pt-spp`` paths, 64 bounces, Russian roulette from
   vertex 3): ``kiln_pt``. It reads the scene through Kiln's ingest but has no probes, so ``kiln_pt`` != 1 points
   at the scene reading (materials, lights, units) and ``kiln_pt`` ~ 1 with a mode != 1 at the probe pipeline.
   In scenes with metals also ``kiln_pt_diffuse`` (column ``pt_diffuse``): the same with ``scene.specular_gi =
   "none"``, i.e. Kiln's albedo reduced to glTF's diffuse term base x (1 - metallic), the lambert reference's model
   (the default ``"metals"`` adds a diffuse equivalent of the metals' specular lobe, which that reference lacks);
5. prints per scene and reference material a table region x mode of ``mean(kiln) / mean(cycles)`` (means over the
   region's receivers of the RGB mean; cycles = ``E_probe``: the indirect light, plus emitters' direct light in
   scenes with emitters), and the bake time. Where the Cycles mean is ~0 (a sealed cavity) the cell shows Kiln's
   absolute mean instead (``=<value>``). The JSON (``--json``) also holds per-channel ratios and per-receiver
   relative RMS errors.

``furnace`` has no Cycles reference but a closed form (``furnace.closed-form.reference.json``, made by
``tests/data/fidelity/make_closed_form.py``): the default config with a uniform sky of radiance 1, where every receiver
gets E = π whatever its normal — a white furnace for every mode, the light stage's bounces and the automatic grid
around a scene that is almost nothing (one 1 mm triangle).

``metal-room`` has two references: ``lambert`` (every surface diffuse with albedo base x (1 - metallic): the
model of a diffuse-only probe bake) and ``importer`` (Blender's Principled BSDF with glossy bounces; Blender 3.4
adds its specular lobe on top of an undimmed diffuse, so closed bright rooms read ~20-27% above a diffuse model:
an upper bracket, not a target).

Sanity (the issue's "no NaN, no negative irradiance"): per scene the number of receivers where a mode (or Kiln's path
tracer, or a compared stored probe) gives a non-finite or a negative value in any channel, and the non-finite values
and negative texels in the bake's irradiance volumes themselves; printed as ``sanity: ...`` (``FLAG`` when any).
The Python references do not clamp: the GLSL modes clamp their result at 0, so a negative here is the value before
that clamp.
"""
from __future__ import annotations

import argparse
import copy
import hashlib
import json
import math
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
from workers.kernels import samplers as SM  # noqa: E402
from workers.kernels.ddgi import sample_irradiance  # noqa: E402
from workers.kernels.grid import OFF, unpack_atlas  # noqa: E402
from workers.kernels.octahedral import bilinear_sample  # noqa: E402
from workers.kernels.pathtrace import indirect_irradiance  # noqa: E402
from workers.kernels.sh import sh_irradiance  # noqa: E402
from workers.procedural import make_scene  # noqa: E402

DATA = ROOT / "tests" / "data" / "fidelity"
MODES = ("leaking", "visibility_weighted", "ddgi", "mask", "mask_normalized")
PROBE_MODES = ("probe_oct", "probe_sh")
PT_BOUNCES, PT_RR_DEPTH = 64, 3
MAX_PROBE_SHIFT = 0.02  # metres: a probe relocated further than this is not compared at its grid position
ZERO = 1e-3             # a region whose Cycles mean is below ZERO x the scene's largest region mean counts as dark
DEFAULT_SCENES = ",".join(sorted(p.name[:-len(".points.json")] for p in DATA.glob("*.points.json")))
SHARED_SCENES = Path(os.environ.get("KILN_SHARED_SCENES", ROOT.parent / "shared" / "scenes"))


def deep_merge(a: dict, b: dict) -> dict:
    out = copy.deepcopy(a)
    for k, v in b.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def source_of(pdoc: dict) -> Path | None:
    """The file a real scene's points file names (None for a procedural scene)."""
    return SHARED_SCENES / pdoc["source"] if pdoc.get("source") else None


def scene_bytes(name: str, pdoc: dict) -> bytes:
    src = source_of(pdoc)
    return src.read_bytes() if src else make_scene(name)


def bake(name: str, work: Path, store_dir: Path | None, config: dict | None = None, source: Path | None = None):
    """Bake scene ``name`` (procedural, or the real scene at ``source``, read in place) with ``config`` (default:
    the default config, ``BakeConfig()``): (scene, {stage: LazyArtifacts}, config, seconds per stage)."""
    if source is not None:
        glb = source
    else:
        glb = work / f"{name}.glb"
        glb.write_bytes(make_scene(name))
    store = Store(store_dir or (work / "store"))
    t0 = time.perf_counter()
    scene = ingest_file(glb)
    t_ingest_file = time.perf_counter() - t0
    sid = store.put_bytes(scene.to_bytes())
    cfg = BakeConfig.model_validate(config or {})
    recs, times = {}, {"ingest_file": t_ingest_file}
    for st, _ in plan(sid, cfg):
        t0 = time.perf_counter()
        rec, cached = pipeline.execute_stage(store, sid, cfg, st.name)
        times[st.name] = time.perf_counter() - t0
        if cached:
            times[st.name + " (cached)"] = times.pop(st.name)
        recs[st.name] = pipeline._lazy(store, rec)
    return scene, recs, cfg, times


def merged_arrays(recs: dict) -> dict:
    out = {}
    for st in ("relocate", "trace", "light", "visibility", "masks", "compress"):
        if st in recs:
            for n in recs[st].names():
                out[n] = recs[st][n]
    return out


def reconstruct(recs: dict, cfg: BakeConfig, pts: np.ndarray, nrm: np.ndarray) -> dict[str, np.ndarray]:
    """(N, 3) indirect irradiance of each mode at receivers (pts, nrm); views = nrm."""
    place = recs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    arrays = merged_arrays(recs)
    out = {}
    for mode in MODES:
        if mode == "ddgi":
            counts = grid["counts"]
            n2 = cfg.light.irradiance_texels + 2
            m2 = cfg.trace.depth_texels + 2
            irr = unpack_atlas(arrays["irradiance"], counts, n2)[..., :3]
            depth = unpack_atlas(arrays["depth_moments"], counts, m2)
            pos = np.asarray(arrays["probe_positions_relocated"]).reshape(-1, 3)
            states = np.asarray(arrays["probe_states"]).reshape(-1)
            out[mode] = np.asarray(sample_irradiance(pts, nrm, nrm, counts, grid["origin"], grid["spacing"], pos, states,
                                                     irr, depth, cfg.light.self_shadow_bias), np.float64)
        else:
            try:
                out[mode] = SM.irradiance(mode, arrays, grid, pts, nrm, views=nrm if mode.startswith("mask") else None)
            except KeyError as e:  # an artifact this bake does not have
                print(f"  {mode}: skipped (no {e})")
    return out


def probe_values(recs: dict, cfg: BakeConfig, points: np.ndarray, dirs: np.ndarray) -> tuple[dict, list[dict]]:
    """The light stage's stored irradiance of the probe at each of ``points`` (grid positions): {mode: (K, 6, 3)}
    (NaN where not comparable) and per point {index, shift, state}."""
    place = recs["place"].stats
    counts = np.asarray(place["counts"])
    origin, spacing = np.asarray(place["origin"]), np.asarray(place["spacing"])
    arrays = merged_arrays(recs)
    nx, ny, nz = counts
    irr = unpack_atlas(arrays["irradiance"], counts, cfg.light.irradiance_texels + 2)[..., :3]
    sh = np.asarray(arrays["probe_sh"]).reshape(nx * ny * nz, -1, 3)
    pos = np.asarray(arrays["probe_positions_relocated"]).reshape(-1, 3)
    states = np.asarray(arrays["probe_states"]).reshape(-1)
    out = {m: np.full((len(points), len(dirs), 3), np.nan) for m in PROBE_MODES}
    info = []
    for k, p in enumerate(points):
        ijk = np.rint((p - origin) / np.where(spacing > 0, spacing, 1.0)).astype(int)
        on_grid = bool(np.all((0 <= ijk) & (ijk < counts))
                       and np.linalg.norm(origin + spacing * ijk - p) < 1e-4)
        if not on_grid:
            info.append({"point": p.tolist(), "on_grid": False})
            continue
        i = int(ijk[0] + nx * (ijk[1] + ny * ijk[2]))
        shift = float(np.linalg.norm(pos[i] - (origin + spacing * ijk)))
        rec = {"point": p.tolist(), "on_grid": True, "probe": i, "shift": shift, "state": int(states[i])}
        rec["compared"] = bool(states[i] != OFF and shift < MAX_PROBE_SHIFT)
        info.append(rec)
        if rec["compared"]:
            out["probe_oct"][k] = bilinear_sample(irr[i].astype(np.float64), dirs)
            out["probe_sh"][k] = sh_irradiance(sh[i], dirs)
    return out, info


def default_grid_probes(name: str, recs: dict, cfg: BakeConfig, dirs: np.ndarray) -> dict | None:
    """The light stage's stored values at probes of the DEFAULT bake's own grid (issue 12 item 2), against the
    Cycles references of ``default-probes/<scene>.*.cycles.json`` (made by make_probe_references.py).

    None when the scene has no such points; ``{"note": ...}`` without values when the default grid is no longer the
    one the points were taken from. Else ``values`` {probe_oct, probe_sh: (P, 6, 3)} (NaN where not compared),
    ``regions``, ``refs`` {material: E_probe (P, 6, 3)}, ``probes`` (per point: index, shift, state)."""
    path = DATA / "default-probes" / f"{name}.points.json"
    if not path.is_file():
        return None
    pdoc = json.loads(path.read_text())
    place = recs["place"].stats
    g = pdoc["probe_grid"]
    same = (list(place["counts"]) == list(g["counts"]) and np.allclose(place["origin"], g["origin"], atol=1e-6)
            and np.allclose(place["spacing"], g["spacing"], atol=1e-6))
    if not same:
        return {"note": f"the default grid is now {place['counts']} (the points were taken from {g['counts']}): "
                        "regenerate them with tests/data/fidelity/make_probe_references.py"}
    refs = {}
    for p in sorted(path.parent.glob(f"{name}.*.cycles.json")):
        ref = json.loads(p.read_text())
        if ref["points"] != pdoc["points"]:
            return {"note": f"{p.name} was made for other points: regenerate it"}
        refs[ref["material"]] = ref.get("E_probe_rgb", ref["E_indirect_rgb"])
        sems = {f"{k}*": v for k, v in (ref.get("spread") or {}).get("region_rel_sem", {}).items()}
    if not refs:
        return {"note": f"no Cycles reference beside {path.name}: run make_probe_references.py"}
    values, info = probe_values(recs, cfg, np.asarray(pdoc["points"], np.float64), dirs)
    return {"values": values, "regions": pdoc["regions"], "refs": refs, "probes": info, "region_rel_sem": sems,
            "compared": sum(1 for p in info if p.get("compared")), "of": len(info)}


def compare(kiln: np.ndarray, ref: np.ndarray, idx: list[int]) -> dict:
    """kiln, ref (P, 6, 3); idx: the region's points. Ratio of region means (RGB mean and per channel) and the
    per-receiver relative RMS error (receivers with ref > 0)."""
    k, r = kiln[idx], ref[idx]
    ok = np.isfinite(k).all(axis=-1)
    if not ok.any():
        return {}
    k, r = k[ok], r[ok]
    km, rm = float(k.mean()), float(r.mean())
    rl, kl = r.mean(-1), k.mean(-1)
    pos = rl > 1e-9
    return {"kiln_mean": km, "cycles_mean": rm, "ratio": km / rm if rm > 0 else None,
            "ratio_rgb": [float(a / b) if b > 0 else None for a, b in zip(k.mean(0), r.mean(0))],
            "kiln_mean_rgb": k.mean(0).tolist(), "cycles_mean_rgb": r.mean(0).tolist(),
            "receiver_rel_rms": float(np.sqrt(np.mean(((kl[pos] - rl[pos]) / rl[pos]) ** 2))) if pos.any() else None,
            "receivers": int(k.shape[0])}


def sanity(modes: dict[str, np.ndarray], probes: dict[str, np.ndarray], probe_idx: list[int], recs: dict,
           cfg: BakeConfig) -> dict:
    """Non-finite and negative irradiance: per mode at the receivers (probe_oct / probe_sh: at the compared probes
    only), and in the bake's irradiance volumes (octahedral atlas texels of non-OFF probes; every float volume of
    the light and compress stages for non-finite values)."""
    out = {"receivers": {}, "volumes": {}}
    for m, v in {**modes, **probes}.items():
        if m in probes:
            v = v[probe_idx]
            v = v[np.isfinite(v).all(axis=(-1, -2))]         # not compared: NaN rows by construction
        v = np.asarray(v, np.float64).reshape(-1, 3)
        bad = ~np.isfinite(v).all(axis=-1)
        neg = (np.where(np.isfinite(v), v, 0.0) < 0).any(axis=-1)
        out["receivers"][m] = {"n": int(v.shape[0]), "nonfinite": int(bad.sum()), "negative": int(neg.sum()),
                               "min": float(np.nanmin(v)) if v.size and np.isfinite(v).any() else None}
    for st in ("light", "compress"):
        if st not in recs:
            continue
        for n in recs[st].names():
            try:
                a = np.asarray(recs[st][n])
            except Exception:  # noqa: BLE001  (not an array artifact)
                continue
            if a.dtype.kind != "f":
                continue
            nf = int((~np.isfinite(a)).sum())
            rec = {"size": int(a.size), "nonfinite": nf}
            if n == "irradiance":
                counts = recs["place"].stats["counts"]
                irr = unpack_atlas(a, counts, cfg.light.irradiance_texels + 2)[..., :3]
                states = np.asarray(recs["trace"]["probe_states"]).reshape(-1)
                on = irr[states != OFF]
                rec["negative_texels"] = int((np.where(np.isfinite(on), on, 0.0) < 0).any(axis=-1).sum())
                rec["min"] = float(np.nanmin(on)) if on.size else None
            out["volumes"][f"{st}/{n}"] = rec
    out["flag"] = any(r["nonfinite"] or r["negative"] for r in out["receivers"].values()) or any(
        r["nonfinite"] or r.get("negative_texels") for r in out["volumes"].values())
    return out


def run_scene(name: str, work: Path, store_dir: Path | None, pt_spp: int = 16384,
              overrides: dict | None = None) -> dict | None:
    """The comparison of scene ``name``; None (with a message) for a real scene whose source is not there."""
    pdoc = json.loads((DATA / f"{name}.points.json").read_text())
    source = source_of(pdoc)
    if source is not None and not source.is_file():
        print(f"skipping {name}: its source {source} is not there (a real scene, read from {SHARED_SCENES}, never "
              f"copied into the project; KILN_SHARED_SCENES sets the folder)", flush=True)
        return None
    scene_config = pdoc.get("config") or {}
    refs = {}
    for path in sorted([*DATA.glob(f"{name}.*.cycles.json"), *DATA.glob(f"{name}.*.reference.json")]):
        ref = json.loads(path.read_text())
        refs[ref["material"]] = ref
    if not refs:
        raise SystemExit(f"no Cycles reference for {name} in {DATA}: run tests/data/fidelity/make_references.py")
    sha = hashlib.sha256(scene_bytes(name, pdoc)).hexdigest()
    notes = []
    if pdoc["glb_sha256"] != sha:
        notes.append(f"{name}.points.json was made for another version of the scene: regenerate the points and "
                     "references")
    for m, ref in refs.items():
        if ref["glb_sha256"] != sha or ref["points"] != pdoc["points"] or (ref.get("config") or {}) != scene_config:
            notes.append(f"reference {m} was made for another version of the scene, points or lights: regenerate it")
    t0 = time.perf_counter()
    scene, recs, cfg, times = bake(name, work, store_dir, deep_merge(scene_config, overrides or {}), source)
    bake_seconds = time.perf_counter() - t0
    points = np.asarray(pdoc["points"], np.float64)
    dirs = np.asarray(next(iter(refs.values()))["dirs"], np.float64)
    P, D = len(points), len(dirs)
    pts = np.repeat(points, D, axis=0)
    nrm = np.tile(dirs, (P, 1))
    modes = {m: v.reshape(P, D, 3) for m, v in reconstruct(recs, cfg, pts, nrm).items()}
    pt_seconds = None
    if pt_spp > 0:
        lit = recs["ingest"]["lights"]
        t0 = time.perf_counter()
        pt = indirect_irradiance(scene, pts, nrm, lit["lights"], sky=lit["sky"], spp=pt_spp, bounces=PT_BOUNCES,
                                 rr_depth=PT_RR_DEPTH, seed=cfg.seed)
        pt_seconds = time.perf_counter() - t0
        extra = {}
        if any(float(m.get("metallic", 0.0)) > 0 for m in scene.materials):
            # metals: Kiln's GI albedo adds a diffuse equivalent of their specular lobe (scene.specular_gi, default
            # "metals"); with "none" it is glTF's diffuse term, base x (1 - metallic): the lambert oracle's model
            scene.specular_gi = "none"
            pt2 = indirect_irradiance(scene, pts, nrm, lit["lights"], sky=lit["sky"], spp=pt_spp, bounces=PT_BOUNCES,
                                      rr_depth=PT_RR_DEPTH, seed=cfg.seed)
            scene.specular_gi = cfg.scene.specular_gi
            extra["kiln_pt_diffuse"] = np.asarray(pt2.irradiance, np.float64).reshape(P, D, 3)
        modes = {"kiln_pt": np.asarray(pt.irradiance, np.float64).reshape(P, D, 3), **extra, **modes}
    probe_idx = pdoc["regions"].get("probes", [])
    probes, probe_info, probe_bake = ({}, [], None)
    if probe_idx:
        pv, probe_info = probe_values(recs, cfg, points[probe_idx], dirs)
        probe_bake = {"config": "default", "seconds": None}
        if not any(p.get("compared") for p in probe_info) and pdoc.get("probe_grid"):
            # the default grid does not hold these points: bake the points file's grid to read its stored probes
            g = {"place": {"counts": pdoc["probe_grid"]["counts"]}}
            t1 = time.perf_counter()
            _, recs2, cfg2, _ = bake(name, work, store_dir, deep_merge(scene_config, g), source)
            probe_bake = {"config": g, "seconds": time.perf_counter() - t1}
            pv, probe_info = probe_values(recs2, cfg2, points[probe_idx], dirs)
        for m, v in pv.items():
            full = np.full((P, D, 3), np.nan)
            full[probe_idx] = v
            probes[m] = full
    default_probes = default_grid_probes(name, recs, cfg, dirs)
    place = recs["place"].stats
    lit = recs["ingest"]["lights"]
    out = {"scene": name, "bake_seconds": bake_seconds, "stage_seconds": times,
           "config": "default (BakeConfig())" + (f" + {json.dumps(scene_config)}" if scene_config else "")
           + (f" + EXPERIMENT {json.dumps(overrides)}" if overrides else ""),
           "source": pdoc.get("source"), "triangles": int(np.asarray(scene.triangles).shape[0]),
           "lights": len(lit["lights"]), "sky": list(lit["sky"]),
           "sanity": sanity(modes, probes, probe_idx, recs, cfg),
           "kiln_pt": {"spp": pt_spp, "bounces": PT_BOUNCES, "rr_depth": PT_RR_DEPTH, "seconds": pt_seconds},
           "grid": {k: place[k] for k in ("counts", "origin", "spacing")},
           "grid_auto": place.get("auto"),
           "light": {k: recs["light"].stats.get(k) for k in ("bounces", "converged", "mean_irradiance")},
           "probes_off": int((np.asarray(recs["trace"]["probe_states"]).reshape(-1) == OFF).sum()),
           "ingest_warnings": list(scene.warnings), "notes": notes, "probes": probe_info, "probe_bake": probe_bake,
           "default_probes": default_probes and {k: v for k, v in default_probes.items() if k != "values"},
           "references": {}}
    for mat, ref in refs.items():
        target = np.asarray(ref.get("E_probe_rgb", ref["E_indirect_rgb"]), np.float64)
        regs = {}
        for region, idx in pdoc["regions"].items():
            row = {"cycles_mean": float(target[idx].mean()), "modes": {}}
            for m, v in {**modes, **(probes if region == "probes" else {})}.items():
                c = compare(v, target, idx)
                if c:
                    row["modes"][m] = c
            regs[region] = row
        if default_probes and default_probes.get("values") and mat in default_probes["refs"]:
            # the default bake's own probes (default-probes/<scene>.points.json): stored values against their reference
            dref = np.asarray(default_probes["refs"][mat], np.float64)
            for region, idx in default_probes["regions"].items():
                row = {"cycles_mean": float(dref[idx].mean()), "modes": {}}
                for m, v in default_probes["values"].items():
                    c = compare(v, dref, idx)
                    if c:
                        row["modes"][m] = c
                regs[f"{region}*"] = row
        out["references"][mat] = {"regions": regs, "settings": ref["settings"], "seeds": ref["seeds"],
                                  "spread": ref.get("spread", {})}
    return out


def table(res: dict) -> list[str]:
    lines = []
    cols = ["kiln_pt", "kiln_pt_diffuse", *MODES, *PROBE_MODES]
    for mat, r in res["references"].items():
        regs = r["regions"]
        top = max((abs(v["cycles_mean"]) for v in regs.values()), default=0.0)
        sky = r["settings"].get("sky") or [0, 0, 0]
        if r["settings"].get("closed_form"):
            lines.append(f"== {res['scene']} vs the closed form (E = pi x L_sky on every normal, sky {sky}): "
                         "mean(kiln)/mean(closed form); the 'cycles W/m2' column is the closed form's value")
        else:
            lines.append(f"== {res['scene']} vs Cycles {mat} ({r['settings']['samples']} spp x {len(r['seeds'])} "
                         f"seeds, {r['settings']['bounces']} bounces{f', sky {sky}' if max(sky) > 0 else ''}): "
                         "mean(kiln)/mean(cycles) of the indirect irradiance"
                         + (" (+ the sky seen directly)" if max(sky) > 0 else ""))
        lines.append(f"{'region':<13}{'cycles W/m2':>12}" + "".join(f"{c:>11}" for c in
                     ("kiln_pt", "pt_diffuse", "leaking", "vis_wtd", "ddgi", "mask", "mask_norm", "probe_oct", "probe_sh")) + f"{'ref sem':>9}")
        spr = {**(r.get("spread") or {}).get("region_rel_sem", {}),
               **((res.get("default_probes") or {}).get("region_rel_sem") or {})}
        for region, row in regs.items():
            cells = []
            dark = row["cycles_mean"] < ZERO * top
            for c in cols:
                v = row["modes"].get(c)
                if v is None:
                    cells.append(f"{'-':>11}")
                elif dark or v["ratio"] is None:
                    cells.append(f"{'=' + format(v['kiln_mean'], '.2e'):>11}")
                else:
                    cells.append(f"{v['ratio']:>11.3f}")
            s = spr.get(region)
            lines.append(f"{region:<13}{row['cycles_mean']:>12.4g}" + "".join(cells)
                         + (f"{100 * s:>8.1f}%" if s is not None else f"{'':>9}"))
    st = res["stage_seconds"]
    slow = sorted(((v, k) for k, v in st.items()), reverse=True)[:4]
    lines.append(f"bake {res['bake_seconds']:.1f} s ({res['config']}; {res['triangles']} triangles, "
                 f"{res['lights']} lights; grid {res['grid']['counts']} = {int(np.prod(res['grid']['counts']))} probes; "
                 "slowest: " + ", ".join(f"{k} {v:.1f}" for v, k in slow) + ")")
    auto = res.get("grid_auto") or {}
    lines.append(f"grid.auto.reason: {auto.get('reason', '- (explicit grid)')}")
    san = res["sanity"]
    bad = [f"{m}: {v['nonfinite']} non-finite, {v['negative']} negative of {v['n']} (min {v['min']:.3g})"
           for m, v in san["receivers"].items() if v["nonfinite"] or v["negative"]]
    bad += [f"{n}: {v['nonfinite']} non-finite" + (f", {v.get('negative_texels')} negative texels (min "
                                                   f"{v['min']:.3g})" if v.get("negative_texels") else "")
            for n, v in san["volumes"].items() if v["nonfinite"] or v.get("negative_texels")]
    lines.append("sanity: " + ("FLAG " + "; ".join(bad) if bad else
                               f"no NaN, no negative irradiance ({len(san['receivers'])} modes at the receivers, "
                               f"{len(san['volumes'])} volumes)"))
    n_cmp = sum(1 for p in res["probes"] if p.get("compared"))
    lines.append(f"light stage: {res['light']['bounces']} bounces, converged {res['light']['converged']}; "
                 f"{res['probes_off']} of {int(np.prod(res['grid']['counts']))} probes OFF")
    if res["probes"]:
        pb = res["probe_bake"] or {}
        src = "the default bake" if pb.get("config") == "default" else \
            f"a second bake with {pb.get('config')} ({pb.get('seconds', 0):.1f} s; the default grid holds no such probe)"
        lines.append(f"probe_oct / probe_sh: stored values of {n_cmp}/{len(res['probes'])} probes of {src} "
                     f"(not OFF, relocated < {MAX_PROBE_SHIFT * 100:.0f} cm)")
    dp = res.get("default_probes")
    if dp:
        lines.append("probes-dark* / probes-lit*: " + (dp["note"] if "note" in dp else
                     f"stored values of {dp['compared']}/{dp['of']} probes of the DEFAULT bake's own grid at their "
                     "un-relocated positions (default-probes/, not OFF, relocated < "
                     f"{MAX_PROBE_SHIFT * 100:.0f} cm); the other columns there are empty"))
    for w in res["ingest_warnings"]:
        lines.append(f"ingest warning: {w}")
    for n in res["notes"]:
        lines.append(f"note: {n}")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=DEFAULT_SCENES, help="comma list of scenes with points and references "
                    f"(default: all, {DEFAULT_SCENES})")
    ap.add_argument("--json", type=Path, default=None, help="write the results as JSON here")
    ap.add_argument("--store", type=Path, default=None, help="stage store to reuse (default: a fresh temp store)")
    ap.add_argument("--pt-spp", type=int, default=16384, help="paths per receiver of Kiln's path tracer (0: skip)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=JSON",
                    help="a config override on top of the default (an experiment, not the default: the table says "
                         "so), e.g. --set masks.clusters=8; repeatable")
    args = ap.parse_args()
    overrides: dict = {}
    for item in args.set:
        key, _, value = item.partition("=")
        node = overrides
        *path, leaf = key.split(".")
        for k in path:
            node = node.setdefault(k, {})
        node[leaf] = json.loads(value)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in [s for s in args.scenes.split(",") if s]:
            print(f"baking {name} ...", flush=True)
            res = run_scene(name, Path(tmp), args.store, args.pt_spp, overrides)
            if res is None:
                continue
            results[name] = res
            print("\n".join(table(res)), flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=_json_default) + "\n")
        print(f"wrote {args.json}")
    return 0


def _json_default(x):
    if isinstance(x, (np.floating, np.integer)):
        v = x.item()
        return v if not (isinstance(v, float) and not math.isfinite(v)) else None
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x))


if __name__ == "__main__":
    sys.exit(main())
