"""Does light cross a zero-thickness wall? plane-wall against the same scene with a box wall, one grid for both.

    .venv/bin/python tests/bench/bench_wall_leak.py [--thickness 0.01] [--spp 4096] [--probe-spp 256]

Run by hand (not part of the test command). ``plane-wall`` (:mod:`workers.procedural_interiors`: two rooms divided by
ONE double-sided plane x = 4.5 with a door) read 1.07-1.10 of Cycles in its dark room with the default config
(tests/bench/bench_fidelity.py), where a box-walled scene reads less. To tell a leak through the plane (the light
stage's gather reaching lit-side probes from dark-side hits, or bias offsets of hit points on a zero-thickness
surface) from the probe pipeline's error in a dark room lit through a door, this bakes two scenes with the SAME
probe grid (the default bake's automatic grid of plane-wall, given explicitly as ``place.counts`` + ``place.box``):

- ``plane``: plane-wall itself;
- ``box``: the same room with the divider replaced by a box wall of ``--thickness`` centred on x = 4.5 (the same
  door), single-sided like the shell.

Kiln's own path tracer (:func:`workers.kernels.pathtrace.indirect_irradiance`, 64 bounces) is the reference for each
scene (Cycles' references exist only for plane-wall). Printed per scene: at the bench's receivers
(tests/data/fidelity/plane-wall.points.json; the box wall's faces are thickness/2 nearer them)
``visibility_weighted`` and ``mask_normalized`` over the path tracer, and the light stage's stored octahedral
irradiance of every live probe inside the dark room (>= 3 cm from its surfaces; 6 axis directions) over the path
tracer at the probe's relocated position, by distance from the wall; and the light stage's gather at the dark room's
probe-ray hits: how many dark-side hits give any weight to a probe on the lit side of the wall (through the door: the
hits in the door's plane) and the lit probes' total weight there; and, at a sample of the dark room's hits, the light
stage's gathered E_indirect (the final maps: G) and the E_indirect it shades the hits with (G with its near-field
occlusion, ``light.near_*``: "shaded"; the same as G with ``--set light.near_radius=0``) over the path tracer's, by the
hit's distance to the room's nearest edge. ``--set SECTION.KEY=JSON`` changes both bakes' config.
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
sys.path.insert(0, str(ROOT / "tests" / "bench"))

import bench_fidelity as BF  # noqa: E402
from workers import procedural_interiors as PI  # noqa: E402
from workers.kernels.ddgi import cage_probes  # noqa: E402
from workers.kernels.gather import apply_sampler_weights, sampler_weights  # noqa: E402
from workers.kernels.grid import OFF, unpack_atlas  # noqa: E402
from workers.kernels.octahedral import bilinear_sample  # noqa: E402
from workers.kernels.pathtrace import indirect_irradiance  # noqa: E402
from workers.kernels.probe_hits import hit_surfaces, near_occlusion, probe_visibility  # noqa: E402
from workers.kernels.shading import direct_irradiance  # noqa: E402
from workers.procedural_glb import Light, SceneSpec, encode_glb, solid_mesh  # noqa: E402
from workers.raycast import caster_for_scene  # noqa: E402
from workers.stages.trace import probe_rays_of  # noqa: E402

XW = 4.5            # the divider plane of plane-wall (workers/procedural_interiors.py); the dark room is x > XW
ROOM_B = ((XW, 0.0, 0.0), (8.0, 2.8, 4.0))
AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


def box_wall_glb(th: float) -> bytes:
    """plane-wall with its divider replaced by a box wall x in [XW - th/2, XW + th/2], the same door."""
    t = 0.10
    ops = [(True, ((-t, -t, -t), (8.0 + t, 2.8 + t, 4.0 + t))),
           (False, ((0.0, 0.0, 0.0), (XW - th / 2, 2.8, 4.0))), (False, ((XW + th / 2, 0.0, 0.0), (8.0, 2.8, 4.0))),
           (False, ((XW - th / 2 - 1e-3, 0.0, 2.8), (XW + th / 2 + 1e-3, 2.0, 3.7)))]
    return encode_glb(SceneSpec(name="plane-wall-box", materials=PI._materials(),
                                meshes=[solid_mesh("shell", ops, PI._floor_or_wall)],
                                lights=[Light("room-a", "point", 25.0, position=(2.0, 2.4, 1.5))],
                                bake_box=PI._bounds(ops)))


def measure(label: str, glb: bytes, work: Path, config: dict, spp: int, probe_spp: int, hit_sample: int) -> dict:
    path = work / f"{label}.glb"
    path.write_bytes(glb)
    scene, recs, cfg, _ = BF.bake(label, work, None, config, source=path)
    place = recs["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    lit = recs["ingest"]["lights"]
    out = {"grid": grid}
    # 1. the bench's receivers: modes / Kiln's path tracer
    pdoc = json.loads((BF.DATA / "plane-wall.points.json").read_text())
    ref = json.loads(next(BF.DATA.glob("plane-wall.*.cycles.json")).read_text())
    points, dirs = np.asarray(pdoc["points"], np.float64), np.asarray(ref["dirs"], np.float64)
    n = len(points)
    pts, nrm = np.repeat(points, len(dirs), 0), np.tile(dirs, (n, 1))
    modes = {k: v.reshape(n, len(dirs), 3) for k, v in BF.reconstruct(recs, cfg, pts, nrm).items()}
    pt = np.asarray(indirect_irradiance(scene, pts, nrm, lit["lights"], sky=lit["sky"], spp=spp, bounces=64,
                                        rr_depth=3, seed=cfg.seed).irradiance).reshape(n, len(dirs), 3)
    out["regions"] = {r: {m: float(modes[m][idx].mean() / pt[idx].mean())
                          for m in ("visibility_weighted", "mask_normalized")}
                      for r, idx in pdoc["regions"].items() if r != "probes"}
    # 2. stored probe values in the dark room / the path tracer at the probes
    tr = recs["trace"]
    counts = grid["counts"]
    states = np.asarray(tr["probe_states"]).reshape(-1)
    pos = np.asarray(recs["relocate"]["probe_positions_relocated"]).reshape(-1, 3).astype(np.float32)
    irr = unpack_atlas(np.asarray(recs["light"]["irradiance"]), counts, cfg.light.irradiance_texels + 2)[..., :3]
    lo, hi = np.asarray(ROOM_B[0]) + 0.03, np.asarray(ROOM_B[1]) - 0.03
    dk = np.flatnonzero(np.all((pos > lo) & (pos < hi), axis=1) & (states != OFF))
    stored = np.stack([bilinear_sample(irr[i].astype(np.float64), AXES) for i in dk]).mean(-1)
    pv = np.asarray(indirect_irradiance(scene, np.repeat(pos[dk].astype(np.float64), 6, 0), np.tile(AXES, (len(dk), 1)),
                                        lit["lights"], sky=lit["sky"], spp=probe_spp, bounces=64, rr_depth=3,
                                        seed=cfg.seed + 1).irradiance).reshape(len(dk), 6, 3).mean(-1)
    x = pos[dk, 0]
    bands = {"all": x > 0, "x < 4.75": x < 4.75, "4.75-5.5": (x >= 4.75) & (x < 5.5), ">= 5.5": x >= 5.5}
    out["probes"] = {k: {"n": int(c.sum()), "stored_over_pt": float(stored[c].mean() / pv[c].mean())}
                     for k, c in bands.items()}
    # 3. the gather at dark probes' ray hits: weight on lit-side probes
    dirs_r = probe_rays_of(tr)
    surf = hit_surfaces(scene, dirs_r, np.asarray(tr["ray_hits"]), np.asarray(tr["ray_tri"]))
    R = dirs_r.rays
    keep = np.isin(surf.index // R, dk) & (surf.position[:, 0] > XW - 1e-3)
    P_, N_, V_ = surf.position[keep], surf.normal[keep], surf.view[keep]
    m = cfg.trace.depth_texels + 2
    full = "depth_moments_full" if "depth_moments_full" in tr.names() else "depth_moments"
    depth = unpack_atlas(np.asarray(tr[full], np.float32), counts, m)
    bias = cfg.light.self_shadow_bias
    vis, _ = probe_visibility(type("S", (), dict(position=P_, normal=N_, view=V_))(), grid, pos, states,
                              caster_for_scene(scene), bias)
    W = sampler_weights(P_, N_, V_, grid, pos, states, depth, cfg.light.irradiance_texels, bias, vis)
    _, cage = cage_probes(P_, N_, V_, grid["counts"], grid["origin"], grid["spacing"], bias)
    wl = (W.weight * (pos[cage][:, :, 0] < XW)).sum(1)
    door = (P_[:, 2] > 2.8 - 0.3) & (P_[:, 2] < 3.7 + 0.3) & (P_[:, 1] < 2.3)
    out["gather"] = {"dark_hits": int(keep.sum()), "with_lit_weight": int((wl > 0).sum()),
                     "lit_weight_sum": float(wl.sum()), "lit_weight_sum_off_door": float(wl[~door].sum()),
                     "with_lit_weight_off_door": int((wl[~door] > 0).sum())}
    # 4. the gathered E_indirect (final maps) at a sample of those hits inside room B against the path tracer there,
    # by the hit's distance to the nearest edge of room B (a concave edge: floor / ceiling / wall junctions)
    inb = np.flatnonzero(np.all((P_ > np.asarray(ROOM_B[0]) - 0.01) & (P_ < np.asarray(ROOM_B[1]) + 0.01), axis=1))
    sub = np.sort(np.random.default_rng(cfg.seed).choice(inb, size=min(hit_sample, inb.size), replace=False))
    maps = np.ascontiguousarray(irr, np.float32)
    G = apply_sampler_weights(W, maps)[sub]
    eg = G.mean(-1)
    geo = surf.geo_normal[keep][sub].astype(np.float64)
    # what the light stage shades the hits with: G with its near-field occlusion (workers.kernels.bounce.integrate
    # ``near``), at its fixed point E = ((1 − a)·G + a·(π·L'_e + ρ'·E_direct)) / (1 − a·ρ'), a the weighted
    # occlusion (light.near_strength × near_occlusion's)
    lc = cfg.light
    es = eg
    if lc.near_radius > 0 and lc.near_rays > 0:
        bounds = np.asarray(recs["ingest"].stats["bounds"])
        eps = 1e-4 * max(float(np.linalg.norm(bounds[1] - bounds[0])), 1e-3)
        caster = caster_for_scene(scene)
        Ps, Ns, Gs = P_[sub], N_[sub], surf.geo_normal[keep][sub]
        nf = near_occlusion(scene, Ps, Ns, Gs, caster, lc.near_radius * float(min(grid["spacing"])), lc.near_rays,
                            eps)
        a, rn, le = np.zeros((len(sub), 1)), np.zeros((len(sub), 3)), np.zeros((len(sub), 3))
        a[nf.index, 0], rn[nf.index], le[nf.index] = lc.near_strength * nf.a, nf.albedo, nf.emission
        ed = (direct_irradiance(Ps, Ns, lit["lights"], caster, eps, geo_normals=Gs) if lit["lights"]
              else np.zeros((len(sub), 3)))
        es = (((1 - a) * G + a * (np.pi * le + rn * ed)) / (1 - a * rn)).mean(-1)
    ep = np.asarray(indirect_irradiance(scene, P_[sub].astype(np.float64), N_[sub].astype(np.float64), lit["lights"],
                                        sky=lit["sky"], spp=probe_spp, bounces=64, rr_depth=3, seed=cfg.seed + 2,
                                        geo_normals=geo).irradiance).mean(-1)
    alb = surf.albedo[keep][sub].mean(-1)
    dd = np.sort(np.minimum(np.abs(P_[sub] - np.asarray(ROOM_B[0])), np.abs(P_[sub] - np.asarray(ROOM_B[1]))), axis=1)
    edge = dd[:, 1]                                    # dd[:, 0] ~ 0: the face the hit lies on
    tot = float((alb * ep).sum())
    out["hits"] = {k: {"n": int(c.sum()), "gathered_over_pt": float(eg[c].sum() / ep[c].sum()),
                       "shaded_over_pt": float(es[c].sum() / ep[c].sum()),
                       "excess_share": float((alb[c] * (es[c] - ep[c])).sum() / tot)}
                   for k, c in {"edge < 5 cm": edge < 0.05, "5-15 cm": (edge >= 0.05) & (edge < 0.15),
                                "15-30 cm": (edge >= 0.15) & (edge < 0.3), ">= 30 cm": edge >= 0.3,
                                "all": edge >= 0}.items()}
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--thickness", type=float, default=0.01, help="the box wall's thickness, metres")
    ap.add_argument("--spp", type=int, default=4096, help="path tracer paths per receiver")
    ap.add_argument("--probe-spp", type=int, default=256, help="path tracer paths per probe direction")
    ap.add_argument("--hits", type=int, default=6000, help="dark-room hits path-traced (--probe-spp paths each)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=JSON",
                    help="a config override for both bakes, e.g. --set light.near_radius=0; repeatable")
    args = ap.parse_args()
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        t0 = time.perf_counter()
        extra: dict = {}
        for item in args.set:
            key, val = item.split("=", 1)
            sec, name = key.split(".", 1)
            extra.setdefault(sec, {})[name] = json.loads(val)
        res["plane"] = measure("plane-wall", PI.make_interior("plane-wall"), work, extra, args.spp, args.probe_spp,
                               args.hits)
        g = res["plane"]["grid"]
        o, s, c = (np.asarray(g[k], np.float64) for k in ("origin", "spacing", "counts"))
        fixed = {**extra, "place": {**extra.get("place", {}), "counts": [int(v) for v in c],
                                    "box": {"min": o.tolist(), "max": (o + s * (c - 1)).tolist()}}}
        res["box"] = measure("box-wall", box_wall_glb(args.thickness), work, fixed, args.spp, args.probe_spp, args.hits)
        print(f"grid {list(c)} spacing {np.round(s, 3).tolist()} (plane-wall's automatic grid, both scenes); "
              f"box wall {args.thickness * 100:.1f} cm; {time.perf_counter() - t0:.0f} s")
    print(f"{'receivers (mode / Kiln PT)':<28}" + "".join(f"{k + ' ' + m[:8]:>20}" for k in res for m in ("vis_wtd", "mask_norm")))
    for r in res["plane"]["regions"]:
        print(f"{r:<28}" + "".join(f"{res[k]['regions'][r][m]:>20.3f}" for k in res
                                   for m in ("visibility_weighted", "mask_normalized")))
    print(f"{'dark probes (stored / PT)':<28}" + "".join(f"{k:>20}" for k in res))
    for b in res["plane"]["probes"]:
        print(f"{b:<28}" + "".join(f"{res[k]['probes'][b]['stored_over_pt']:>14.3f} ({res[k]['probes'][b]['n']:>4})"
                                   for k in res))
    for k, v in res.items():
        gth = v["gather"]
        print(f"{k}: {gth['dark_hits']} dark-side hits of dark probes; {gth['with_lit_weight']} give weight to a lit-side "
              f"probe (sum {gth['lit_weight_sum']:.1f}); away from the door (> 30 cm): {gth['with_lit_weight_off_door']} "
              f"(sum {gth['lit_weight_sum_off_door']:.2f})")
    print(f"{'room B hits: G / PT, shaded':<28}" + "".join(f"{k:>26}" for k in res) + "   (excess share of the hits' E)")
    for b in res["plane"]["hits"]:
        print(f"{b:<28}" + "".join(f"{res[k]['hits'][b]['gathered_over_pt']:>8.3f} {res[k]['hits'][b]['shaded_over_pt']:.3f} "
                                   f"({res[k]['hits'][b]['n']:>4}) {res[k]['hits'][b]['excess_share']:+.3f}" for k in res))
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
