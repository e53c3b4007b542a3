"""Storage formats of the bundle (issue 17, item 1): bytes and the GI error each format adds against float32.

    .venv/bin/python tests/bench/bench_formats.py [--scenes two-rooms,cornell,zdm2] [--budget 1500] [--points 20000]
                                                  [--zdm2-grid 16x8x16] [--prt]

Per scene it bakes place, relocate, trace and light in this process with the real pipeline, once with every
float artifact kept in float32 (``workers.kernels.precision`` patched to store float32), then applies the
shipped formats (the precision functions as the stages call them, written and read back through
``proto.ktx2``) to that bake's artifacts one change at a time and all together, and reconstructs each GI mode's
indirect irradiance with the Python twins of the runtime shaders (``workers.kernels.point_modes``:
``leaking`` L2 ``sh_l2``, ``leaking`` L1 ``sh_l1_*``, ``ddgi`` on the octahedral atlases and depth moments; with
``--prt`` also ``prt``, relit for the bake's lights, with its SH basis volumes in half floats) at

- ``free``: random points in the probe box outside every solid (6 axis rays see no back face), random unit
  normals, view = normal;
- ``surface``: points on the front faces by area (``workers.kernels.surface_points.area_points``), their
  normals, view = normal.

Error = relative RMSE ‖E_q − E_f‖₂ / ‖E_f‖₂ over all points and the 3 channels (target ≤ 0.5%), plus the 99th
percentile, the largest and the share of points over 1% and 10% of the per-point relative error
|E_q − E_f| / (|E_f| + 1% of the mean |E_f|) (norms over rgb). Bytes per probe: the
level (uncompressed) and the file with Zstandard at the bundle's default level (3; the stages write the DDGI atlases
at 9), float32 and the new format; the ``irradiance`` and ``depth_moments`` rows as the stages store them (RGB9E5;
far-clamped depth, OFF probes kept; tiles without their borders), the ``(…)`` rows the alternatives.

Changes scored (besides the formats): ``depth clamp`` = the trace stage's far clamp
(``workers.kernels.depth_moments.clamp_far``: exact, so its rows must read 0 error), in float32 and in RG16F.
Prints a table per scene and the numbers as JSON on the last line.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from proto.bundle import DEFAULT_ZSTD_LEVEL  # noqa: E402
from proto.ktx2 import decode_ktx2, encode_ktx2  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.kernels import precision  # noqa: E402
from workers.kernels.point_modes import mode_irradiance  # noqa: E402

ZDM2 = ROOT.parent / "shared" / "scenes" / "zdm2-sauerbraten" / "zdm2.glb"
SUN = {"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0, "color": [1.0, 0.95, 0.9]}
STAGES = ("ingest", "place", "relocate", "trace", "light", "prt")
AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


def _float32_only():
    """Patch the precision module so that the stages keep float32 (the reference bake); returns an undo. The PRT
    basis is float32 there too: the float32 bake's arrays are what :func:`variants` quantizes."""
    saved = precision.half, precision.rgb_ufloat, precision.rgb9e5

    def keep(a):
        a = np.ascontiguousarray(a, np.float32)
        c = a.shape[-1] if a.ndim >= 3 else 1
        return a, {1: "R32_SFLOAT", 2: "R32G32_SFLOAT", 4: "R32G32B32A32_SFLOAT"}[c], {}

    precision.half = keep
    precision.rgb_ufloat = precision.rgb9e5 = lambda a: keep(np.ascontiguousarray(a, np.float32))
    return lambda: (setattr(precision, "half", saved[0]), setattr(precision, "rgb_ufloat", saved[1]),
                    setattr(precision, "rgb9e5", saved[2]))


def bake(scene, config: dict) -> dict:
    """The float32 artifacts (and stats) of place .. light."""
    cfg = BakeConfig.model_validate(config)
    undo = _float32_only()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            store = Store(tmp)
            sid = store.put_bytes(scene.to_bytes())
            recs = {}
            for st, _ in plan(sid, cfg):
                if st.name not in STAGES:
                    continue
                rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
                recs[st.name] = pipeline._lazy(store, rec)
            names = ["irradiance", "sh_l1_r", "sh_l1_g", "sh_l1_b", "sh_l2", "probe_sh"]
            arrays = {n: np.asarray(recs["light"][n]) for n in names if n in recs["light"]}
            arrays["depth_moments"] = np.asarray(recs["trace"]["depth_moments_full"])    # unclamped float32
            arrays["probe_states"] = np.asarray(recs["trace"]["probe_states"])
            arrays["probe_positions_relocated"] = np.asarray(recs["relocate"]["probe_positions_relocated"])
            if "prt" in recs and "prt" in recs["prt"]:          # PRT on: its section, tables and basis volumes
                arrays.update({n: recs["prt"][n] for n in recs["prt"].names()})
            place = recs["place"].stats
            grid = {k: place[k] for k in ("counts", "origin", "spacing")}
            return {"arrays": arrays, "grid": grid, "bias": cfg.light.self_shadow_bias,
                    "lights": recs["ingest"]["lights"]["lights"], "bounds": recs["ingest"].stats["bounds"]}
    finally:
        undo()


def _roundtrip(data, vk) -> np.ndarray:
    """What a reader gets back: the KTX2 file written and decoded."""
    arr, _ = decode_ktx2(encode_ktx2(np.asarray(data), vk, DEFAULT_ZSTD_LEVEL, volume=np.asarray(data).ndim == 4))
    return arr.reshape(np.asarray(data).shape)


def _bytes(data, vk) -> tuple[int, int]:
    a = np.asarray(data)
    raw = encode_ktx2(a, vk, None, volume=a.ndim == 4)
    z = encode_ktx2(a, vk, DEFAULT_ZSTD_LEVEL, volume=a.ndim == 4)
    return len(raw), len(z)


def free_points(scene, grid, n: int, rng) -> dict:
    from workers.raycast import caster_for_scene

    caster = caster_for_scene(scene)
    counts, origin, spacing = (np.asarray(grid[k], np.float64) for k in ("counts", "origin", "spacing"))
    hi = origin + spacing * (counts - 1)
    pts = rng.uniform(origin, hi, (3 * n, 3))
    o = np.repeat(pts, 6, axis=0)
    d = np.tile(AXES, (len(pts), 1))
    h = caster.intersect(o, d)
    inside = h.backface.reshape(-1, 6).any(axis=1)
    pts = pts[~inside][:n]
    nrm = rng.standard_normal(pts.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return {"position": pts, "normal": nrm, "view": nrm}


def surface_points(scene, n: int) -> dict:
    from workers.kernels.surface_points import area_points

    p = area_points(scene, n, seed=1)
    return {"position": p["position"], "normal": p["normal"], "view": p["view"]}


def errors(e_q: np.ndarray, e_f: np.ndarray) -> dict:
    rel = float(np.sqrt(((e_q - e_f) ** 2).sum()) / max(np.sqrt((e_f ** 2).sum()), 1e-30))
    mag = np.linalg.norm(e_f, axis=1)
    per = np.linalg.norm(e_q - e_f, axis=1) / (mag + 0.01 * mag.mean() + 1e-30)
    return {"relative_rmse": rel, "p99_relative": float(np.percentile(per, 99)), "max_relative": float(per.max()),
            "over_1pct": float((per > 0.01).mean()), "over_10pct": float((per > 0.1).mean())}


def clamped_depth(arrays, grid, bias: float, bounds) -> tuple[np.ndarray, float]:
    """The trace stage's stored depth moments before rounding: far texels clamped to the probe's reach
    (``workers.kernels.depth_moments.clamp_far``; B = ``bias``, the bake's ``light.self_shadow_bias``)."""
    from workers.kernels.ddgi import bias_scale
    from workers.kernels.depth_moments import clamp_far, reach
    from workers.kernels.grid import pack_atlas, unpack_atlas

    counts = grid["counts"]
    atlas = np.asarray(arrays["depth_moments"], np.float32)
    m = atlas.shape[0] // int(counts[1])
    limit = reach(np.asarray(arrays["probe_positions_relocated"]).reshape(-1, 3), counts, grid["origin"],
                  grid["spacing"], bias_scale(grid["spacing"], bias), bounds)
    maps, share = clamp_far(unpack_atlas(atlas, counts, m), limit)
    return pack_atlas(maps, counts), share


def variants(arrays, depth_clamped=None) -> dict:
    """name -> (changed artifacts {name: (data, vk)}, modes to score). ``depth_clamped``: the far-clamped float32
    depth atlas (:func:`clamped_depth`)."""
    irr_u = precision.rgb_ufloat(arrays["irradiance"])
    irr_h = precision.half(arrays["irradiance"])
    irr_e = precision.rgb9e5(arrays["irradiance"])
    dep = precision.half(arrays["depth_moments"])
    l1 = {f"sh_l1_{c}": precision.half(arrays[f"sh_l1_{c}"])[:2] for c in "rgb"}
    out = {
        "irradiance R11G11B10F": ({"irradiance": irr_u[:2]}, ["ddgi"]),
        "irradiance RGBA16F": ({"irradiance": irr_h[:2]}, ["ddgi"]),
        "irradiance RGB9E5": ({"irradiance": irr_e[:2]}, ["ddgi"]),
        "depth_moments RG16F": ({"depth_moments": dep[:2]}, ["ddgi"]),
        "sh_l1_* RGBA16F": (l1, ["leaking_l1"]),
    }
    if "sh_l2" in arrays:
        out["sh_l2 RGBA16F"] = ({"sh_l2": precision.half(arrays["sh_l2"])[:2]}, ["leaking"])
    if depth_clamped is not None:
        dep_c = precision.half(depth_clamped)
        out["depth clamp (float32)"] = ({"depth_moments": (np.asarray(depth_clamped, np.float32), "R32G32_SFLOAT")},
                                        ["ddgi"])
        out["depth clamp + RG16F"] = ({"depth_moments": dep_c[:2]}, ["ddgi"])
        dep = dep_c
    shipped = {"irradiance": irr_e[:2], "depth_moments": dep[:2], **l1}
    if "sh_l2" in arrays:
        shipped["sh_l2"] = precision.half(arrays["sh_l2"])[:2]
    out["all (as shipped)"] = (shipped, ["leaking", "leaking_l1", "ddgi"])
    if "prt" in arrays:                    # the PRT SH basis volumes in half floats (the prt stage's _basis)
        basis = [n for group in arrays["prt"]["sh"]["basis"] for n in group]
        out["prt_sh_basis RGBA16F"] = ({n: precision.half(arrays[n])[:2] for n in basis}, ["prt"])
    return out


def flat_field() -> dict:
    """The packed 11/11/10 floats on a flat field: grey irradiance v (0.01 … 1000, log-spaced) stored once and read
    back, as every texel and hence any filtered reconstruction of a uniformly lit region reads it. Rounding does not
    average out there: the error is the format's own (≤ 2^-7 relative for R and G, 2^-6 for B)."""
    v = np.exp(np.linspace(np.log(0.01), np.log(1000.0), 200001)).astype(np.float32)
    rgb = np.repeat(v[:, None], 3, axis=1)
    rel = {}
    for name, (data, vk, _) in (("R11G11B10F", precision.rgb_ufloat(rgb[None])),
                                ("RGB9E5", precision.rgb9e5(rgb[None])),
                                ("RGBA16F", precision.half(np.concatenate([rgb, np.ones_like(rgb[:, :1])], 1)[None]))):
        q = _roundtrip(data, vk).reshape(len(v), -1)[:, :3]
        e = np.sqrt((((q - rgb) / rgb) ** 2).mean(axis=1))       # relative RMSE over rgb, per grey value
        rel[name] = {"max": float(e.max()), "mean": float(e.mean()), "share_over_0.5pct": float((e > 0.005).mean())}
    return rel


def modes_at(arrays, grid, pts, bias, modes, lights=(), caster=None) -> dict:
    out = {}
    for m in modes:
        if m == "prt":                     # relit for the bake's own lights (shadow rays), read like leaking
            out[m] = mode_irradiance("prt", arrays, grid, pts["position"], pts["normal"], pts["view"],
                                     lights=lights, caster=caster)
            continue
        a = arrays
        if m == "leaking_l1":                      # the L1 volumes alone (bakes with light.sh_order = 1)
            a = {k: v for k, v in arrays.items() if k != "sh_l2"}
        out[m] = mode_irradiance("leaking" if m == "leaking_l1" else m, a, grid, pts["position"], pts["normal"],
                                 pts["view"], self_shadow_bias=bias)
    return out


def run_scene(name: str, scene, config: dict, n_points: int) -> dict:
    b = bake(scene, config)
    arrays, grid = b["arrays"], b["grid"]
    P = int(np.prod(grid["counts"]))
    rng = np.random.default_rng(7)
    sets = {"free": free_points(scene, grid, n_points, rng), "surface": surface_points(scene, n_points)}
    from workers.raycast import caster_for_scene

    caster = caster_for_scene(scene)
    all_modes = ["leaking", "leaking_l1", "ddgi"] if "sh_l2" in arrays else ["leaking_l1", "ddgi"]
    all_modes += ["prt"] if "prt" in arrays else []
    ref = {s: modes_at(arrays, grid, pts, b["bias"], all_modes, b["lights"], caster) for s, pts in sets.items()}
    res = {"probes": P, "counts": grid["counts"], "points": {s: len(p["position"]) for s, p in sets.items()},
           "artifacts": {}, "changes": {}}
    # bytes per probe, float32 vs the shipped format (and the packed irradiance, measured, not shipped)
    dep_c, share = clamped_depth(arrays, grid, b["bias"], b["bounds"])
    res["depth_clamped_share"] = share
    shipped = {"irradiance": precision.rgb9e5(arrays["irradiance"]),
               "irradiance (RGBA16F)": precision.half(arrays["irradiance"]),
               "irradiance (packed)": precision.rgb_ufloat(arrays["irradiance"]),
               "depth_moments": precision.half(dep_c),
               "depth_moments (unclamped)": precision.half(arrays["depth_moments"]),
               **{f"sh_l1_{c}": precision.half(arrays[f"sh_l1_{c}"]) for c in "rgb"}}
    if "sh_l2" in arrays:
        shipped["sh_l2"] = precision.half(arrays["sh_l2"])
    for group in (arrays["prt"]["sh"]["basis"] if "prt" in arrays else []):
        shipped.update({n: precision.half(arrays[n]) for n in group})
    f32 = {"depth_moments": "R32G32_SFLOAT"}
    from proto.atlas import atlas_strip_border
    ny = int(grid["counts"][1])
    for art, (data, vk, meta) in shipped.items():
        src = art.split(" ")[0]
        r32, z32 = _bytes(arrays[src], f32.get(src, "R32G32B32A32_SFLOAT"))
        if art in ("irradiance", "depth_moments"):       # as the stages store them: tiles without their borders
            data = atlas_strip_border(np.asarray(data), np.asarray(data).shape[0] // ny - 2)
        rn, zn = _bytes(data, vk)
        res["artifacts"][art] = {"float32": f32.get(src, "R32G32B32A32_SFLOAT"), "format": vk, "per_probe": {
            "float32": r32 / P, "float32_zstd": z32 / P, "new": rn / P, "new_zstd": zn / P},
            "texel_relative_rmse": meta["precision"]["relative_rmse"],
            "fallback": meta["precision"].get("fallback") or meta["precision"].get("fallback_from")}
    basis = [k for k in res["artifacts"] if k.startswith("prt_sh_basis_")]
    if basis:                              # one row for the PRT basis volumes: bytes summed, the largest texel error
        rows = [res["artifacts"].pop(k) for k in basis]
        res["artifacts"][f"prt_sh_basis_* ({len(rows)})"] = {
            **rows[0], "per_probe": {k: sum(r["per_probe"][k] for r in rows) for k in rows[0]["per_probe"]},
            "texel_relative_rmse": max(r["texel_relative_rmse"] for r in rows),
            "fallback": next((r["fallback"] for r in rows if r["fallback"]), None)}
    for vname, (changed, modes) in variants(arrays, dep_c).items():
        q = dict(arrays)
        for art, (data, vk) in changed.items():
            q[art] = _roundtrip(data, vk)
        res["changes"][vname] = {
            s: {m: errors(e, ref[s][m])
                for m, e in modes_at(q, grid, pts, b["bias"], modes, b["lights"], caster).items()}
            for s, pts in sets.items()}
    return res


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="two-rooms,cornell,zdm2")
    ap.add_argument("--budget", type=int, default=1500, help="place.budget of the procedural scenes")
    ap.add_argument("--zdm2-grid", default="16x8x16")
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--prt", action="store_true", help="also bake PRT and measure its SH basis in half floats")
    args = ap.parse_args()
    from workers.procedural import make_scene

    results = {"zstd_level": DEFAULT_ZSTD_LEVEL, "flat_field": flat_field(), "scenes": {}}
    print("flat grey field, relative RMSE over rgb of the stored value (0.01-1000, 200001 values):")
    for name, f in results["flat_field"].items():
        print(f"  {name:>11s}: max {f['max']:.3%}, mean {f['mean']:.3%}, over 0.5% at {f['share_over_0.5pct']:.1%} "
              f"of the values")
    for name in args.scenes.split(","):
        if name == "zdm2":
            if not ZDM2.exists():
                print(f"zdm2 skipped: {ZDM2} is absent")
                continue
            scene = ingest_file(ZDM2)
            config = {"place": {"counts": [int(x) for x in args.zdm2_grid.split("x")]},
                      "scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]}, "trace": {"rays_per_probe": args.rays},
                      "evaluate": {"enabled": False}}
        else:
            with tempfile.NamedTemporaryFile(suffix=".glb") as f:
                f.write(make_scene(name))
                f.flush()
                scene = ingest_file(f.name)
            config = {"place": {"budget": args.budget}, "trace": {"rays_per_probe": args.rays},
                      "evaluate": {"enabled": False}}
        if args.prt:
            config["prt"] = {"enabled": True}
        results["scenes"][name] = r = run_scene(name, scene, config, args.points)
        nx, ny, nz = r["counts"]
        print(f"\n{name}: {nx}x{ny}x{nz} = {r['probes']} probes; points {r['points']}; zstd level {DEFAULT_ZSTD_LEVEL}")
        print(f"{'artifact':>21s} {'float32':>20s} {'stored as':>24s} {'B/probe f32':>11s} {'+zstd':>7s} "
              f"{'new':>6s} {'+zstd':>7s} {'texel err':>9s}")
        for art, a in r["artifacts"].items():
            pp = a["per_probe"]
            print(f"{art:>21s} {a['float32']:>20s} {a['format']:>24s} {pp['float32']:11.1f} {pp['float32_zstd']:7.1f} "
                  f"{pp['new']:6.1f} {pp['new_zstd']:7.1f} {a['texel_relative_rmse']:9.2e}"
                  + (f"  fallback: {a['fallback']}" if a["fallback"] else ""))
        print(f"{'change':>24s} {'points':>8s} {'mode':>11s} {'rel RMSE':>9s} {'p99 rel':>9s} {'max rel':>9s} "
              f"{'>1%':>7s} {'>10%':>7s}  target")
        for vname, per_set in r["changes"].items():
            for s, per_mode in per_set.items():
                for m, e in per_mode.items():
                    ok = "ok" if e["relative_rmse"] <= 0.005 else "OVER 0.5%"
                    print(f"{vname:>24s} {s:>8s} {m:>11s} {e['relative_rmse']:9.2e} {e['p99_relative']:9.2e} "
                          f"{e['max_relative']:9.2e} {e['over_1pct']:7.2%} {e['over_10pct']:7.2%}  {ok}")
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
